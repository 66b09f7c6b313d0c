"""Training checkpoints: atomic writes, ``weights_only`` loads, RNG capture.

A checkpoint is a plain dict of tensors, numbers, strings and containers of them, so it loads with
``torch.load(path, weights_only=True)`` (no pickled code). Layout written by ``truckrl.train``::

    {"version": 2,
     "model": state_dict, "ppo": {"optimizer": state_dict, "lr": float},
     "curriculum": {"difficulty", "ema", "promotions", "episodes"},
     "counters": {"iteration", "frames", "wall_time_s", "quality"},
     "rng": {"torch": uint8 tensor, "numpy": {...}, "python": tuple},
     "num_obs": int, "num_beams": int,
     "config": resolved training config (truckrl.config.schemas.TrainConfig) as a YAML string,
     "source": {"commit": str, "dirty": bool}}

:func:`save_training_state` writes it and :func:`load_training_state` reads and checks it; the
policy loader (:mod:`truckrl.rl.policy`) and ``train resume=`` both go through the latter.

Run-dir layout: ``<run_dir>/checkpoints/last.pt`` (plus ``iter_XXXXXX.pt`` when kept). Files get
the mode of any other new file (``0o666`` less the umask), not ``mkstemp``'s ``0o600``.

Every way a file can fail to be a usable checkpoint raises :class:`CheckpointError` with one line
naming the file and the reason: not a PyTorch file (text, YAML...), truncated, holding Python
objects that a ``weights_only`` load refuses (never loaded otherwise), an entry missing or of the
wrong type, counters that do not add up, weights or optimizer state that do not fit the model.
"""

from __future__ import annotations

import math
import os
import pickle
import random
import tempfile
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from truckrl.tasks.config import DEFAULT_TASK

CHECKPOINT_VERSION = 2
CHECKPOINT_DIR = "checkpoints"
LAST_NAME = "last.pt"
#: The checkpoint with the best held-out result (``checkpoint.keep_best``), beside last.pt.
BEST_NAME = "best.pt"
#: Prefix and suffix of the temporary files :func:`save_checkpoint` writes before renaming.
TMP_SUFFIX = ".tmp"


def _file_mode() -> int:
    """Mode of a newly created regular file under the current umask (``0o666 & ~umask``)."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable or not a truckrl checkpoint."""


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` atomically: a temp file in the same dir, then ``os.replace``.

    A process killed mid-write leaves the previous file intact (plus at most a stray temp file).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TMP_SUFFIX, dir=path.parent)
    try:
        os.fchmod(fd, _file_mode())  # mkstemp makes 0o600; the run dir's other files follow umask
        with os.fdopen(fd, "wb") as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


#: ``checkpoint=pretrained[:TASK]``: the trained policies that ship inside the package, one per
#: task folder (``truckrl/tasks/<task>/pretrained.pt``, its model card ``pretrained.md`` beside it).
PRETRAINED_PREFIX = "pretrained"
PRETRAINED_FILE = "pretrained.pt"
TASKS_DIR = Path(__file__).resolve().parent.parent / "tasks"


def pretrained_names() -> list[str]:
    """Tasks with a shipped policy (``truckrl/tasks/<task>/pretrained.pt``)."""
    return sorted(p.parent.name for p in TASKS_DIR.glob(f"*/{PRETRAINED_FILE}"))


def pretrained_path(spec: str) -> Path | None:
    """The shipped file named by ``pretrained`` (the default task's) / ``pretrained:<task>``, or
    None for other specs.

    Raises:
        CheckpointError: ``pretrained:<task>`` names no shipped policy.
    """
    head, sep, name = spec.partition(":")
    if head != PRETRAINED_PREFIX:
        return None
    name = name if sep else DEFAULT_TASK
    p = TASKS_DIR / name / PRETRAINED_FILE
    if not name.isidentifier() or not p.is_file():
        raise CheckpointError(
            f"checkpoint={spec}: no shipped policy {name!r} (shipped: {pretrained_names()})"
        )
    return p


def shipped_task(checkpoint: Path) -> str | None:
    """The task whose shipped policy ``checkpoint`` is, or None for any other file."""
    p = checkpoint.resolve()
    return p.parent.name if p.name == PRETRAINED_FILE and p.parent.parent == TASKS_DIR else None


def resolve_checkpoint(path: str | os.PathLike) -> Path:
    """Map a checkpoint file, a run dir (``<dir>/checkpoints/last.pt``) or
    ``pretrained[:<task>]`` (a policy shipped in the package) to the file.

    Raises:
        CheckpointError: when nothing is there.
    """
    shipped = pretrained_path(str(path)) if not Path(path).exists() else None
    if shipped is not None:
        return shipped
    p = Path(path).expanduser()
    if p.is_dir():
        for candidate in (p / CHECKPOINT_DIR / LAST_NAME, p / LAST_NAME):
            if candidate.is_file():
                return candidate
        raise CheckpointError(
            f"no checkpoint in run dir {p} (looked for {CHECKPOINT_DIR}/{LAST_NAME})"
        )
    if not p.is_file():
        raise CheckpointError(f"checkpoint not found: {p}")
    return p


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> dict:
    """Load a checkpoint file or run dir with ``torch.load(..., weights_only=True)``.

    Raises:
        CheckpointError: missing file, not a PyTorch file, truncated/corrupt, unsafe content, or
            not a truckrl checkpoint (one line saying which).
    """
    p = resolve_checkpoint(path)
    not_torch = _not_a_torch_file(p)
    if not_torch:
        raise CheckpointError(f"{p} is not a truckrl checkpoint: {not_torch}")
    try:
        with warnings.catch_warnings():  # e.g. torch's multi-line note on a foreign pickle protocol
            warnings.simplefilter("ignore")
            state = torch.load(p, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        raise CheckpointError(f"{p} is not a truckrl checkpoint: {_unsafe_reason(e)}") from None
    except (RuntimeError, EOFError, OSError, ValueError, zipfile.BadZipFile) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        first = first.split(". ")[0]  # torch adds sentences of advice
        raise CheckpointError(
            f"cannot read checkpoint {p}: not a truckrl checkpoint, truncated or corrupt ({first})"
        ) from None
    if not isinstance(state, dict) or state.get("version") != CHECKPOINT_VERSION:
        found = state.get("version") if isinstance(state, dict) else type(state).__name__
        raise CheckpointError(
            f"{p} is not a truckrl checkpoint (version {CHECKPOINT_VERSION}; found {found!r})"
        )
    return state


def _not_a_torch_file(p: Path) -> str:
    """Why ``p`` cannot be a file ``torch.save`` wrote ("" when it may be one)."""
    try:
        with open(p, "rb") as f:
            head = f.read(64)
    except OSError as e:
        return f"cannot open it ({e.strerror or e})"
    if head.startswith(b"PK") or head[:1] == b"\x80":  # zip archive (torch >= 1.6) or pickle
        return ""
    if not head:
        return "the file is empty"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "not a PyTorch file (neither a zip archive nor a pickle)"
    first = text.strip().splitlines()[0][:40] if text.strip() else ""
    return f"it is a text file ({first!r}...), not a file written by torch.save"


def _unsafe_reason(e: pickle.UnpicklingError) -> str:
    """The refused content of a ``weights_only`` load, without torch's advice to load unsafely."""
    lines = [ln.strip() for ln in str(e).splitlines()]
    what = next(
        (ln for ln in lines if ln.startswith(("WeightsUnpickler error", "Unsupported"))), ""
    )
    what = what.removeprefix("WeightsUnpickler error:").strip()
    what = what.split(" was not an allowed global")[0]  # drop torch's advice on allowing it
    detail = f" ({what})" if what else ""
    return (
        "it holds Python objects besides tensors and plain values, which a safe load refuses"
        f"{detail}"
    )


def capture_rng() -> dict[str, Any]:
    """RNG states of torch (CPU), numpy and Python ``random`` as weights_only-safe values."""
    # The legacy global generator is what third-party code draws from, hence its state here.
    kind, keys, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    return {
        "torch": torch.get_rng_state(),
        "numpy": {
            "kind": str(kind),
            "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "gauss": float(gauss),
        },
        "python": _to_lists(random.getstate()),
    }


def restore_rng(state: dict[str, Any]) -> None:
    """Inverse of :func:`capture_rng`."""
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state(  # noqa: NPY002
        (n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["gauss"])
    )
    version, internal, gauss_next = state["python"]
    random.setstate((version, tuple(internal), gauss_next))


def _to_lists(x: Any) -> Any:
    return [_to_lists(v) for v in x] if isinstance(x, tuple) else x


#: Entries of ``counters.quality`` (the run's quality_reached record, or None; older
#: checkpoints lack it), each a finite number >= 0.
QUALITY_KEYS = ("minutes", "frames", "iteration", "difficulty", "success_rate")

#: Entries every training checkpoint holds, with their type.
TRAINING_KEYS: dict[str, type] = {
    "model": dict,
    "ppo": dict,
    "curriculum": dict,
    "counters": dict,
    "rng": dict,
    "num_obs": int,
    "num_beams": int,
    "config": str,
}


def save_training_state(
    path: str | os.PathLike,
    *,
    model: torch.nn.Module,
    ppo: Any,
    curriculum: Any,
    counters: dict[str, Any],
    config_yaml: str,
    num_obs: int,
    num_beams: int,
    source: dict[str, Any] | None = None,
    heldout: dict[str, float] | None = None,
) -> Path:
    """Write a training checkpoint atomically (layout in the module doc).

    ``heldout``: the held-out evaluation this checkpoint was kept for (best.pt), stored as
    ``state["heldout"]`` (``difficulty``, ``success_rate``, ``frames``); omitted otherwise.
    """
    state = {
        "version": CHECKPOINT_VERSION,
        "model": model.state_dict(),
        "ppo": ppo.state_dict(),
        "curriculum": curriculum.state_dict(),
        "counters": dict(counters),
        "rng": capture_rng(),
        "num_obs": int(num_obs),
        "num_beams": int(num_beams),
        "config": config_yaml,
        "source": dict(source or {}),
    }
    if heldout is not None:
        state["heldout"] = dict(heldout)
    return save_checkpoint(path, state)


def best_record(path: str | os.PathLike) -> tuple[float, float] | None:
    """``(difficulty, success rate)`` of the held-out evaluation that a best.pt was kept for,
    or None where there is no such file or it holds no record (an unreadable file: None too,
    so a run carries on and replaces it)."""
    p = Path(path)
    if not p.is_file():
        return None
    try:
        h = load_checkpoint(p, "cpu").get("heldout")
        return (float(h["difficulty"]), float(h["success_rate"])) if h else None
    except (CheckpointError, KeyError, TypeError, ValueError):
        return None


def _count_like(v: Any) -> bool:
    """A finite number >= 0 (not a bool)."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0


def load_training_state(
    path: str | os.PathLike, map_location: str | torch.device = "cpu"
) -> dict[str, Any]:
    """Load a training checkpoint and check its entries (:func:`check_training_state`).

    Raises:
        CheckpointError: unreadable, not a truckrl checkpoint, or an entry missing or wrong.
    """
    p = resolve_checkpoint(path)
    state = load_checkpoint(p, map_location)
    check_training_state(state, p)
    state["path"] = p
    return state


def check_training_state(state: dict[str, Any], p: Path | str) -> None:
    """Check every entry of :data:`TRAINING_KEYS` is there with its type, and the counters.

    Raises:
        CheckpointError: naming the file and the first bad entry.
    """
    for key, typ in TRAINING_KEYS.items():
        if key not in state:
            raise CheckpointError(f"{p} is not a usable training checkpoint ({key!r} missing)")
        if not isinstance(state[key], typ) or isinstance(state[key], bool):
            raise CheckpointError(
                f"{p} is not a usable training checkpoint ({key!r} is a "
                f"{type(state[key]).__name__}, not a {typ.__name__})"
            )
    c = state["counters"]
    for key in ("iteration", "frames"):
        v = c.get(key)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise CheckpointError(
                f"{p}: bad counters (counters.{key} = {v!r}; a whole number >= 0 is needed)"
            )
    wall = c.get("wall_time_s")
    if (
        not isinstance(wall, int | float)
        or isinstance(wall, bool)
        or not math.isfinite(wall)
        or wall < 0
    ):
        raise CheckpointError(f"{p}: bad counters (counters.wall_time_s = {wall!r}; seconds >= 0)")
    quality = c.get("quality")
    if quality is not None and not (
        isinstance(quality, dict) and all(_count_like(quality.get(k)) for k in QUALITY_KEYS)
    ):
        raise CheckpointError(
            f"{p}: bad counters (counters.quality = {quality!r}; None or "
            f"{{{', '.join(QUALITY_KEYS)}}}, each a number >= 0)"
        )
    if (c["iteration"] == 0) != (c["frames"] == 0) or c["frames"] < c["iteration"]:
        raise CheckpointError(
            f"{p}: bad counters (iteration {c['iteration']} with {c['frames']} frames)"
        )
    for key in ("num_obs", "num_beams"):
        if state[key] < 1:
            raise CheckpointError(f"{p}: bad metadata ({key} = {state[key]})")
    for key in ("difficulty", "ema", "promotions", "episodes"):
        v = state["curriculum"].get(key)
        if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v) or v < 0:
            raise CheckpointError(f"{p}: bad curriculum state (curriculum.{key} = {v!r})")
    if not isinstance(state["ppo"].get("optimizer"), dict) or "lr" not in state["ppo"]:
        raise CheckpointError(f"{p}: ppo state lacks 'optimizer' or 'lr'")
    if not all(k in state["rng"] for k in ("torch", "numpy", "python")):
        raise CheckpointError(f"{p}: rng state lacks one of torch, numpy, python")


def load_weights(model: torch.nn.Module, weights: dict[str, Any], p: Path | str) -> None:
    """``model.load_state_dict(weights)``, or :class:`CheckpointError` saying what does not fit."""
    try:
        model.load_state_dict(weights)
    except (RuntimeError, KeyError, TypeError, ValueError) as e:
        lines = [ln.strip() for ln in str(e).strip().splitlines() if ln.strip()]
        detail = lines[1] if len(lines) > 1 else (lines[0] if lines else type(e).__name__)
        raise CheckpointError(
            f"{p}: the weights do not fit the model its config describes ({detail})"
        ) from None


def _check_sizes(
    state: dict[str, Any], num_obs: int, num_beams: int, env: str, settable: bool = False
) -> None:
    """One line where the weights do not fit ``num_obs`` / ``num_beams``; ``settable``: the
    caller's env takes ``env.lidar.num_beams`` from the command line, so the line names it."""
    if (state["num_obs"], state["num_beams"]) != (num_obs, num_beams):
        hint = (
            f" (set env.lidar.num_beams={state['num_beams']})"
            if settable and state["num_obs"] == num_obs
            else ""
        )
        raise CheckpointError(
            f"{state['path']}: the weights are for {state['num_obs']} observations and "
            f"{state['num_beams']} LiDAR beams; {env} gives {num_obs} and {num_beams}{hint}"
        )


def load_init_weights(
    state: dict[str, Any], model: torch.nn.Module, num_obs: int, num_beams: int
) -> None:
    """Start a new run from another checkpoint's network weights (``train init=``): the model,
    log-std included; not its optimizer, curriculum, counters or config.

    Args:
        state: from :func:`load_training_state`.
        model: built from this run's config; must have the same layers and sizes.
        num_obs, num_beams: this run's env observation and LiDAR sizes.

    Raises:
        CheckpointError: one line naming what does not fit.
    """
    _check_sizes(state, num_obs, num_beams, "this run's env", settable=True)
    load_weights(model, state["model"], state["path"])


def check_optimizer_state(
    optimizer: torch.optim.Optimizer, saved: dict[str, Any], p: Path | str, steps: int | None
) -> None:
    """Check a saved optimizer state fits ``optimizer``'s parameters (count and shapes) and, with
    ``steps``, that every parameter took exactly that many steps.

    ``Optimizer.load_state_dict`` checks only the number of parameters per group: the state of
    another model of the same depth would load and fail at the first step.

    Raises:
        CheckpointError: naming the first parameter whose state does not fit.
    """
    params = [q for g in optimizer.param_groups for q in g["params"]]
    groups = saved.get("param_groups")
    state = saved.get("state")
    if not isinstance(groups, list) or not isinstance(state, dict):
        raise CheckpointError(f"{p}: the optimizer state lacks 'param_groups' or 'state'")
    ids = [i for g in groups if isinstance(g, dict) for i in g.get("params", [])]
    if len(ids) != len(params):
        raise CheckpointError(
            f"{p}: the optimizer state is for {len(ids)} parameters, the model has {len(params)}"
        )
    for n, (i, param) in enumerate(zip(ids, params, strict=True)):
        for name, value in state.get(i, {}).items():
            if name != "step" and torch.is_tensor(value) and value.shape != param.shape:
                raise CheckpointError(
                    f"{p}: the optimizer state does not fit the model (parameter {n}: "
                    f"{name} {tuple(value.shape)} vs {tuple(param.shape)})"
                )
    for i in ids if steps is not None else ():
        took = int(state[i]["step"]) if "step" in state.get(i, {}) else 0
        if took != steps:
            raise CheckpointError(
                f"{p}: bad counters (the optimizer took {took} steps; iteration x epochs x "
                f"minibatches = {steps})"
            )


def restore_training(
    state: dict[str, Any],
    model: torch.nn.Module,
    ppo: Any,
    curriculum: Any,
    num_obs: int,
    num_beams: int,
    steps_per_iteration: int,
) -> None:
    """Load a checkpoint into a new model, PPO learner and curriculum, checking first that it
    fits: observation and beam counts, weights, optimizer state shapes, and the optimizer's step
    count against ``counters.iteration x steps_per_iteration`` (epochs x minibatches).

    Raises:
        CheckpointError: one line naming the first thing that does not fit.
    """
    p = state["path"]
    _check_sizes(state, num_obs, num_beams, "its config's env")
    load_weights(model, state["model"], p)
    steps = state["counters"]["iteration"] * steps_per_iteration
    check_optimizer_state(ppo.optimizer, state["ppo"]["optimizer"], p, steps)
    try:
        ppo.load_state_dict(state["ppo"])
        curriculum.load_state_dict(state["curriculum"])
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(
            f"{p}: optimizer or curriculum state does not load ({first})"
        ) from None
