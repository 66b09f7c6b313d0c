"""Top-level configs of the entry points and their registration as Hydra structured configs.

Every default lives in a dataclass field (:func:`truckrl.config.fields.param`: default, range,
unit, meaning); YAML files under ``truckrl/conf/`` hold only presets that differ from them (``ppo/fast``,
``experiment/*``, ``control/*``, ``curriculum/none``, ``launch/*``). ``truckrl tools configs
[PREFIX]`` prints every field as a table (what docs/configuration.md points to).

Hydra groups (``register()``): ``task`` (one per task module, placed at ``env.task``), ``ppo``,
``curriculum``, ``model`` (``paper`` = the dataclass defaults) and the schemas ``train_schema``,
``evaluate_schema``, ``play_schema`` that the primary configs extend.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

from truckrl.config.fields import ConfigError, param, spec_table, validate
from truckrl.rl.config import ModelConfig, PPOConfig
from truckrl.rl.curriculum import CurriculumConfig
from truckrl.tasks import MAX_DIFFICULTY, EnvConfig, task_class, task_names
from truckrl.tasks.config import DEFAULT_TASK
from truckrl.viz.config import ViewConfig
from truckrl.viz.keyboard import KeyboardConfig

SEED_MAX = 2**62


@dataclass
class CollectorConfig:
    """Rollout shape: ``workers`` processes x ``num_envs`` trucks x ``steps_per_env`` steps."""

    workers: int = param(1, lo=1, hi=4096, unit="processes", doc="ParallelEnv workers (1: none)")
    num_envs: int = param(
        24, lo=1, hi=10_000_000, unit="trucks", doc="trucks per worker", source="paper"
    )
    steps_per_env: int = param(
        512, lo=1, hi=1_000_000, unit="steps", doc="steps per truck per iteration", source="paper"
    )
    compile_policy: bool = param(
        False,
        doc="torch.compile the rollout policy the collector calls every step (network, action "
        "sample, log-prob; compiled once per process)",
    )

    @property
    def frames_per_batch(self) -> int:
        return self.workers * self.num_envs * self.steps_per_env


@dataclass
class LogConfig:
    """TensorBoard and console output."""

    interval: int = param(1, lo=1, hi=1e9, unit="iterations", doc="between scalar writes")
    video_interval: int = param(
        50,
        lo=0,
        hi=1e9,
        unit="iterations",
        doc="at most this many iterations between videos (also every 5 min; 0: never)",
    )
    video_steps: int = param(200, lo=1, hi=100_000, unit="frames", doc="max frames per video")
    video_fps: float = param(10.0, lo=0.0, hi=1000.0, lo_open=True, unit="1/s", doc="video rate")
    progress_bar: bool = param(True, doc="tqdm progress bar")
    eval_interval_min: float = param(
        5.0,
        lo=0.0,
        hi=1e7,
        unit="min",
        doc="wall clock between held-out evaluations (truckrl/evaluation/heldout.py; 0: never; "
        "unused when eval_interval_frames is set)",
    )
    eval_interval_frames: int | None = param(
        None,
        lo=1,
        hi=1e15,
        unit="frames",
        doc="training frames between held-out evaluations (at the first iteration that ends "
        "past each multiple); when set it replaces eval_interval_min, so which checkpoint "
        "becomes best.pt does not depend on the machine's speed (null: eval_interval_min)",
    )
    eval_episodes: int = param(
        200, lo=1, hi=1_000_000, unit="episodes", doc="held-out scenes per evaluation"
    )
    quality_target: float = param(
        0.95,
        lo=0.0,
        hi=1.0,
        doc="held-out success rate of a good policy: the first held-out evaluation at or above "
        "it, at difficulty >= quality_difficulty, logs quality_reached (minutes since the "
        "run's start, demonstrations included, and frames)",
    )
    quality_difficulty: float = param(
        6.0,
        lo=0.0,
        hi=MAX_DIFFICULTY,
        doc="curriculum difficulty at which quality_target counts",
        source="paper's goal",
    )
    backend: str = param(
        "tensorboard",
        choices=("tensorboard", "csv", "wandb", "mlflow"),
        doc="where scalars and videos go, through TorchRL's logger of that name (wandb and "
        "mlflow need their extras: pip install 'truckrl[wandb]')",
    )
    backend_args: dict[str, Any] = param(
        {},
        doc="keyword arguments for the backend's logger (wandb: project=..., offline=true; "
        "mlflow: tracking_uri=...)",
    )


@dataclass
class CheckpointConfig:
    """Checkpoint cadence."""

    interval: int = param(10, lo=1, hi=1e9, unit="iterations", doc="between writes of last.pt")
    keep_every: int = param(
        0, lo=0, hi=1e9, unit="iterations", doc="also keep iter_XXXXXX.pt every N (0: never)"
    )
    keep_best: bool = param(
        True,
        doc="after each held-out evaluation, keep best.pt: the best held-out success at the "
        "highest difficulty evaluated so far",
    )


#: Top-level keys (:class:`TrainConfig` fields) a resumed run takes from its command line where
#: that sets them (the rest of each from the checkpoint); all others come from the checkpoint
#: (``truckrl.rl.session.resumed_config``).
RESUME_OVERRIDES = (
    "total_frames",
    "max_minutes",
    "stop_difficulty",
    "stop_on_quality",
    "resume",
    "overwrite",
    "device",
    "threads",
    "log",
    "checkpoint",
)


@dataclass
class DemosConfig:
    """A start cloned from demonstrations (the CEM planner's, or a task folder's own
    demonstrator), made by the run itself before PPO (``truckrl/rl/imitation.py``;
    docs/training.md, docs/reversing.md). Skipped on resume.

    With ``bc_coeff > 0`` the demonstrations also stay in the PPO update as a cloning term whose
    weight decays to 0 over ``bc_frames`` (kept in ``<run dir>/demos.pt`` for a resume). With
    ``dagger_rounds > 0`` they include the rounds' labelled states of the clone's own drives.
    """

    episodes: int = param(
        0, lo=0, hi=1_000_000, unit="scenes", doc="scenes the planner solves first (0: no demos)"
    )
    source: str = param(
        "planner",
        choices=("planner", "driver"),
        doc="who demonstrates: the CEM planner (any forward task) or the task's own demonstrator "
        "(demonstrations() in its folder's expert.py, for scenes the planner cannot solve)",
    )
    seed: int = param(
        99991, lo=0, hi=SEED_MAX, doc="their scene seed: one no evaluation uses (not 12345)"
    )
    difficulty: float = param(
        4.0, lo=0.0, hi=MAX_DIFFICULTY, doc="tolerance level the demonstrations must meet"
    )
    epochs: int = param(30, lo=1, hi=100_000, doc="behaviour-cloning passes over the samples")
    lr: float = param(2e-3, lo=0.0, hi=1.0, lo_open=True, doc="behaviour-cloning Adam step")
    batch_size: int = param(4096, lo=1, hi=10_000_000, unit="samples", doc="per minibatch")
    std: float = param(
        0.3, lo=0.0, hi=10.0, lo_open=True, unit="action", doc="policy std set after cloning"
    )
    samples: int | None = param(
        None, lo=2, hi=1_000_000, doc="planner candidates per scene per iteration (null: its own)"
    )
    iterations: int | None = param(
        None, lo=1, hi=100_000, doc="planner CEM iterations per attempt (null: its own)"
    )
    compile: bool = param(True, doc="torch.compile the planner's rollouts (compiled once)")
    device: str | None = param(
        None,
        doc="where the planner plans and replays (null: the run's device); cloning runs on the "
        "run's device. cpu under a GPU run: planning on the host's cores",
    )
    bc_coeff: float = param(
        0.0,
        lo=0.0,
        hi=1e3,
        doc="weight of the cloning term (action MSE on the demonstrations) added to every PPO "
        "minibatch loss at frame 0 (0: cloning only before PPO)",
    )
    bc_frames: int = param(
        20_000_000,
        lo=1,
        hi=1e15,
        unit="frames",
        doc="the cloning weight falls linearly from bc_coeff to 0 over this many frames",
    )
    bc_batch: int = param(
        1024, lo=1, hi=10_000_000, unit="samples", doc="demonstration samples per PPO minibatch"
    )
    bc_loss: str = param(
        "mean",
        choices=("mean", "executed"),
        doc="the cloning error (before PPO and in it) of the actor's mean, or of the mean as the "
        "env executes it (clamped to [-1, 1], the gradient straight through): a trained "
        "policy's saturated mean is then left where the demonstration agrees",
    )
    dagger_rounds: int = param(
        0,
        lo=0,
        hi=1000,
        doc="DAgger rounds after the first clone (source driver): the clone drives dagger_episodes "
        "new scenes, the task's demonstrator labels every state it visits, and the clone is fit "
        "again to all samples so far (0: the demonstrations only)",
    )
    dagger_episodes: int = param(
        1024, lo=1, hi=1_000_000, unit="scenes", doc="scenes the clone drives in each round"
    )
    dagger_epochs: int = param(
        10, lo=1, hi=100_000, doc="behaviour-cloning passes over all samples after each round"
    )


@dataclass
class TrainConfig:
    """``truckrl train``: everything a training run reads.

    A run ends on its own: at the paper's goal (``stop_difficulty`` 6: 0.47 m and 0.94 deg) or
    after ``max_minutes`` 60, whichever comes first. These are the dataclass defaults; the
    default preset ``experiment=demos`` caps the curriculum at 6 instead and trains for the 60
    minutes.
    """

    seed: int = param(0, lo=0, hi=SEED_MAX, doc="torch/numpy/python seed; env seeds derive from it")
    device: str = param("cpu", doc="env and policy device: cpu | cuda")
    threads: int | None = param(
        None,
        lo=1,
        hi=1024,
        doc="torch CPU threads of the training process (torch.set_num_threads, set before "
        "anything runs; the same seed and threads give the same run; null: torch's default)",
    )
    total_frames: int | None = param(
        None, lo=1, hi=1e15, unit="frames", doc="stop after this many frames (all sessions)"
    )
    max_minutes: float | None = param(
        60.0, lo=0.0, hi=1e7, lo_open=True, unit="min", doc="stop after this long (this session)"
    )
    stop_difficulty: float | None = param(
        6.0,
        lo=0.0,
        hi=MAX_DIFFICULTY,
        doc="stop once the curriculum reaches this difficulty",
        source="paper's goal",
    )
    stop_on_quality: bool = param(
        False,
        doc="stop at quality_reached: the first held-out evaluation at or above "
        "log.quality_target at difficulty >= log.quality_difficulty",
    )
    resume: str | None = param(
        None, doc="checkpoint file or run dir to continue; auto: this run dir's, if any"
    )
    overwrite: bool = param(False, doc="start anew in a run dir that already holds a checkpoint")
    init: str | None = param(
        None,
        doc="checkpoint, run dir or pretrained[:task] whose network weights start this new run "
        "(fine-tuning; its optimizer, curriculum and counters are not used)",
    )
    env: EnvConfig = field(default_factory=EnvConfig)
    train_env: dict[str, Any] = param(
        {},
        doc="env changes for the training envs only (train_env.task.scene.crossing_prob=1.0); "
        "held-out checks, best.pt, evaluate and play use env; kept on resume",
    )
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    log: LogConfig = field(default_factory=LogConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    demos: DemosConfig = field(default_factory=DemosConfig)

    def __post_init__(self) -> None:
        validate(self)
        check_device("device", self.device)
        if self.demos.device is not None:
            check_device("demos.device", self.demos.device)
        planner_compile = self.demos.compile and self.demos.episodes > 0 and self.init is None
        planner_compile = planner_compile and self.demos.source == "planner"
        compiled = {"env.compile": self.env.compile, "ppo.compile": self.ppo.compile}
        compiled |= {"collector.compile_policy": self.collector.compile_policy}
        planner = {"demos.compile": planner_compile}
        plan_device = self.demos.device or self.device
        if plan_device.startswith("cpu") == self.device.startswith("cpu"):
            check_compiler(self.device, **compiled, **planner)  # one line naming them all
        else:  # the planner on the other side (a GPU run planning on the host's CPU)
            check_compiler(self.device, **compiled)
            check_compiler(plan_device, **planner)
        from truckrl.tasks.config import with_env_overrides

        with_env_overrides(self.env, self.train_env, fixed=True, where="train_env")
        self.check_dagger()
        if self.resume is None:  # a resume's stop rules may come from its run: checked merged
            self.check_stops()
        self.ppo.check_batch(self.collector.frames_per_batch)

    def check_dagger(self) -> None:
        """Refuse in one line DAgger rounds that would not run or have no labeller: they need
        demonstrations (``demos.episodes > 0``) from the task's own demonstrator, whose
        ``expert.py`` has ``labelled``."""
        d = self.demos
        if d.dagger_rounds == 0:
            return
        if d.episodes == 0 or d.source != "driver":
            raise ConfigError(
                f"demos.dagger_rounds = {d.dagger_rounds} needs demos.episodes > 0 and "
                f"demos.source = driver (got {d.episodes} and {d.source!r}; or set it to 0)"
            )
        from truckrl.planning.experts import scripted_labels

        scripted_labels(self.env.task.name)

    def check_stops(self) -> None:
        """Refuse in one line a run that sets neither ``total_frames`` nor ``max_minutes``."""
        if self.total_frames is None and self.max_minutes is None:
            raise ConfigError(
                "set total_frames and/or max_minutes (both are null: the run might never stop)"
            )


@dataclass
class EvaluateConfig:
    """``truckrl eval``: deterministic evaluation of a policy (``policy=``: the specs of
    ``truckrl/rl/policy_specs.py``)."""

    policy: str = param(
        "checkpoint",
        doc="what plays: checkpoint:PATH | pretrained[:TASK] | onnx:FILE | planner | "
        "module:function (checkpoint: the checkpoint field)",
    )
    checkpoint: str | None = param(
        None,
        doc="checkpoint file, run dir or pretrained[:TASK]: short for policy=checkpoint:PATH; "
        "with policy=planner, whose env config and scenes the planner gets",
    )
    difficulty: float | None = param(
        None,
        lo=0.0,
        hi=MAX_DIFFICULTY,
        doc="null: the policy's curriculum difficulty (checkpoint, ONNX export), else 6",
    )
    episodes: int = param(100, lo=1, hi=10_000_000, doc="one episode per seeded scene")
    seed: int = param(12345, lo=0, hi=SEED_MAX, doc="scene seed: same seed, same scenes")
    device: str = param("cpu", doc="env and policy device")
    threads: int | None = param(
        None,
        lo=1,
        hi=1024,
        doc="torch CPU threads (torch.set_num_threads, set before anything runs; null: "
        "torch's default)",
    )
    output: str | None = param(
        None,
        doc="JSON file; null: <run dir of the checkpoint>/eval/<difficulty>-<seed>.json "
        "(other policies: outputs/eval/<kind>-<name>-<difficulty>-<seed>.json)",
    )
    env: dict[str, Any] = param(
        {},
        doc="the policy's env config changed for this evaluation only "
        "(env.task.scene.crossing_prob=0.7); not the task or the beam count of a checkpoint or "
        "ONNX export; task=NAME (env.task.name) picks the task of a policy without env config "
        "(module:function, planner, an ONNX file without model card)",
    )

    def __post_init__(self) -> None:
        validate(self)
        check_device("device", self.device)
        from truckrl.rl.policy_specs import base_env, spec_of

        if spec_of(self.policy, self.checkpoint) is None:
            raise ConfigError(
                "checkpoint is required: checkpoint=<file or run dir> (or policy=SPEC: "
                "pretrained, onnx:FILE, planner, module:function)"
            )
        base_env(self.env)  # a task name that is not a task folder


ON_DONE = ("new", "same", "wait")


@dataclass
class PlayConfig:
    """``truckrl play``: the viewer (keyboard, policy, replay or random driving)."""

    seed: int = param(0, lo=0, hi=SEED_MAX, doc="scene seed (as TruckEnv(seed=...))")
    device: str = param("cpu", doc="env and policy device")
    threads: int = param(1, lo=1, hi=1024, doc="torch CPU threads (one truck gains nothing more)")
    policy: str | None = param(
        None,
        doc="watch a policy: checkpoint:PATH | pretrained[:TASK] | onnx:FILE | planner | "
        "module:function (null: the keyboard, or checkpoint)",
    )
    checkpoint: str | None = param(
        None, doc="checkpoint file, run dir or pretrained[:TASK]: short for policy=checkpoint:PATH"
    )
    actions: str | None = param(None, doc="key script (text) or .npy [F, 2] action array")
    headless: bool = param(False, doc="no window; stops after `episodes` (default 1)")
    record: str | None = param(None, doc="mp4 file: every frame shown (view + HUD)")
    strip: str | None = param(None, doc="png file: evenly spaced views side by side")
    strip_frames: int = param(5, lo=1, hi=100, doc="tiles in the strip")
    strip_height: int = param(300, lo=16, hi=4096, unit="px", doc="height of each strip tile")
    difficulty: float | None = param(
        None, lo=0.0, hi=MAX_DIFFICULTY, doc="null: env.tolerance.difficulty or the checkpoint's"
    )
    difficulty_step: float = param(
        0.5, lo=0.0, hi=MAX_DIFFICULTY, lo_open=True, doc="change per +/- key (curriculum step)"
    )
    fps: float | None = param(
        None, lo=0.0, hi=1000.0, lo_open=True, unit="1/s", doc="null: real time, 1 / env.dt"
    )
    max_frames: int | None = param(None, lo=1, hi=1e9, doc="stop after this many frames")
    episodes: int | None = param(None, lo=1, hi=1e9, doc="stop after this many episodes")
    on_done: str = param("new", choices=ON_DONE, doc="after an episode: new | same | wait")
    done_hold_s: float = param(
        5.0, lo=0.0, hi=3600.0, unit="s", doc="show a finished episode (a key moves on sooner)"
    )
    env: EnvConfig = field(default_factory=EnvConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    keyboard: KeyboardConfig = field(default_factory=KeyboardConfig)

    def __post_init__(self) -> None:
        validate(self)
        check_device("device", self.device)
        from truckrl.rl.policy_specs import spec_of

        spec = spec_of(self.policy, self.checkpoint)
        if spec is not None and self.actions:
            raise ConfigError("give policy (or checkpoint) or actions, not both")


def check_device(name: str, device: str) -> None:
    """Raise :class:`ConfigError` unless ``device`` names a torch device this machine has."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(
            f"{name} = {device!r} is not a torch device (cpu, cuda, cuda:1)"
        ) from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(
            f"{name} = {device!r} but torch sees no CUDA GPU here (torch.cuda.is_available() is "
            f"False): use {name}=cpu"
        )


def check_compiler(device: str, **options: bool) -> None:
    """Raise :class:`ConfigError` when a ``torch.compile`` option is on for a CPU run and the C++
    compiler that torch.compile's CPU backend (inductor) builds its kernels with is missing.

    ``options`` maps dotted field names to their values. Inductor runs ``$CXX`` (default ``g++``,
    ``clang++`` on macOS); without it the first compiled call fails deep inside torch with a
    long traceback, minutes into a run, so this checks before any work starts.
    """
    import os
    import shutil

    on = [name for name, value in options.items() if value]
    if not on or not str(device).startswith("cpu"):
        return
    cxx = os.environ.get("CXX", "clang++" if sys.platform == "darwin" else "g++")
    if shutil.which(cxx):
        return
    fields = " and ".join(f"{name} = true" for name in on)
    off = " ".join(f"{name}=false" for name in on)
    raise ConfigError(
        f"{fields} need a C++ compiler ({cxx}) for torch.compile on the CPU, and none is on the "
        f"PATH: install one (apt-get install g++) or run eagerly with {off}"
    )


def structured(cls: type) -> Any:
    """``cls`` as an OmegaConf structured node whose list fields accept overrides.

    OmegaConf makes tuple-typed fields and frozen dataclasses read-only; the ``[min, max]`` ranges,
    layer widths and frozen configs must take command-line overrides
    (``env.task.scene.road_width=[12,18]``), so the flag is cleared. Element types are still
    checked at composition; ranges by :func:`validate` when the config is built.
    """
    from omegaconf import DictConfig, ListConfig, OmegaConf

    node = OmegaConf.structured(cls)

    def writable(n: Any) -> None:
        OmegaConf.set_readonly(n, False)
        keys = n.keys() if isinstance(n, DictConfig) else range(len(n))
        for k in keys:
            child = n._get_node(k)
            if isinstance(child, DictConfig) and _is_task_config(OmegaConf.get_type(child)):
                # env.task holds whichever task config the ``task`` group picks (train and play
                # list one in their defaults): the default's type, IntersectionConfig, and its
                # fields would refuse or pollute another task's node
                n[k] = OmegaConf.create({})
                child = n._get_node(k)
            if isinstance(child, DictConfig | ListConfig):
                writable(child)

    writable(node)
    return node


def _is_task_config(t: Any) -> bool:
    from truckrl.tasks import TaskConfig

    return isinstance(t, type) and issubclass(t, TaskConfig)


def register() -> None:
    """Register the schemas and the structured config groups with Hydra's ConfigStore."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=structured(TrainConfig))
    cs.store(name="evaluate_schema", node=structured(EvaluateConfig))
    cs.store(name="play_schema", node=structured(PlayConfig))
    for name in task_names():
        node = structured(task_class(name).config_class)
        cs.store(group="task", name=name, node=node, package="env.task")
    # what train.yaml and play.yaml list for the task: the default task's choice (the YAML files
    # name no task, a task is named only in its folder); task=<name> replaces it
    cs.store(name="default_task", node={"defaults": [{"task": DEFAULT_TASK}]})
    cs.store(group="ppo", name="paper", node=structured(PPOConfig), package="ppo")
    cs.store(
        group="curriculum", name="paper", node=structured(CurriculumConfig), package="curriculum"
    )
    cs.store(group="model", name="paper", node=structured(ModelConfig), package="model")


def main(argv: list[str]) -> int:
    """Print every config field (name, default, unit, allowed, meaning), optionally filtered."""
    prefix = argv[0] if argv else ""
    tables = [spec_table(TrainConfig)]
    tables += [spec_table(task_class(t).config_class, "env.task") for t in task_names()]
    tables += [spec_table(PlayConfig, "play"), spec_table(EvaluateConfig, "evaluate")]
    rows = []
    for row in (r for table in tables for r in table):
        hidden = row[0] == "env.task" or row[0].startswith("play.env.")  # shown once, above
        if row[0].startswith(prefix) and not hidden and row not in rows:
            rows.append(row)
    if not rows:
        print(f"error: no config field starts with {prefix!r}", file=sys.stderr)
        return 2
    width = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        print("  ".join(r[i].ljust(width[i]) for i in range(4)) + "  " + r[4])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
