"""Training checkpoints: atomic writes, ``weights_only`` loads, RNG capture.

A checkpoint is a plain dict of tensors, numbers, strings and containers of them, so it loads with
``torch.load(path, weights_only=True)`` (no pickled code). Layout written by ``truckrl.train``::

    {"version": 2,
     "model": state_dict, "ppo": {"optimizer": state_dict, "lr": float},
     "curriculum": {"difficulty", "ema", "promotions", "episodes"},
     "counters": {"iteration", "frames", "wall_time_s"},
     "rng": {"torch": uint8 tensor, "numpy": {...}, "python": tuple},
     "num_obs": int, "num_beams": int,
     "config": resolved training config (truckrl.configs.TrainConfig) as a YAML string,
     "source": {"commit": str, "dirty": bool}}

:func:`save_training_state` writes it and :func:`load_training_state` reads and checks it; the
policy loader (:mod:`truckrl.agent.policy`) and ``train resume=`` both go through the latter.

Run-dir layout: ``<run_dir>/checkpoints/last.pt`` (plus ``iter_XXXXXX.pt`` when kept).
"""

from __future__ import annotations

import os
import pickle
import random
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

CHECKPOINT_VERSION = 2
CHECKPOINT_DIR = "checkpoints"
LAST_NAME = "last.pt"


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable or not a truckrl checkpoint."""


def save_checkpoint(path: str | os.PathLike, state: dict[str, Any]) -> Path:
    """Write ``state`` to ``path`` atomically: a temp file in the same dir, then ``os.replace``.

    A process killed mid-write leaves the previous file intact (plus at most a stray temp file).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def resolve_checkpoint(path: str | os.PathLike) -> Path:
    """Map a checkpoint file or a run dir (``<dir>/checkpoints/last.pt``) to the file.

    Raises:
        CheckpointError: when nothing is there.
    """
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
        CheckpointError: missing file, corrupt/truncated file, or not a truckrl checkpoint.
    """
    p = resolve_checkpoint(path)
    try:
        state = torch.load(p, map_location=map_location, weights_only=True)
    except (RuntimeError, EOFError, OSError, pickle.UnpicklingError, zipfile.BadZipFile) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"cannot read checkpoint {p}: {first}") from None
    if not isinstance(state, dict) or state.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{p} is not a truckrl checkpoint (version {CHECKPOINT_VERSION})")
    return state


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
) -> Path:
    """Write a training checkpoint atomically (layout in the module doc)."""
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
    return save_checkpoint(path, state)


def load_training_state(
    path: str | os.PathLike, map_location: str | torch.device = "cpu"
) -> dict[str, Any]:
    """Load a training checkpoint and check it has every entry of :data:`TRAINING_KEYS`.

    Raises:
        CheckpointError: unreadable, not a truckrl checkpoint, or an entry missing or mistyped.
    """
    p = resolve_checkpoint(path)
    state = load_checkpoint(p, map_location)
    for key, typ in TRAINING_KEYS.items():
        if not isinstance(state.get(key), typ):
            raise CheckpointError(f"{p} is not a usable training checkpoint ({key!r} missing)")
    state["path"] = p
    return state
