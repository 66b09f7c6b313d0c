"""``truckrl <command> [KEY=VALUE ...]``: every command of the package behind one name.

    truckrl train experiment=fast            # = python -m truckrl.train experiment=fast
    truckrl eval checkpoint=pretrained       # = python -m truckrl.evaluate checkpoint=pretrained
    truckrl tools configs ppo                # every field under ppo

Every command takes ``KEY=VALUE`` arguments (dotted keys for nested fields, values in YAML
syntax); ``truckrl <command> --help`` lists them. ``train``, ``eval``, ``play`` and ``export``
compose a Hydra config (presets, sweeps with ``-m``); the others build one dataclass
(:func:`truckrl.cli.key_value_config`). This module imports only the command it runs: ``truckrl
--help`` loads no torch. An unknown command prints one line ``error: ...`` and exits with code 2.
"""

from __future__ import annotations

import difflib
import importlib
import runpy
import sys

#: command -> (module, what it does). A Hydra command's module runs as ``python -m <module>``.
HYDRA = {
    "train": ("truckrl.train", "PPO training with the success curriculum"),
    "eval": ("truckrl.evaluate", "score a checkpoint (or the planner) on held-out scenes"),
    "play": ("truckrl.play", "the viewer: drive, watch a policy, record a video"),
    "export": ("truckrl.export", "a checkpoint's actor as ONNX or TorchScript"),
}
#: command -> (module with ``main(argv) -> int``, what it does).
PLAIN = {
    "plan": ("truckrl.plan", "the CEM planner baseline on held-out scenes"),
    "bench": ("truckrl.bench.__main__", "throughput benchmarks (lidar, env, train)"),
}
TOOLS = {
    "paths": ("truckrl.tools.paths", "draw where policies drive, side by side"),
    "diagnose": ("truckrl.tools.diagnose", "where a policy fails (tasks with a diagnosis)"),
    "imitate": ("truckrl.tools.imitate", "clone planner demonstrations into a checkpoint"),
    "scenes": ("truckrl.tools.scenes", "render random scenes of a task to a PNG"),
    "curves": ("truckrl.tools.curves", "a run's learning curves as a PNG"),
    "configs": ("truckrl.tools.configs", "every config field: default, unit, range, meaning"),
    "aggregate": ("truckrl.tools.aggregate", "runs over seeds: per-seed figures, IQM, 95 % CI"),
    "pretrained": ("truckrl.tools.pretrained", "rebuild a task's shipped policy and its card"),
}


def usage() -> str:
    rows = [(name, about) for name, (_, about) in (HYDRA | PLAIN).items()]
    rows.append(("tools", " | ".join(TOOLS) + " (truckrl tools --help)"))
    return "\n".join(
        [
            "usage: truckrl <command> [KEY=VALUE ...]",
            "",
            "commands:",
            *(f"  {name:<8}{about}" for name, about in rows),
            "",
            "truckrl <command> --help lists a command's keys. train, eval, play and export take",
            "Hydra overrides (presets such as experiment=fast, sweeps with -m); python -m",
            "truckrl.train ... and the other modules work as before.",
        ]
    )


def tools_usage() -> str:
    return "\n".join(
        [
            "usage: truckrl tools <tool> [KEY=VALUE ...]",
            "",
            "tools:",
            *(f"  {name:<12}{about}" for name, (_, about) in TOOLS.items()),
            "",
            "truckrl tools <tool> --help lists a tool's keys.",
        ]
    )


def _unknown(kind: str, name: str, known: dict) -> int:
    close = difflib.get_close_matches(name, list(known), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    print(f"error: no {kind} {name!r}{hint}; one of: {', '.join(known)}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    """Run ``truckrl <command> ...``; the command's exit code."""
    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(usage())
        return 0
    command, rest = args[0], args[1:]
    if command in HYDRA:
        # as `python -m <module>`: the module is __main__ (env workers that spawn starts
        # re-import it and ignore stop signals; Hydra names the job after it)
        sys.argv = [f"truckrl {command}", *rest]
        from truckrl import cli  # no torch: keeps the line as typed for the JSON's provenance

        cli.TYPED_ARGV[:] = ["truckrl", command, *rest]
        runpy.run_module(HYDRA[command][0], run_name="__main__", alter_sys=True)
        return 0
    if command in PLAIN:
        return importlib.import_module(PLAIN[command][0]).main(rest) or 0
    if command == "tools":
        if not rest or rest[0] in ("-h", "--help"):
            print(tools_usage())
            return 0
        if rest[0] not in TOOLS:
            return _unknown("tool", rest[0], TOOLS)
        return importlib.import_module(TOOLS[rest[0]][0]).main(rest[1:]) or 0
    return _unknown("command", command, {**HYDRA, **PLAIN, "tools": None})


if __name__ == "__main__":
    sys.exit(main())
