"""One parser and loader of policy specs: what ``truckrl eval policy=...`` and ``truckrl play
policy=...`` drive.

==========================  ===================================================================
spec                        the policy
==========================  ===================================================================
``checkpoint:PATH``         a training checkpoint (file or run dir) through
                            :func:`~truckrl.rl.policy.load_policy`: its mean action, its env config
                            and curriculum difficulty. ``checkpoint=PATH`` is the short form.
``pretrained[:TASK]``       the policy shipped for ``TASK`` (default: the default task's)
``onnx:FILE``               a model ``truckrl export`` wrote, run by onnxruntime on the CPU
                            (:class:`OnnxPolicy`); env config and difficulty from its model card
                            (metadata key ``truckrl``), or, in a file without one, the task's
                            default env
``planner``                 the CEM planner baseline (``truckrl.planning``): no actor here, the
                            commands drive it themselves
``module:function``         ``function`` of the importable ``module`` (the working directory is
                            searched too) is a factory: called with the keyword arguments it
                            names among ``env_config`` and ``device``, it returns a policy in
                            either convention of :func:`~truckrl.evaluation.rollout.as_policy`;
                            env config: the task's default (``task=``) with ``env.*`` overrides
==========================  ===================================================================

Every way a spec can be wrong is a :class:`~truckrl.config.fields.ConfigError` with one line
naming the spec (exit code 2 on the command line), raised before any episode runs: an unknown
scheme, a missing file, a module that does not import, a function that is not there or returns
no callable, an ONNX file whose inputs and output are not ``observation [B, F]``, ``lidar [B, R]``
-> ``action [B, 2]`` for the env's ``F`` features and ``R`` beams. A checkpoint that cannot be
used is a :class:`~truckrl.rl.checkpoint.CheckpointError` (also exit code 2).
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from truckrl.config.fields import ConfigError, build
from truckrl.evaluation.rollout import as_policy
from truckrl.tasks import EnvConfig, make_task, task_names

#: The spec forms, as error messages list them.
SPEC_FORMS = "checkpoint:PATH | pretrained[:TASK] | onnx:FILE | planner | module:function"
#: Metadata key of the model card ``truckrl export`` writes (``truckrl.export.CARD_KEY``).
CARD_KEY = "truckrl"
#: The model card's entry holding the full env config (``dataclasses.asdict`` of it).
CARD_ENV = "env_config"
#: ONNX tensor names: the env's observation entries in, the action out.
ONNX_INPUTS = ("observation", "lidar")
ONNX_OUTPUT = "action"


@dataclass(frozen=True)
class PolicySpec:
    """A parsed spec.

    Attributes:
        kind: "checkpoint" (files, run dirs and ``pretrained[:TASK]``), "onnx", "planner" or
            "module".
        target: what to load: the checkpoint path or ``pretrained[:TASK]``, the ONNX file,
            ``module:function``; "" for the planner.
        text: the spec as written.
    """

    kind: str
    target: str
    text: str

    @property
    def name(self) -> str:
        """A short name for file names: the file stem, ``module.function`` or the kind."""
        if self.kind == "onnx":
            return Path(self.target).stem
        if self.kind == "module":
            return self.target.replace(":", ".")
        return self.kind


def _dotted(name: str) -> bool:
    return bool(name) and all(part.isidentifier() for part in name.split("."))


def parse_policy_spec(text: str, field: str = "policy") -> PolicySpec:
    """Parse ``text`` (one of :data:`SPEC_FORMS`); no file is opened here.

    Raises:
        ConfigError: an unknown scheme or an empty path (one line naming ``field``).
    """
    text = str(text).strip()
    head, sep, rest = text.partition(":")
    if text == "planner":
        return PolicySpec("planner", "", text)
    if head == "pretrained":
        return PolicySpec("checkpoint", text, text)
    if head in ("checkpoint", "onnx") and sep:
        if not rest.strip():
            raise ConfigError(f"{field} = {text!r}: give the file after '{head}:'")
        return PolicySpec(head, rest.strip(), text)
    if sep and _dotted(head) and rest.isidentifier():
        return PolicySpec("module", text, text)
    raise ConfigError(f"{field} = {text!r} is not a policy; use {SPEC_FORMS}")


def spec_of(policy: str | None, checkpoint: str | None) -> PolicySpec | None:
    """The spec that a command's ``policy`` and ``checkpoint`` fields name together.

    ``policy=checkpoint`` (eval's default) means the ``checkpoint`` field;
    ``checkpoint=PATH`` alone is short for ``policy=checkpoint:PATH``; with ``policy=planner``
    the checkpoint only says whose env config and scenes the planner gets. None: neither is set.

    Raises:
        ConfigError: a bad spec, or a policy other than the planner given with a checkpoint.
    """
    if policy in (None, "", "checkpoint"):
        return parse_policy_spec(f"checkpoint:{checkpoint}") if checkpoint else None
    spec = parse_policy_spec(policy)
    if checkpoint and spec.kind != "planner":
        raise ConfigError(
            f"policy = {policy!r} and checkpoint = {checkpoint!r}: give one "
            f"(checkpoint=PATH is short for policy=checkpoint:PATH)"
        )
    return spec


@dataclass
class ResolvedPolicy:
    """A loaded policy with what is needed to run it.

    Attributes:
        spec: what was asked for.
        actor: ``td [N] -> td [N]`` writing "action" ``[N, 2]`` (a TorchRL actor: its mean under
            ``ExplorationType.DETERMINISTIC``); None for the planner.
        env_config: the env config it runs in.
        difficulty: its own curriculum difficulty (a checkpoint's, an ONNX card's), else None.
        path: the checkpoint or ONNX file, else None.
        counters: a checkpoint's training counters, else None.
        fixed_env: the task and beam count are the policy's (``env.*`` overrides may not change
            them): true for checkpoints and ONNX files.
    """

    spec: PolicySpec
    actor: Callable[[TensorDictBase], TensorDictBase] | None
    env_config: EnvConfig
    difficulty: float | None = None
    path: Path | None = None
    counters: dict | None = None
    fixed_env: bool = False


def base_env(overrides: dict | None) -> EnvConfig:
    """The default env config of the task that env overrides name (``env.task.name``, which
    ``task=NAME`` sets on eval's command line), else of the default task: the env of a policy
    that brings none, before the overrides are merged in.

    Raises:
        ConfigError: no task folder of that name.
    """
    task = (overrides or {}).get("task")
    name = task.get("name") if isinstance(task, dict) else None
    if name is None:
        return EnvConfig()
    if name not in task_names():
        raise ConfigError(f"task = {name!r} is not a task; known: {task_names()}")
    return build(EnvConfig, {"task": {"name": name}}, "env")


def resolve_policy(
    spec: PolicySpec,
    device: str | torch.device = "cpu",
    env_config: EnvConfig | None = None,
) -> ResolvedPolicy:
    """Load what ``spec`` names.

    Args:
        env_config: the env of a policy that brings none (``module:function``, the planner, an
            ONNX file without a model card); default: the default task's.

    Raises:
        ConfigError: see the module docstring.
        CheckpointError: an unusable checkpoint.
    """
    env_cfg = env_config if env_config is not None else EnvConfig()
    if spec.kind == "checkpoint":
        from truckrl.rl.policy import load_policy

        p = load_policy(spec.target, device)
        return ResolvedPolicy(
            spec, p.actor, p.env_config, p.difficulty, p.path, p.counters, fixed_env=True
        )
    if spec.kind == "onnx":
        return load_onnx_policy(spec, env_cfg)
    if spec.kind == "module":
        return ResolvedPolicy(spec, load_factory(spec, env_cfg, device), env_cfg)
    return ResolvedPolicy(spec, None, env_cfg)


# ---------------------------------------------------------------------------------- module
@contextlib.contextmanager
def _cwd_on_path():
    """The working directory on ``sys.path`` while a user's module imports (``truckrl`` as a
    console script does not put it there, ``python -m`` does)."""
    cwd = os.getcwd()
    added = cwd not in sys.path and "" not in sys.path
    if added:
        sys.path.insert(0, cwd)
    try:
        yield
    finally:
        if added:
            with contextlib.suppress(ValueError):
                sys.path.remove(cwd)


def load_factory(
    spec: PolicySpec, env_cfg: EnvConfig, device: str | torch.device
) -> Callable[[TensorDictBase], TensorDictBase]:
    """Import ``module``, call its factory ``function`` and wrap what it returns
    (:func:`~truckrl.evaluation.rollout.as_policy`).

    Raises:
        ConfigError: the module does not import, the function is missing or not callable, or it
            returns something that is not callable.
    """
    module_name, _, fn_name = spec.target.rpartition(":")
    where = f"policy = {spec.text!r}"
    try:
        with _cwd_on_path():
            module = importlib.import_module(module_name)
    except Exception as e:  # any error of the user's module: one line
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise ConfigError(
            f"{where}: module {module_name!r} does not import ({type(e).__name__}: {first})"
        ) from None
    factory = getattr(module, fn_name, None)
    if factory is None:
        raise ConfigError(f"{where}: module {module_name!r} has no {fn_name!r}")
    if not callable(factory):
        raise ConfigError(f"{where}: {module_name}.{fn_name} is a {type(factory).__name__}, "
                          "not a function")  # fmt: skip
    offered = {"env_config": env_cfg, "device": device}
    try:
        params = inspect.signature(factory).parameters
        kwargs = {k: v for k, v in offered.items() if k in params}
    except (TypeError, ValueError):  # no signature (a builtin): call it bare
        kwargs = {}
    policy = factory(**kwargs)
    if not callable(policy):
        raise ConfigError(
            f"{where}: {module_name}.{fn_name}() returned a {type(policy).__name__}, not a "
            "callable policy (td -> td, or obs -> action)"
        )
    return as_policy(policy)


# ---------------------------------------------------------------------------------- onnx
class OnnxPolicy:
    """An exported model run by onnxruntime: ``td [N] -> td [N]`` with "action" ``[N, 2]``.

    All ``N`` trucks go through one ``session.run`` on the CPU (float32 numpy in and out); the
    action is the model's output, the policy's raw mean, as the TorchRL actor's under
    ``ExplorationType.DETERMINISTIC`` (the env clamps it). On a GPU env every call copies the
    observations to the host and the action back: onnxruntime here runs on the CPU.
    """

    def __init__(self, session: Any) -> None:
        self.session = session

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        feeds = {k: td[k].detach().to("cpu", torch.float32).numpy() for k in ONNX_INPUTS}
        (action,) = self.session.run([ONNX_OUTPUT], feeds)
        return td.set(ONNX_OUTPUT, torch.from_numpy(action).to(td.device))


def onnx_session(path: Path, what: str) -> Any:
    """An onnxruntime CPU session of ``path``.

    Raises:
        ConfigError: onnxruntime is missing, or the file is not a readable ONNX model.
    """
    try:
        import onnxruntime as ort
    except ImportError:
        raise ConfigError(f"{what} needs onnxruntime: pip install 'truckrl[export]'") from None
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = torch.get_num_threads()  # the threads torch was given
    opts.log_severity_level = 3  # errors only
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own Fail / InvalidGraph / ...
        first = str(e).strip().splitlines()[0][:200] if str(e).strip() else type(e).__name__
        raise ConfigError(f"{what}: {path} is not a readable ONNX model ({first})") from None


def card_of(session: Any) -> dict | None:
    """The model card ``truckrl export`` stored (metadata key ``truckrl``), or None."""
    text = session.get_modelmeta().custom_metadata_map.get(CARD_KEY)
    if not text:
        return None
    try:
        card = json.loads(text)
    except json.JSONDecodeError:
        return None
    return card if isinstance(card, dict) else None


def check_onnx_io(session: Any, env_cfg: EnvConfig, what: str) -> None:
    """Check that the model reads ``observation [B, F]`` and ``lidar [B, R]`` and writes
    ``action [B, 2]`` (float32) for ``env_cfg``'s ``F`` features and ``R`` beams.

    Raises:
        ConfigError: a name, rank, size or dtype differs (one line saying which).
    """
    num_obs = make_task(env_cfg).num_features
    want = {"observation": num_obs, "lidar": env_cfg.lidar.num_beams}
    inputs = {i.name: i for i in session.get_inputs()}
    if sorted(inputs) != sorted(ONNX_INPUTS):
        raise ConfigError(
            f"{what}: the model's inputs are {sorted(inputs)}, the env gives {list(ONNX_INPUTS)}"
        )
    outputs = {o.name: o for o in session.get_outputs()}
    if ONNX_OUTPUT not in outputs:
        raise ConfigError(f"{what}: the model has no output {ONNX_OUTPUT!r} ({sorted(outputs)})")
    checks = [(k, inputs[k], n) for k, n in want.items()] + [("action", outputs["action"], 2)]
    for name, arg, size in checks:
        shape = list(arg.shape)
        if len(shape) != 2 or shape[1] != size or arg.type != "tensor(float)":
            env = f"task {env_cfg.task.name!r} with {env_cfg.lidar.num_beams} beams"
            raise ConfigError(
                f"{what}: {name} is {arg.type} {shape}, {env} needs tensor(float) [batch, {size}]"
            )


def load_onnx_policy(spec: PolicySpec, env_cfg: EnvConfig) -> ResolvedPolicy:
    """An ONNX file as a :class:`ResolvedPolicy`: env config and difficulty from its model card
    when it has one (``truckrl export`` writes them), else ``env_cfg`` and none.

    Raises:
        ConfigError: missing or unreadable file, no onnxruntime, or inputs/outputs that do not
            fit the env (:func:`check_onnx_io`).
    """
    what = f"policy = {spec.text!r}"
    path = Path(spec.target).expanduser()
    if not path.is_file():
        raise ConfigError(f"{what}: file not found: {path}")
    session = onnx_session(path, what)
    card = card_of(session) or {}
    difficulty = None
    carded = isinstance(card.get(CARD_ENV), dict)
    if carded:
        try:
            env_cfg = build(EnvConfig, card[CARD_ENV], "env")
        except ConfigError as e:
            raise ConfigError(f"{what}: its model card's env config is not valid ({e})") from None
        difficulty = float(card["difficulty"]) if "difficulty" in card else None
    check_onnx_io(session, env_cfg, what)
    return ResolvedPolicy(
        spec, OnnxPolicy(session), env_cfg, difficulty, path, None, fixed_env=carded
    )
