"""``truckrl export``: a trained policy as a standalone ONNX or TorchScript model.

    truckrl export checkpoint=outputs/DATE/TIME                      # -> <run>/export/policy.onnx
    truckrl export checkpoint=outputs/DATE/TIME format=torchscript out=policy.pt

The exported model is the deterministic actor: ``(observation [B, 26], lidar [B, R]) -> action
[B, 2]``, float32, any batch size B. The action is the **raw mean of the Gaussian policy**, not
clamped: the environment clamps every action to ``[-1, 1]`` before use (and zeroes non-finite
ones), so a controller running the model must do the same. Inputs are exactly the env's
``observation`` and ``lidar`` entries (the table in :mod:`truckrl.env`).

The model carries a JSON description (:func:`model_card`): the observation table (index ->
meaning, normalisation), the LiDAR beam angles and range scale, the action's meaning in the
checkpoint's control mode, the step time, and where it came from. ONNX keeps it in the model's
``metadata_props`` (key ``truckrl``; ``onnxruntime``: ``session.get_modelmeta().custom_metadata_map``),
TorchScript in the extra file ``truckrl.json`` (``torch.jit.load(path, _extra_files={"truckrl.json":
""})``).

ONNX needs the ``export`` extra (``pip install 'truckrl[export]'``: onnx, onnxscript; onnxruntime to
run it). Fields: :class:`ExportConfig`. A missing or unusable checkpoint, or a missing
exporter, prints one line and exits with code 2.
"""

from __future__ import annotations

if __name__ == "__main__":  # answer --help before the imports below load torch
    from truckrl.cli import exit_on_help

    exit_on_help("export")

import contextlib
import importlib.util
import json
import logging
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig
from torch import Tensor, nn

from truckrl.cli import hydra_entry
from truckrl.config.fields import ConfigError, param, validate
from truckrl.config.schemas import structured
from truckrl.rl.network import GaussianHead, TwoBranchTrunk
from truckrl.rl.policy import LoadedPolicy, load_policy
from truckrl.rl.session import run_dir_of
from truckrl.sim.control import commanded
from truckrl.sim.lidar import beam_angles
from truckrl.tasks import EnvConfig, make_task
from truckrl.tasks.base import OBSERVED_PARAMS
from truckrl.tasks.config import SENSOR_SCALE

FORMATS = ("onnx", "torchscript")
SUFFIX = {"onnx": ".onnx", "torchscript": ".pt"}
#: Key of the JSON model card (ONNX metadata key; TorchScript extra file ``truckrl.json``).
CARD_KEY = "truckrl"


@dataclass
class ExportConfig:
    """``truckrl export``: write a checkpoint's deterministic actor to a file."""

    checkpoint: str | None = param(None, doc="checkpoint file or run dir (required)")
    format: str = param("onnx", choices=FORMATS, doc="onnx | torchscript")
    out: str | None = param(None, doc="output file; null: <run dir>/export/policy.onnx or .pt")
    opset: int | None = param(None, lo=17, hi=100, doc="ONNX opset; null: the exporter's default")

    def __post_init__(self) -> None:
        validate(self)
        if not self.checkpoint:
            raise ConfigError("checkpoint is required: checkpoint=<file or run dir>")


def register_schema() -> None:
    """Register :class:`ExportConfig` as ``export_schema`` (``truckrl/conf/export.yaml`` extends it)."""
    from hydra.core.config_store import ConfigStore

    ConfigStore.instance().store(name="export_schema", node=structured(ExportConfig))


class DeterministicActor(nn.Module):
    """The policy's mean action: ``(observation [B, F], lidar [B, R]) -> action [B, A]``.

    The same modules (shared weights) as the TorchRL actor under
    ``ExplorationType.DETERMINISTIC``, without tensordicts, sampling or clamping.
    """

    def __init__(self, actor: nn.Module) -> None:
        super().__init__()
        trunks = [m for m in actor.modules() if isinstance(m, TwoBranchTrunk)]
        heads = [m for m in actor.modules() if isinstance(m, GaussianHead)]
        if len(trunks) != 1 or len(heads) != 1:
            raise TypeError("expected an actor with one TwoBranchTrunk and one GaussianHead")
        self.trunk, self.head = trunks[0], heads[0]

    def forward(self, observation: Tensor, lidar: Tensor) -> Tensor:
        loc, _ = self.head(self.trunk(observation, lidar))
        return loc


# ---------------------------------------------------------------------------------- model card
def observation_table(env_cfg: EnvConfig) -> list[dict[str, Any]]:
    """One row per numeric observation index: ``{"index", "meaning", "normalisation"}``.

    The same table as the :mod:`truckrl.env` docstring, with the vehicle-parameter ranges and the
    control mode's limits of ``env_cfg`` filled in.
    """
    scale = f"/ {SENSOR_SCALE:g} m"
    limit = "/ its per-truck limit"
    rows = [
        ("goal rear axle x in the tractor frame (forward) [m]", scale),
        ("goal rear axle y in the tractor frame (left) [m]", scale),
        ("sin(goal heading - tractor heading)", "-"),
        ("cos(goal heading - tractor heading)", "-"),
        ("sin(goal heading - trailer heading)", "-"),
        ("cos(goal heading - trailer heading)", "-"),
        ("sin(articulation angle)", "-"),
        ("cos(articulation angle)", "-"),
        ("speed [m/s]", limit),
        ("acceleration [m/s^2]", limit),
        ("jerk [m/s^3]", limit),
        ("steering angle [rad]", limit),
        ("steering rate [rad/s]", limit),
        ("steering acceleration [rad/s^2]", limit),
    ]
    (_, lon_limit), (_, lat_limit) = commanded(
        env_cfg.control.longitudinal, env_cfg.control.lateral
    )
    bounds = env_cfg.vehicle.bounds()
    for key, what in [(k, k) for k in OBSERVED_PARAMS] + [
        (lon_limit, f"{lon_limit} (limit of the longitudinal command)"),
        (lat_limit, f"{lat_limit} (limit of the lateral command)"),
    ]:
        lo, hi = bounds[key]
        rows.append((what.replace("_", " "), f"[{lo:g}, {hi:g}] -> [-1, 1]"))
    task = make_task(env_cfg)
    rows += [(f"task extra {i} ({task.name})", "-") for i in range(task.num_extras)]
    return [{"index": i, "meaning": m, "normalisation": n} for i, (m, n) in enumerate(rows)]


def model_card(loaded: LoadedPolicy, fmt: str) -> dict[str, Any]:
    """The JSON description stored with an exported model (see the module docstring)."""
    cfg = loaded.env_config
    (lon_q, lon_limit), (lat_q, lat_limit) = commanded(
        cfg.control.longitudinal, cfg.control.lateral
    )
    angles = beam_angles(cfg.lidar.num_beams, cfg.lidar.fov)
    return {
        "format": fmt,
        "model": "truckrl deterministic actor (mean of the Gaussian policy)",
        "inputs": {
            "observation": {
                "shape": ["batch", len(observation_table(cfg))],
                "dtype": "float32",
                "table": observation_table(cfg),
            },
            "lidar": {
                "shape": ["batch", cfg.lidar.num_beams],
                "dtype": "float32",
                "meaning": "first-hit range of each beam / max_range_m, in [0, 1]",
                "max_range_m": cfg.lidar.max_range,
                "beam_angles_deg": [round(math.degrees(float(a)), 6) for a in angles],
                "beam_angles_from": "the tractor heading, counter-clockwise; origin: tractor body centre",
            },
        },
        "output": {
            "action": {
                "shape": ["batch", 2],
                "dtype": "float32",
                "meaning": [
                    f"longitudinal command: {lon_q} / {lon_limit} (control {cfg.control.longitudinal})",
                    f"lateral command: {lat_q} / {lat_limit} (control {cfg.control.lateral})",
                ],
                "clamp": "not applied: clamp to [-1, 1] (and replace non-finite values by 0) "
                "as the environment does",
            }
        },
        "dt_s": cfg.dt,
        "task": cfg.task.name,
        "difficulty": loaded.difficulty,
        "checkpoint": str(loaded.path),
        "counters": loaded.counters,
    }


# ---------------------------------------------------------------------------------- export
def example_inputs(loaded: LoadedPolicy, batch: int = 2) -> tuple[Tensor, Tensor]:
    cfg = loaded.env_config
    num_obs = len(observation_table(cfg))
    return torch.zeros(batch, num_obs), torch.zeros(batch, cfg.lidar.num_beams)


def export_onnx(
    model: DeterministicActor, inputs: tuple[Tensor, Tensor], card: dict, out: Path, opset=None
) -> None:
    """Write ``model`` as ONNX (torch.export-based exporter) with a dynamic batch dimension."""
    missing = [m for m in ("onnx", "onnxscript") if importlib.util.find_spec(m) is None]
    if missing:
        raise ConfigError(
            f"format=onnx needs {' and '.join(missing)}: pip install 'truckrl[export]' "
            "(or use format=torchscript)"
        )
    batch = torch.export.Dim("batch")
    with quiet_exporter():
        program = torch.onnx.export(
            model,
            inputs,
            input_names=["observation", "lidar"],
            output_names=["action"],
            dynamic_shapes=({0: batch}, {0: batch}),
            opset_version=opset,
            dynamo=True,
            verbose=False,
        )
    program.model.metadata_props[CARD_KEY] = json.dumps(card)
    program.save(str(out), external_data=False)


def export_torchscript(
    model: DeterministicActor, inputs: tuple[Tensor, Tensor], card: dict, out: Path
) -> None:
    """Write ``model`` as TorchScript (traced; the batch size stays free)."""
    with quiet_exporter():
        traced = torch.jit.trace(model, inputs)
        torch.jit.save(traced, str(out), _extra_files={f"{CARD_KEY}.json": json.dumps(card)})


@contextlib.contextmanager
def quiet_exporter():
    """Silence the exporters' progress logs and their known, harmless warnings.

    torch 2.13 marks ``torch.jit`` deprecated (TorchScript still loads and runs; ONNX is the
    default format here); the ONNX exporter logs every graph pass at INFO level (shown under
    Hydra's logging), warns that torchvision ops are not registered and that the shared batch axis
    keeps one name.
    """
    loggers = [logging.getLogger(n) for n in ("onnx_ir", "onnxscript", "torch.onnx")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings(
                "ignore", r"`torch\.jit\.\w+` is deprecated", DeprecationWarning
            )
            warnings.filterwarnings("ignore", r"`isinstance\(treespec, LeafSpec\)`", FutureWarning)
            warnings.filterwarnings("ignore", r"# The axis name: .* will not be used", UserWarning)
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def default_out(loaded: LoadedPolicy, fmt: str) -> Path:
    ckpt = loaded.path
    run_dir = run_dir_of(ckpt)
    return run_dir / "export" / f"policy{SUFFIX[fmt]}"


@torch.no_grad()
def export(cfg: ExportConfig) -> Path:
    """Load ``cfg.checkpoint`` and write its deterministic actor; returns the file written."""
    loaded = load_policy(cfg.checkpoint, "cpu")
    model = DeterministicActor(loaded.actor).eval()
    out = Path(cfg.out) if cfg.out else default_out(loaded, cfg.format)
    out.parent.mkdir(parents=True, exist_ok=True)
    card = model_card(loaded, cfg.format)
    inputs = example_inputs(loaded)
    if cfg.format == "onnx":
        export_onnx(model, inputs, card, out, cfg.opset)
    else:
        export_torchscript(model, inputs, card, out)
    return out


register_schema()


@hydra_entry("export", ExportConfig)
def main(cfg: ExportConfig, raw: DictConfig) -> None:
    out = export(cfg)
    print(f"export: {out} ({cfg.format}; observation, lidar -> action = raw policy mean)")


if __name__ == "__main__":
    main()
