"""``truckrl eval``: score a policy on fixed seeded scenes with its mean action.

    truckrl eval checkpoint=outputs/DATE/TIME difficulty=2 episodes=200
    truckrl eval policy=onnx:policy.onnx episodes=200       # an exported model, by onnxruntime
    truckrl eval policy=mypkg.drivers:make task=dock        # a user's factory

``policy=`` names what plays (:mod:`truckrl.rl.policy_specs`: ``checkpoint:PATH``,
``pretrained[:TASK]``, ``onnx:FILE``, ``planner``, ``module:function``); ``checkpoint=PATH`` is
short for ``policy=checkpoint:PATH``. Runs one deterministic episode in each of ``episodes``
scenes drawn from ``seed`` (the same seed gives the same scenes, so policies are compared on
identical tasks) at ``difficulty`` (default: the policy's curriculum difficulty, else 6), with the
policy's env config (a checkpoint's, an ONNX export's model card; else the default env of
``task``), changed by ``env.*`` overrides. Prints the outcome rates and mean / p95 final
errors, then the percentiles of the realised |jerk|, |steering rate| and the rest of
:data:`~truckrl.evaluation.rollout.MOTION` over every step of the successful episodes
(``"smoothness"``), then the outcome rates and errors per scene category (intersection: route,
turn angle split left / right, crossing angle, trailer length, road width, goal distance; other
tasks: their ``category_dims``; see :mod:`truckrl.evaluation.categories`), then everything as one line of JSON (the category rows under
``"categories"``), and writes that JSON to ``output``: by default
``<run dir of the checkpoint>/eval/<difficulty>-<seed>.json``, beside the evaluated run (other
policies: ``outputs/eval/<kind>-<name>-<difficulty>-<seed>.json``). The
output location is checked before any episode runs; if the write still fails at the end, the
results are printed first and the error after them. Fields: ``EvaluateConfig`` in
``truckrl/config/schemas.py``.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig

from truckrl.cli import check_writable, hydra_entry, provenance

if TYPE_CHECKING:
    from truckrl.config.schemas import EvaluateConfig
    from truckrl.rl.policy_specs import PolicySpec
    from truckrl.tasks import Quantity

#: Folder of a run dir that default evaluation outputs go to.
EVAL_DIR = "eval"


def default_output(
    checkpoint: Path, difficulty: float, seed: int, env_overrides: dict | None = None
) -> Path:
    """``<run dir>/eval/<difficulty>-<seed>.json`` (difficulty as ``2`` or ``2.5``); with env
    overrides, ``<difficulty>-<seed>-<field>=<value>[-...].json``."""
    from truckrl.rl.session import run_dir_of

    return run_dir_of(checkpoint) / EVAL_DIR / f"{difficulty:g}-{seed}{_tag(env_overrides)}.json"


def _tag(env_overrides: dict | None) -> str:
    """``-<field>=<value>`` per env override, for file names ('' without any)."""
    from truckrl.tasks.config import flat_overrides

    flat = flat_overrides(env_overrides or {})
    tag = "".join(f"-{k.removeprefix('env.')}={v}" for k, v in flat.items())
    return re.sub(r"[^A-Za-z0-9_.=+-]", "_", tag)


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` atomically (a temporary file in the same folder, renamed)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(json.dumps(data, indent=2) + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


#: Difficulty a policy without one of its own (the planner without a checkpoint,
#: ``module:function``, an ONNX file without model card) is scored at when ``difficulty`` is
#: null: the paper's final curriculum level.
PLANNER_DIFFICULTY = 6.0


def evaluate(ec: EvaluateConfig) -> dict:
    """Load, check the output, run, summarise, print and write; return the JSON-ready result.

    With ``policy=planner`` the CEM planner (:mod:`truckrl.planning`) plays the same scenes
    instead of a policy: with the checkpoint's env config and difficulty when one is given (a
    side-by-side comparison), else the default env of ``task`` at difficulty 6; its JSON goes to
    ``planner-<difficulty>-<seed>.json`` (beside the run, or under ``outputs/eval/``).

    Raises:
        CheckpointError: the checkpoint cannot be used (before any episode runs).
        ConfigError: a policy spec that cannot be used (before any episode runs); the output
            cannot be written: before any episode runs when the check finds it, or after
            printing the results when the final write fails.
    """
    from truckrl.rl.checkpoint import resolve_checkpoint
    from truckrl.rl.policy_specs import spec_of

    if ec.threads is not None:  # before any torch work, as truckrl train does
        import torch

        torch.set_num_threads(ec.threads)
    spec = spec_of(ec.policy, ec.checkpoint)
    if ec.checkpoint:
        resolve_checkpoint(ec.checkpoint)  # a wrong path is reported before torchrl loads

    from truckrl.config.fields import ConfigError
    from truckrl.evaluation.categories import (
        format_category_table,
        summarize_by_category,
        task_bins,
    )
    from truckrl.evaluation.rollout import smoothness, summarize

    if spec.kind == "planner":
        summary_head, results, (tol_pos, tol_deg), errors, output, task = _run_planner(ec)
    else:
        summary_head, results, (tol_pos, tol_deg), errors, output, task = _run_policy(ec, spec)
    bins = task_bins(task, results)
    summary = {
        "task": task,
        **summary_head,
        "tolerance_position_m": tol_pos,
        "tolerance_heading_deg": tol_deg,
        "seed": ec.seed,
        **summarize(results, errors),
        "smoothness": smoothness(results) if "motion" in results else None,
        "categories": summarize_by_category(results, bins, errors) if bins else [],
    }
    print_table(summary, errors)
    if summary["smoothness"]:
        print_smoothness(summary["smoothness"])
    print()
    if bins:
        print("by scene category (bins [lo, hi)):")
        print(format_category_table(summary["categories"]))
    else:
        print(f"no per-category table: task {task!r} declares no scene categories")
    print(json.dumps({**summary, "output": str(output)}))
    try:
        write_json(output, {"provenance": provenance(ec.device), **summary})
    except OSError as e:
        sys.stdout.flush()  # the results first, then the one-line error (stderr)
        raise ConfigError(
            f"output={output}: the results above were not written ({e.strerror or e})"
        ) from None
    return {**summary, "output": str(output)}


def _run_policy(ec: EvaluateConfig, spec: PolicySpec):
    """The policy's mean action on the scenes: ``(head, results, tolerance, errors, output,
    task name)``."""
    from truckrl.evaluation.rollout import evaluate_policy
    from truckrl.rl.policy_specs import base_env, resolve_policy
    from truckrl.tasks.config import flat_overrides, with_env_overrides

    policy = resolve_policy(spec, ec.device, base_env(ec.env))
    env_cfg = with_env_overrides(policy.env_config, ec.env, fixed=policy.fixed_env)
    difficulty = ec.difficulty
    if difficulty is None:
        difficulty = PLANNER_DIFFICULTY if policy.difficulty is None else policy.difficulty
    if ec.output:
        output = Path(ec.output)
    elif spec.kind == "checkpoint":
        output = default_output(policy.path, difficulty, ec.seed, ec.env)
    else:
        name = f"{spec.kind}-{spec.name}-{difficulty:g}-{ec.seed}{_tag(ec.env)}.json"
        output = Path("outputs") / EVAL_DIR / name
    check_writable(output, "output")
    results, tolerance, errors = evaluate_policy(
        policy.actor, env_cfg, difficulty, ec.episodes, ec.seed, ec.device
    )
    head: dict = {"policy": spec.kind, "policy_spec": spec.text}
    if spec.kind == "checkpoint":
        head |= {
            "checkpoint": str(policy.path),
            "iteration": int(policy.counters["iteration"]),
            "frames": int(policy.counters["frames"]),
        }
    else:
        head["checkpoint"] = None
        if spec.kind == "onnx":
            head["onnx"] = str(policy.path)
    head |= {"difficulty": difficulty, "env_overrides": flat_overrides(ec.env)}
    return head, results, tolerance, errors, output, env_cfg.task.name


def planner_config():
    """The planner's settings for ``policy=planner``: the defaults of
    :class:`~truckrl.planning.PlannerConfig` (the baseline of docs/planner.md)."""
    from truckrl.planning import PlannerConfig

    return PlannerConfig()


def _run_planner(ec: EvaluateConfig):
    """The planner on the scenes: ``(head, results, tolerance, errors, output, task name)``."""
    import time

    from truckrl.planning import plan_episodes
    from truckrl.rl.policy_specs import base_env
    from truckrl.tasks.config import flat_overrides, with_env_overrides

    if ec.checkpoint:
        from truckrl.rl.policy import load_policy

        policy = load_policy(ec.checkpoint, "cpu")
        env_cfg, path = policy.env_config, policy.path
        difficulty = policy.difficulty if ec.difficulty is None else ec.difficulty
        output = default_output(path, difficulty, ec.seed, ec.env)
        output = output.with_name(f"planner-{output.name}")
    else:
        env_cfg, path = base_env(ec.env), None
        difficulty = PLANNER_DIFFICULTY if ec.difficulty is None else ec.difficulty
        name = f"planner-{difficulty:g}-{ec.seed}{_tag(ec.env)}.json"
        output = Path("outputs") / EVAL_DIR / name
    env_cfg = with_env_overrides(env_cfg, ec.env, fixed=False)
    output = Path(ec.output) if ec.output else output
    check_writable(output, "output")
    t0 = time.perf_counter()
    results, tolerance, errors = plan_episodes(
        env_cfg, difficulty, ec.episodes, ec.seed, planner_config(), ec.device
    )
    head = {
        "checkpoint": str(path) if path else None,
        "policy": "planner",
        "policy_spec": "planner",
        "difficulty": difficulty,
        "planner_seconds": time.perf_counter() - t0,
        "planner_rollouts": int(results["rollouts"]),
        "env_overrides": flat_overrides(ec.env),
    }
    return head, results, tolerance, errors, output, env_cfg.task.name


def print_table(s: dict, errors: tuple[Quantity, ...]) -> None:
    from truckrl.tasks import OUTCOMES

    print(
        f"{s['episodes']} episodes at difficulty {s['difficulty']} "
        f"(tolerance {s['tolerance_position_m']:.3g} m, {s['tolerance_heading_deg']:.3g} deg)"
    )
    print("  ".join(f"{o.name} {s[f'{o.name}_rate']:.3f}" for o in OUTCOMES))
    lo, hi = s["success_ci95"]
    print(f"success 95 % interval {lo:.3f}-{hi:.3f} (Wilson, {s['episodes']} scenes)")
    print(f"{'final error':<30}{'mean':>10}{'p95':>10}")
    for q in errors:
        key = f"{q.key}_{q.shown_unit}"
        print(f"{f'{q.key} [{q.shown_unit}]':<30}{s[f'{key}_mean']:>10.3f}{s[f'{key}_p95']:>10.3f}")


def print_smoothness(sm: dict) -> None:
    """The :func:`~truckrl.evaluation.rollout.smoothness` table: one row per quantity."""
    from truckrl.evaluation.rollout import MOTION, SMOOTHNESS_PERCENTILES

    head = "".join(f"{f'p{p}':>10}" for p in SMOOTHNESS_PERCENTILES)
    print(f"{'|motion| in successes':<30}{head}")
    for key, unit in MOTION:
        row = "".join(f"{sm[f'{key}_{unit}_p{p}']:>10.3f}" for p in SMOOTHNESS_PERCENTILES)
        print(f"{f'{key} [{unit}]':<30}{row}")


def prepare_argv(argv: list[str]) -> list[str]:
    """``env.FIELD=VALUE`` adds a key to the (empty) ``env`` overrides: Hydra spells that
    ``+env.FIELD=VALUE``, so the ``+`` is added here. ``task=NAME`` is short for
    ``env.task.name=NAME`` (eval has no ``task`` group: a policy's env is its own)."""
    from truckrl.cli import plus_overrides

    argv = [f"env.task.name={a[5:]}" if a.startswith("task=") else a for a in argv]
    return plus_overrides(argv, "env.")


@hydra_entry("evaluate", "EvaluateConfig", prepare="truckrl.evaluate:prepare_argv")
def main(ec: EvaluateConfig, raw: DictConfig) -> None:
    evaluate(ec)


if __name__ == "__main__":
    main()
