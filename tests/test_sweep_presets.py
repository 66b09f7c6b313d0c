"""Sweep and launch presets (``truckrl/conf/launch/``): each composes with ``truckrl train``
(Hydra compose, no training), and the objective a sweeper optimizes. A two-trial Optuna sweep
of a tiny run is marked slow."""

from __future__ import annotations

import pytest
import yaml
from hydra import compose, initialize_config_dir

from tests.conftest import TINY_TRAIN, run_cli
from truckrl.cli import CONFIG_PATH, with_task_presets
from truckrl.config.schemas import register
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.progress import sweep_objective

SUBMITIT = "hydra_plugins.hydra_submitit_launcher"
OPTUNA = "hydra_plugins.hydra_optuna_sweeper"


def composed(*overrides: str):
    """``conf/train.yaml`` with ``overrides``, Hydra's own config included."""
    register()
    with initialize_config_dir(config_dir=CONFIG_PATH, version_base=None):
        return compose("train", with_task_presets(list(overrides)), return_hydra_config=True)


def test_slurm_gpu_is_slurm_with_one_gpu_on_cuda():
    pytest.importorskip(SUBMITIT)
    slurm, gpu = composed("+launch=slurm"), composed("+launch=slurm_gpu")
    assert gpu.hydra.launcher._target_.endswith("submitit_launcher.SlurmLauncher")
    assert (gpu.device, gpu.hydra.launcher.gpus_per_node, slurm.device) == ("cuda", 1, "cpu")
    for key in ("signal_delay_s", "max_num_timeout", "timeout_min"):  # requeueing as slurm's
        assert gpu.hydra.launcher[key] == slurm.hydra.launcher[key]
    assert (gpu.resume, gpu.max_minutes, gpu.total_frames) == ("auto", None, 2_000_000_000)


def test_the_local_launcher_runs_a_gpu_job_as_documented():
    """slurm_gpu.yaml's local command composes (submitit_local on this machine's GPU)."""
    pytest.importorskip(SUBMITIT)
    cfg = composed("+launch=local", "device=cuda", "hydra.launcher.gpus_per_node=1")
    assert cfg.hydra.launcher._target_.endswith("submitit_launcher.LocalLauncher")
    assert cfg.hydra.launcher.gpus_per_node == 1


@pytest.mark.parametrize("launch", ["optuna", "[optuna,local]", "[optuna,slurm]"])
def test_optuna_searches_ppo_and_curriculum_knobs_on_any_launcher(launch):
    pytest.importorskip(OPTUNA)
    if launch != "optuna":
        pytest.importorskip(SUBMITIT)
    cfg = composed(f"+launch={launch}")
    sweeper = cfg.hydra.sweeper
    assert sweeper._target_.endswith("optuna_sweeper.OptunaSweeper")
    assert sweeper.direction == "maximize" and sweeper.sampler.seed == 0
    assert {k.split(".")[0] for k in sweeper.params} == {"ppo", "curriculum"}
    for key in sweeper.params:  # every searched knob is a field of the config
        group, field = key.split(".")
        assert field in cfg[group], key
    launcher = {"optuna": "BasicLauncher", "[optuna,local]": "LocalLauncher",
                "[optuna,slurm]": "SlurmLauncher"}[launch]  # fmt: skip
    assert cfg.hydra.launcher._target_.endswith(launcher)


def test_the_objective_is_difficulty_plus_the_share_of_the_next_step():
    assert sweep_objective({"difficulty": 2.0, "ema": 0.35}, 0.7, 0.5) == pytest.approx(2.25)
    assert sweep_objective({"difficulty": 2.0, "ema": 0.9}, 0.7, 0.5) == pytest.approx(2.5)
    assert sweep_objective({"difficulty": 0.0, "ema": 0.0}, 0.7, 0.5) == 0.0


@pytest.mark.slow
def test_a_two_trial_optuna_sweep_of_a_tiny_run(tmp_path):
    """Each trial returns its objective to the sweeper (``truckrl.cli``'s task passes the
    return value on); the study's best value is the best trial's."""
    pytest.importorskip(OPTUNA)
    proc = run_cli("train", "-m", "+launch=optuna", "hydra.sweeper.n_trials=2",
                   f"hydra.sweep.dir={tmp_path}", *TINY_TRAIN, "total_frames=512")  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    values = []
    for job in ("0", "1"):
        state = load_checkpoint(tmp_path / job)
        cc = yaml.safe_load(state["config"])["curriculum"]
        values.append(sweep_objective(state["curriculum"], cc["threshold"], cc["step"]))
    result = yaml.safe_load((tmp_path / "optimization_results.yaml").read_text())
    assert result["best_value"] == pytest.approx(max(values))
    assert set(result["best_params"]) == set(composed("+launch=optuna").hydra.sweeper.params)
