"""Hydra composition of the structured configs: presets, groups, overrides and the field table."""

from dataclasses import replace

import pytest

from tests.conftest import compose_config, run_cli
from truckrl.cli import to_config
from truckrl.config.fields import ConfigError
from truckrl.config.schemas import EvaluateConfig, PlayConfig, TrainConfig, main
from truckrl.sim.control import LATERAL_MODES, LONGITUDINAL_MODES
from truckrl.tasks import task_names


def test_defaults_compose_to_the_dataclass_defaults():
    tc = to_config(TrainConfig, compose_config("train", "experiment=paper"))
    expected = TrainConfig()
    assert expected.env.task.scene.left_turn_exit > 0.0
    expected.env.task.scene.left_turn_exit = 0.0  # the paper's scenes: no left-turn exit rule
    assert tc == expected  # the paper experiment overrides nothing else
    assert to_config(PlayConfig, compose_config("play")) == PlayConfig()
    ec = to_config(EvaluateConfig, compose_config("evaluate", "checkpoint=x"))
    assert ec == EvaluateConfig(checkpoint="x")


def test_gpu_experiment_asks_for_cuda_and_refuses_a_machine_without_it():
    import torch

    cfg = compose_config("train", "experiment=gpu")
    assert (cfg.device, cfg.collector.num_envs, cfg.collector.steps_per_env) == ("cuda", 16384, 32)
    assert (cfg.ppo.num_epochs, cfg.ppo.num_minibatches) == (5, 16)
    if torch.cuda.is_available():
        assert to_config(TrainConfig, cfg).device == "cuda"
    else:
        with pytest.raises(ConfigError, match=r"^device = 'cuda' but torch sees no CUDA GPU"):
            to_config(TrainConfig, cfg)


def test_gpu_demos_experiment_is_demos_with_a_gpu_batch():
    import torch

    demos = compose_config("train", "experiment=demos")
    gpu = compose_config("train", "experiment=gpu_demos")
    assert (gpu.device, gpu.demos.device) == ("cuda", None)  # the planner on the GPU too
    assert (gpu.collector.num_envs, gpu.collector.steps_per_env) == (4096, 64)
    assert (gpu.demos.bc_batch, demos.demos.bc_batch) == (4096, 1024)
    # held-out checks by frames, half as often per frame as on the CPU (4x the batch)
    assert (gpu.log.eval_interval_frames, demos.log.eval_interval_frames) == (10**7, 5 * 10**6)
    # the cloning term of its documented runs, half the CPU default's length
    assert (gpu.demos.bc_frames, demos.demos.bc_frames) == (2 * 10**7, 4 * 10**7)
    # everything else is experiment=demos, the training scenes (all crossings) included
    on_cpu = compose_config("train", "experiment=gpu_demos", "device=cpu",
                            "collector.num_envs=1024", "demos.bc_batch=1024",
                            "log.eval_interval_frames=5000000",
                            "demos.bc_frames=40000000")  # fmt: skip
    assert to_config(TrainConfig, on_cpu) == to_config(TrainConfig, demos)
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"^device = 'cuda' but torch sees no CUDA GPU"):
            to_config(TrainConfig, gpu)


def test_gpu_d8_experiment_is_gpu_demos_fine_tuning_the_shipped_policy_up_to_difficulty_8():
    """experiment=gpu_d8 changes gpu_demos only where its file says: the shipped weights, no
    demonstrations, the curriculum 6 -> 8, quality counted at 90 % at 8, a frame budget."""
    d8 = to_config(TrainConfig, compose_config("train", "experiment=gpu_d8", "device=cpu"))
    base = to_config(TrainConfig, compose_config("train", "experiment=gpu_demos", "device=cpu"))
    expected = replace(
        base,
        init="pretrained:intersection",
        total_frames=60_000_000,
        max_minutes=None,
        demos=replace(base.demos, episodes=0, bc_coeff=0.0),
        curriculum=replace(base.curriculum, start_difficulty=6.0, max_difficulty=8.0),
        log=replace(
            base.log, quality_difficulty=8.0, quality_target=0.9, eval_interval_frames=10_000_000
        ),  # fmt: skip
    )
    assert d8 == expected
    assert base.train_env["task"]["scene"]["crossing_prob"] == 1.0  # the same training scenes


@pytest.mark.parametrize(
    "preset, base, changes",
    [
        ("finetune_dock", "dock", dict(init="pretrained:dock", start=7.0, top=7.0,
                                       frames=160_000_000, quality=(7.0, 0.95), episodes=300,
                                       max_std=0.5, lr_max=3e-4, desired_kl=0.005)),
        ("finetune_uturn", "pretrained_uturn", dict(init="pretrained:uturn", start=4.0, top=6.0,
                                                    frames=108_000_000, quality=(6.0, 0.9),
                                                    episodes=200)),
        ("finetune_intersection", "pretrained_intersection",
         dict(init="pretrained:intersection", start=6.0, top=6.0, frames=50_000_000,
              quality=(6.0, 0.99), episodes=1000, max_std=0.3, lr_max=3e-4, desired_kl=0.005,
              no_demos=True)),
    ],
)  # fmt: skip
def test_fine_tune_presets_change_their_task_preset_only_where_their_file_says(
    preset, base, changes
):
    """experiment=finetune_dock / finetune_uturn / finetune_intersection change their task preset
    only where their file says:
    the shipped weights, 4,096 trucks, the curriculum's start and cap, quality at the issue's
    target, held-out checks every 5 M frames, a frame budget (the CPU fine-tunes: the std bound
    and the smaller updates too; finetune_intersection: no demonstrations)."""
    got = to_config(TrainConfig, compose_config("train", f"experiment={preset}", "device=cpu"))
    ref = to_config(TrainConfig, compose_config("train", f"experiment={base}"))
    ppo = ref.ppo
    if "lr_max" in changes:
        ppo = replace(ppo, lr_max=changes["lr_max"], desired_kl=changes["desired_kl"])
    demos = replace(ref.demos, episodes=0, bc_coeff=0.0) if changes.get("no_demos") else ref.demos
    expected = replace(
        ref,
        init=changes["init"],
        total_frames=changes["frames"],
        max_minutes=None,
        stop_difficulty=None,
        collector=replace(ref.collector, num_envs=4096),
        demos=demos,
        model=replace(
            ref.model,
            max_std=changes.get("max_std", ref.model.max_std),
            init_std=min(ref.model.init_std, changes.get("max_std", ref.model.init_std)),
        ),
        ppo=ppo,
        curriculum=replace(
            ref.curriculum, start_difficulty=changes["start"], max_difficulty=changes["top"]
        ),
        log=replace(
            ref.log,
            quality_difficulty=changes["quality"][0],
            quality_target=changes["quality"][1],
            eval_interval_frames=5_000_000,
            eval_episodes=changes["episodes"],
        ),  # fmt: skip
    )
    assert got == expected


@pytest.mark.parametrize(
    "preset, base", [("gpu_dock", "finetune_dock"), ("gpu_uturn", "finetune_uturn")]
)
def test_gpu_reversing_presets_need_a_gpu(preset, base):
    """experiment=gpu_dock and gpu_uturn are finetune_dock and finetune_uturn on a CUDA device;
    both stop with one line where torch sees no GPU."""
    import torch

    got = to_config(TrainConfig, compose_config("train", f"experiment={preset}", "device=cpu"))
    ref = to_config(TrainConfig, compose_config("train", f"experiment={base}"))
    assert got == ref
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"^device = 'cuda' but torch sees no CUDA GPU"):
            to_config(TrainConfig, compose_config("train", f"experiment={preset}"))


@pytest.mark.parametrize(
    "value, message",
    [
        ("gpu0", r"^demos.device = 'gpu0' is not a torch device"),
        ("cuda", r"^demos.device = 'cuda' but torch sees no CUDA GPU"),
    ],
)
def test_demos_device_is_checked_before_work(value, message):
    import torch

    if value == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(ConfigError, match=message):
        to_config(TrainConfig, compose_config("train", f"demos.device={value}"))


def test_compile_options_without_a_cpp_compiler_stop_before_work(monkeypatch, tmp_path):
    """torch.compile on the CPU builds its kernels with $CXX (g++): without one the run stops at
    the config with one line naming the options that are on, not minutes later in inductor."""
    cfg = compose_config("train")  # the default run: env, loss, policy and planner compiled
    assert to_config(TrainConfig, cfg).ppo.compile
    monkeypatch.setenv("PATH", str(tmp_path))  # an empty folder: no compiler on the PATH
    monkeypatch.setenv("CXX", "g++")
    with pytest.raises(ConfigError) as err:
        to_config(TrainConfig, cfg)
    msg = str(err.value)
    assert "\n" not in msg
    on = "env.compile = true and ppo.compile = true and collector.compile_policy = true"
    assert msg.startswith(on + " and demos.compile = true need a C++ compiler (g++)")
    eager = "env.compile=false ppo.compile=false collector.compile_policy=false"
    assert msg.endswith(eager + " demos.compile=false")
    off = compose_config("train", *eager.split(), "demos.episodes=0")
    assert not to_config(TrainConfig, off).ppo.compile  # eager: no compiler needed
    monkeypatch.setenv("CXX", "sh")  # any $CXX on the PATH is taken as the compiler
    monkeypatch.setenv("PATH", "/bin:/usr/bin")
    assert to_config(TrainConfig, cfg).env.compile


def test_demos_experiment_is_fast_plus_its_values():
    fast = to_config(TrainConfig, compose_config("train", "experiment=fast"))
    demos = to_config(TrainConfig, compose_config("train", "experiment=demos"))
    assert to_config(TrainConfig, compose_config("train")) == demos  # the default
    assert (demos.ppo.gamma, demos.env.task.reward.time, demos.curriculum.max_difficulty) == (
        0.998,
        -0.005,
        6.0,
    )
    assert (demos.demos.episodes, fast.demos.episodes) == (600, 0)
    assert (demos.demos.bc_coeff, fast.demos.bc_coeff) == (1.0, 0.0)
    assert (demos.model.max_std, fast.model.max_std) == (0.5, None)
    assert (demos.env.lidar.num_beams, fast.env.lidar.num_beams) == (32, 16)
    # training scenes are all crossings; the env that evaluates keeps the default mix
    assert demos.train_env == {"task": {"scene": {"crossing_prob": 1.0}}} and fast.train_env == {}
    assert demos.env.task.scene.crossing_prob == fast.env.task.scene.crossing_prob == 0.7
    assert replace(demos.env, lidar=fast.env.lidar, task=fast.env.task) == fast.env
    assert (demos.stop_difficulty, fast.stop_difficulty) == (None, 6.0)
    for part in ("collector", "checkpoint"):
        assert getattr(demos, part) == getattr(fast, part), part
    assert (demos.log.eval_interval_frames, fast.log.eval_interval_frames) == (5 * 10**6, None)
    assert replace(demos.log, eval_interval_frames=None) == fast.log
    assert replace(demos.model, max_std=None) == fast.model
    assert demos.ppo.lr == fast.ppo.lr and demos.env.compile == fast.env.compile


@pytest.mark.parametrize("lon", LONGITUDINAL_MODES)
@pytest.mark.parametrize("lat", LATERAL_MODES)
def test_every_control_preset_composes(lon, lat):
    tc = to_config(TrainConfig, compose_config("train", f"control={lon}_{lat}"))
    assert (tc.env.control.longitudinal, tc.env.control.lateral) == (lon, lat)


def test_every_task_is_a_group_option():
    for name in task_names():
        tc = to_config(TrainConfig, compose_config("train", f"task={name}"))
        assert tc.env.task.name == name
        # experiment=demos trains on crossings only for the intersection task alone
        crossings = {"task": {"scene": {"crossing_prob": 1.0}}}
        assert tc.train_env == (crossings if name == "intersection" else {}), name


def test_list_and_nested_overrides():
    tc = to_config(
        TrainConfig,
        compose_config("train", "env.task.scene.road_width=[12,16]", "model.numeric_hidden=[32]"),
    )
    assert tc.env.task.scene.road_width == (12.0, 16.0)
    assert tc.model.numeric_hidden == (32,)


@pytest.mark.parametrize(
    ("override", "field"),
    [
        ("env.max_steps=0", "env.max_steps"),
        ("env.task.scene.road_width=[18,12]", "env.task.scene.road_width"),
        ("env.task.reward.success=nan", "env.task.reward.success"),
        ("collector.num_envs=0", "collector.num_envs"),
        ("device=gpu0", "device"),
    ],
)
def test_bad_values_name_the_field(override, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        to_config(TrainConfig, compose_config("train", override))


def test_config_table_lists_every_field(capsys):
    assert main(["env.task.reward"]) == 0
    out = capsys.readouterr().out
    assert "env.task.reward.progress" in out and "0.05" in out and "paper" in out
    assert main(["no.such.prefix"]) == 2
    assert capsys.readouterr().err == "error: no config field starts with 'no.such.prefix'\n"


@pytest.mark.e2e
@pytest.mark.parametrize("prefix", ["env.vehicle", "prefix=env.vehicle"])
def test_config_table_cli(prefix):
    proc = run_cli("tools.configs", prefix)
    assert proc.returncode == 0, proc.stderr
    assert "env.vehicle.wheelbase" in proc.stdout and "[3.4, 4.2]" in proc.stdout
    assert "ppo.lr" not in proc.stdout


def test_default_run_ends_on_its_own():
    """`python -m truckrl.train` (experiment=demos) caps the curriculum at 6 and stops after 60
    minutes; experiment=fast stops at the paper's goal (difficulty 6) or after 60 minutes."""
    tc = to_config(TrainConfig, compose_config("train"))
    assert (tc.stop_difficulty, tc.max_minutes, tc.total_frames) == (None, 60.0, None)
    assert tc.curriculum.max_difficulty == 6.0
    fast = to_config(TrainConfig, compose_config("train", "experiment=fast"))
    assert (fast.stop_difficulty, fast.max_minutes) == (6.0, 60.0)
    assert not tc.overwrite and tc.resume is None


@pytest.mark.parametrize(
    ("dotted", "words"),
    [
        ("env.lidar.num_beams", "a whole number in [1, 4096]"),
        ("env.task.scene.road_width", "a [min, max] pair of numbers"),
        ("ppo.lr", "a number in (0, 1]"),
        ("log.progress_bar", "true or false"),
        ("stop_difficulty", ", or null"),
    ],
)
def test_field_descriptions_for_composition_errors(dotted, words):
    from truckrl.cli import accepted, field_spec

    hint, spec = field_spec(dotted, TrainConfig)
    assert words in accepted(hint, spec)
