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

The card also holds the checkpoint's full env config (``env_config``) and curriculum difficulty,
so ``truckrl eval policy=onnx:FILE`` and ``truckrl play policy=onnx:FILE`` drive the file in the
same env (:mod:`truckrl.rl.policy_specs`).

Before reporting success the export verifies what it wrote (:func:`verify`): the ONNX checker
(``onnx.checker.check_model``, full check), the file's input and output names and shapes against
the env, and a parity check: onnxruntime (TorchScript: ``torch.jit.load``) on a batch of real
observations of the env (:func:`verification_inputs`: :data:`VERIFY_TRUCKS` trucks over
:data:`VERIFY_STEPS` steps of the policy) must give the torch policy's mean action within
:data:`VERIFY_ATOL`. The file is written under a temporary name and renamed to ``out`` only once
verified: a file that fails is removed, an older file at ``out`` stays, and the command prints
one line ``error: ...`` and exits with code 1 (a failed export, not a bad input).

ONNX needs the ``export`` extra (``pip install 'truckrl[export]'``: onnx, onnxscript, and
onnxruntime to verify and run it). Fields: :class:`ExportConfig`. A missing or unusable
checkpoint, or a missing exporter package, prints one line and exits with code 2.
"""

from __future__ import annotations

if __name__ == "__main__":  # answer --help before the imports below load torch
    from truckrl.cli import exit_on_help

    exit_on_help("export")

import contextlib
import dataclasses
import importlib.util
import json
import logging
import math
import os
import sys
import tempfile
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
from truckrl.rl.checkpoint import _file_mode as file_mode  # mode under the umask
from truckrl.rl.network import GaussianHead, TwoBranchTrunk
from truckrl.rl.policy import LoadedPolicy, load_policy

# CARD_KEY: the key of the JSON model card (ONNX metadata key; TorchScript extra file
# ``truckrl.json``), the one truckrl.rl.policy_specs reads
from truckrl.rl.policy_specs import CARD_ENV, CARD_KEY, check_onnx_io, onnx_session
from truckrl.rl.session import run_dir_of
from truckrl.sim.control import commanded
from truckrl.sim.lidar import beam_angles
from truckrl.tasks import EnvConfig, make_task
from truckrl.tasks.base import OBSERVED_PARAMS
from truckrl.tasks.config import SENSOR_SCALE

FORMATS = ("onnx", "torchscript")
SUFFIX = {"onnx": ".onnx", "torchscript": ".pt"}
#: Largest ``|exported - torch|`` action difference the verification accepts (float32 kernels
#: of two runtimes differ by ~1e-6 on these small networks; a wrong weight or op by far more).
VERIFY_ATOL = 1e-4
#: Trucks and policy steps whose observations the parity check feeds both models.
VERIFY_TRUCKS = 64
VERIFY_STEPS = 10
#: Exit code of a written file that fails its verification (bad input is 2).
VERIFY_EXIT = 1


class ExportVerificationError(RuntimeError):
    """The written file does not pass the ONNX checker or does not compute the policy's action."""


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
        CARD_ENV: dataclasses.asdict(cfg),
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
def verification_inputs(loaded: LoadedPolicy) -> tuple[Tensor, Tensor]:
    """Real observations ``([M, F], [M, R])``: :data:`VERIFY_TRUCKS` trucks of the checkpoint's env
    (seed 0, its curriculum difficulty) at reset and after each of :data:`VERIFY_STEPS` steps of
    the policy's mean action, ``M = VERIFY_TRUCKS * (VERIFY_STEPS + 1)``. Zeros or random inputs
    would miss the ranges a controller sees."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from truckrl.env import TruckEnv

    cfg = dataclasses.replace(loaded.env_config, compile=False)
    env = TruckEnv(num_envs=VERIFY_TRUCKS, config=cfg, seed=0)
    env.set_difficulty(loaded.difficulty)
    td = env.reset()
    obs, lidar = [td["observation"]], [td["lidar"]]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(VERIFY_STEPS):
            td = env.step(loaded.actor(td))["next"]  # ended trucks reset automatically
            obs.append(td["observation"])
            lidar.append(td["lidar"])
    env.close()
    return torch.cat(obs).float(), torch.cat(lidar).float()


@torch.no_grad()
def verify(
    path: Path, fmt: str, model: DeterministicActor, loaded: LoadedPolicy
) -> tuple[float, int]:
    """Check the written file (module docstring); return ``(max |action difference|, rows)``.

    Raises:
        ExportVerificationError: the ONNX checker rejects the file, its inputs/outputs do not fit
            the env, or its actions differ from the torch policy's by more than
            :data:`VERIFY_ATOL` (or are not finite).
    """
    obs, lidar = verification_inputs(loaded)
    want = model(obs, lidar).numpy()
    if fmt == "onnx":
        import onnx

        try:
            onnx.checker.check_model(str(path), full_check=True)
        except onnx.checker.ValidationError as e:
            raise ExportVerificationError(f"the ONNX checker rejects it: {_first(e)}") from None
        try:
            session = onnx_session(path, "export")
            check_onnx_io(session, loaded.env_config, "export")
        except ConfigError as e:
            raise ExportVerificationError(_first(e)) from None
        (got,) = session.run(["action"], {"observation": obs.numpy(), "lidar": lidar.numpy()})
        runtime = "onnxruntime"
    else:
        got = torch.jit.load(str(path))(obs, lidar).numpy()
        runtime = "torch.jit.load"
    diff = float(abs(got - want).max()) if got.shape == want.shape else math.inf
    if not diff <= VERIFY_ATOL:  # NaN fails too
        raise ExportVerificationError(
            f"{runtime}'s actions differ from the torch policy's by up to {diff:.3g} on "
            f"{len(obs)} real observations (tolerance {VERIFY_ATOL:g})"
        )
    return diff, len(obs)


def export(cfg: ExportConfig) -> Path:
    """Load ``cfg.checkpoint``, write its deterministic actor and verify the file
    (:func:`export_verified`); returns the file written."""
    return export_verified(cfg)[0]


def _first(e: Exception) -> str:
    """The first line of an exception's message (its type when it has none)."""
    return str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__


@torch.no_grad()
def export_verified(cfg: ExportConfig) -> tuple[Path, float, int]:
    """Load ``cfg.checkpoint``, write its deterministic actor and verify the file
    (:func:`verify`); returns ``(file written, max |action difference|, observations)``.

    Raises:
        ConfigError: a missing exporter or onnxruntime (before anything is written).
        ExportVerificationError: the file failed its verification; nothing is left at ``out``
            from this export (an older file there is kept).
    """
    if cfg.format == "onnx" and importlib.util.find_spec("onnxruntime") is None:
        raise ConfigError(
            "format=onnx needs onnxruntime to verify the file: pip install 'truckrl[export]' "
            "(or use format=torchscript)"
        )
    loaded = load_policy(cfg.checkpoint, "cpu")
    model = DeterministicActor(loaded.actor).eval()
    out = Path(cfg.out) if cfg.out else default_out(loaded, cfg.format)
    out.parent.mkdir(parents=True, exist_ok=True)
    card = model_card(loaded, cfg.format)
    inputs = example_inputs(loaded)
    fd, name = tempfile.mkstemp(dir=out.parent, prefix=f".{out.stem}.", suffix=out.suffix)
    os.close(fd)
    tmp = Path(name)
    try:
        if cfg.format == "onnx":
            export_onnx(model, inputs, card, tmp, cfg.opset)
        else:
            export_torchscript(model, inputs, card, tmp)
        diff, rows = verify(tmp, cfg.format, model, loaded)
        os.chmod(tmp, file_mode())  # mkstemp's 0o600 -> what a plain open() would have made
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out, diff, rows


register_schema()


@hydra_entry("export", ExportConfig)
def main(cfg: ExportConfig, raw: DictConfig) -> None:
    try:
        out, diff, rows = export_verified(cfg)
    except ExportVerificationError as e:
        sys.stdout.flush()
        print(f"error: export not written, verification failed: {e}", file=sys.stderr, flush=True)
        sys.exit(VERIFY_EXIT)
    print(f"export: {out} ({cfg.format}; observation, lidar -> action = raw policy mean)")
    check = "onnx checker, onnxruntime" if cfg.format == "onnx" else "torch.jit.load"
    print(f"verified: {check}: max |action - torch policy's| = {diff:.2g} on {rows} real "
          f"observations (tolerance {VERIFY_ATOL:g})")  # fmt: skip


if __name__ == "__main__":
    main()
