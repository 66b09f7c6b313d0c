"""``truckrl tools configs [PREFIX]``: every config field (name, default, unit, allowed range,
meaning) of train, eval, play and the tasks, optionally only those under ``PREFIX``.

    truckrl tools configs ppo          # or prefix=ppo
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from truckrl.config.fields import param

PROG = "truckrl tools configs"


@dataclass
class ConfigsConfig:
    """What to list."""

    prefix: str = param("", doc="only fields whose dotted name starts with this (ppo, env.task)")


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config

    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) == 1 and "=" not in args[0] and not args[0].startswith("-"):
        args = [f"prefix={args[0]}"]  # the bare prefix: truckrl tools configs ppo
    cfg = key_value_config(ConfigsConfig, args, PROG, __doc__.split("\n\n")[0].replace("\n", " "))
    from truckrl.config.schemas import main as print_fields

    return print_fields([cfg.prefix] if cfg.prefix else [])


if __name__ == "__main__":
    sys.exit(main())
