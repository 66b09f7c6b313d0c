"""``truckrl bench <benchmark> [KEY=VALUE ...]``: dispatch to one benchmark module.

A benchmark is a module under ``truckrl.bench`` listed in :data:`BENCHMARKS`, exposing
``parse(argv)`` (``KEY=VALUE`` arguments into its options, :func:`truckrl.cli.key_value_config`;
bad input is one line, exit 2, before any work) and ``run(options)``; its docstring's first line
is its one-line description. ``truckrl bench <benchmark> --help`` lists its keys.
"""

from __future__ import annotations

import importlib
import sys
from types import ModuleType

#: Sub-command name -> module. Modules not present in this checkout are left out of the CLI.
BENCHMARKS: dict[str, str] = {
    "lidar": "truckrl.bench.lidar",
    "env": "truckrl.bench.env",
    "train": "truckrl.bench.train",
    "trainers": "truckrl.bench.trainers",
}
PROG = "truckrl bench"


def _available() -> dict[str, ModuleType]:
    found = {}
    for name, module in BENCHMARKS.items():
        try:
            found[name] = importlib.import_module(module)
        except ModuleNotFoundError as err:
            if err.name != module:  # the module exists but something it imports is missing
                raise
    return found


def usage(modules: dict[str, ModuleType]) -> str:
    """The benchmarks, one a line, with their descriptions."""
    lines = [f"usage: {PROG} BENCHMARK [KEY=VALUE ...]  (BENCHMARK --help lists its keys)", ""]
    lines.append("Throughput benchmarks: print a table, write JSON to outputs/bench/.")
    width = max(len(n) for n in modules)
    for name, module in modules.items():
        doc = (module.__doc__ or name).strip().splitlines()[0]
        lines.append(f"  {name:<{width}}  {doc}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import fail

    argv = sys.argv[1:] if argv is None else list(argv)
    modules = _available()
    if not argv:
        fail(f"give a BENCHMARK, one of {list(modules)} (see {PROG} --help)")
    if argv[0] in ("-h", "--help"):
        print(usage(modules))
        return 0
    name, rest = argv[0], argv[1:]
    if name not in modules:
        fail(f"benchmark {name!r} is not one of {list(modules)} (see {PROG} --help)")
    module = modules[name]
    module.run(module.parse(rest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
