"""``python -m truckrl.bench <benchmark> [options]``: dispatch to one benchmark module.

A benchmark is a module under ``truckrl.bench`` listed in :data:`BENCHMARKS`, exposing
``add_arguments(parser)`` and ``run(args)``; its docstring's first line is its help text.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from types import ModuleType

#: Sub-command name -> module. Modules not present in this checkout are left out of the CLI.
BENCHMARKS: dict[str, str] = {
    "lidar": "truckrl.bench.lidar",
    "env": "truckrl.bench.env",
    "train": "truckrl.bench.train",
}


def _available() -> dict[str, ModuleType]:
    found = {}
    for name, module in BENCHMARKS.items():
        try:
            found[name] = importlib.import_module(module)
        except ModuleNotFoundError as err:
            if err.name != module:  # the module exists but something it imports is missing
                raise
    return found


def main(argv: list[str] | None = None) -> int:
    modules = _available()
    parser = argparse.ArgumentParser(
        prog="python -m truckrl.bench",
        description="Throughput benchmarks: print a table, write JSON to outputs/bench/.",
    )
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, module in modules.items():
        doc = (module.__doc__ or name).strip().splitlines()[0]
        p = sub.add_parser(name, help=doc, description=module.__doc__)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    args = parser.parse_args(argv)
    args._run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
