"""``truckrl tools aggregate`` (:mod:`truckrl.tools.aggregate`) and its statistics
(:mod:`truckrl.tools.stats`): the IQM and bootstrap interval on hand-computed values, run dirs
with events written by the project's logger at chosen times, and a real two-seed sweep."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import TINY_TRAIN, run_cli
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.rl.checkpoint import TASKS_DIR, load_checkpoint, save_checkpoint
from truckrl.rl.logger import RunLogger
from truckrl.rl.policy import load_policy
from truckrl.tools.aggregate import _on_grid, main
from truckrl.tools.stats import bootstrap_ci, iqm, iqm_weights, percentile, summary


# ------------------------------------------------------------------------------- statistics
def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm([4, 1, 3, 2]) == 2.5  # (2 + 3) / 2
    assert iqm([1, 2, 3, 4, 5, 6, 7, 8]) == 4.5  # (3 + 4 + 5 + 6) / 4
    assert iqm([7.0]) == 7.0


def test_iqm_weighs_values_straddling_a_quartile_in_part():
    """n = 5: each value owns 1/5 of [0, 1]; [1/4, 3/4] holds 3/4 of the 2nd and 4th values'
    shares and all of the 3rd's: (0.75 * 1 + 2 + 0.75 * 6) / 2.5 = 7.25 / 2.5 = 2.9 (dropping
    whole values, scipy's trim_mean, would give (1 + 2 + 6) / 3 = 3)."""
    assert iqm_weights(5) == pytest.approx([0.0, 0.75, 1.0, 0.75, 0.0])
    assert iqm([100, 6, 2, 1, 0]) == pytest.approx(2.9)
    # n = 3: shares [0, 1/3], [1/3, 2/3], [2/3, 1]: weights 0.25, 1, 0.25 -> (0.25*3+6+0.25*30)/1.5
    assert iqm([3, 6, 30]) == pytest.approx((0.75 + 6 + 7.5) / 1.5)


def test_an_infinite_value_counts_only_where_it_has_weight():
    assert iqm([1, 2, 3, math.inf]) == 2.5  # the top quarter: no weight
    assert iqm([1, 2, math.inf, math.inf]) == math.inf


def test_percentile_interpolates_between_order_statistics():
    s = np.array([0.0, 10.0, 20.0, math.inf])
    assert percentile(s, 0.5) == 15.0  # h = 1.5
    assert percentile(s, 0.0) == 0.0 and percentile(s, 1.0) == math.inf
    assert percentile(s, 0.9) == math.inf  # between 20 and inf


def test_bootstrap_interval_of_two_seeds():
    """Two seeds 0 and 1: a resample's IQM (the mean of two draws) is 0, 0.5 or 1 with
    probabilities 1/4, 1/2, 1/4, so of 2,000 resamples the 2.5 % and 97.5 % quantiles are 0 and 1,
    and the 40 % and 60 % ones (level 0.2) both 0.5."""
    assert bootstrap_ci([0.0, 1.0]) == (0.0, 1.0)
    assert bootstrap_ci([0.0, 1.0], level=0.2) == (0.5, 0.5)
    assert bootstrap_ci([0.3, 0.3, 0.3]) == (0.3, 0.3)
    assert bootstrap_ci([0.0, 1.0], seed=5) == bootstrap_ci([1.0, 0.0], seed=5)  # order-free


def test_summary_treats_never_as_infinite_or_leaves_it_out():
    assert summary([1.0, 3.0, None], missing=math.inf) == {"iqm": None, "ci95": None}
    out = summary([1.0, 2.0, 3.0, 4.0, None], missing=math.inf)  # weights 0, .75, 1, .75, 0
    assert out["iqm"] == pytest.approx((0.75 * 2 + 3 + 0.75 * 4) / 2.5)
    assert out["ci95"] is None  # resamples with two or more never: an infinite upper end
    assert summary([0.5, None]) == {"iqm": 0.5, "ci95": [0.5, 0.5]}
    assert summary([None]) == {"iqm": None, "ci95": None}


def test_a_curve_on_the_plot_grid_holds_each_value_until_the_next():
    """(minutes, frames, value) rows on a frames grid: NaN before the first row and after the
    last, else the value of the latest row at or before the grid point."""
    series = np.array([[0.5, 1000.0, 0.0], [2.0, 3000.0, 6.0]])
    grid = np.array([500.0, 1000.0, 2000.0, 3000.0, 4000.0])
    y = _on_grid(series, grid, column=1)
    assert np.isnan(y[0]) and np.isnan(y[4]) and list(y[1:4]) == [0.0, 0.0, 6.0]
    assert list(_on_grid(series, np.array([1.0, 2.0]), column=0)) == [0.0, 6.0]


# ------------------------------------------------------------------------------- synthetic runs
#: Per seed: (curriculum/difficulty as (minutes, frames, value), final difficulty, demos seconds).
SYNTHETIC = {
    0: ([(0.5, 1000, 0.0), (2.0, 3000, 6.0), (3.0, 4000, 6.0)], 6.0, 60.0),
    1: ([(0.5, 1000, 0.0), (1.0, 2000, 5.5), (4.0, 5000, 6.5)], 6.5, 0.0),
    2: ([(0.5, 1000, 0.0), (5.0, 8000, 6.0)], 6.0, 0.0),
    3: ([(0.5, 1000, 0.0), (6.0, 9000, 5.5)], 5.5, 0.0),
}
#: seed -> its quality/reached_minutes; seed 3 never reached the target.
QUALITY = {0: 7.5, 1: 9.0, 2: 12.0}
T0 = 1.7e9  # [s] wall time of every run's first event
SHIPPED = TASKS_DIR / "intersection" / "pretrained.pt"


def synthetic_run(root: Path, seed: int, lr: float | None = None) -> Path:
    """A run dir: last.pt of the shipped intersection policy with its weights perturbed by the
    seed (so seeds score differently), its config's seed (and ``ppo.lr``) set and the curriculum
    at the run's final difficulty; TensorBoard events written by :class:`RunLogger` at chosen
    wall times; ``demos.json`` where the run had demonstrations."""
    points, final, demos_s = SYNTHETIC[seed]
    state = load_checkpoint(SHIPPED)
    config = yaml.safe_load(state["config"])
    config["seed"] = seed
    if lr is not None:
        config["ppo"]["lr"] = lr
    g = torch.Generator().manual_seed(seed)
    state["model"] = {
        k: v + 0.03 * seed * torch.randn(v.shape, generator=g) if v.is_floating_point() else v
        for k, v in state["model"].items()
    }
    state["config"] = yaml.safe_dump(config)
    state["curriculum"]["difficulty"] = final
    state["source"] = {"commit": "c" * 40, "dirty": seed == 3}
    state.pop("heldout", None)
    run = root / f"seed-{seed}"
    save_checkpoint(run / "checkpoints" / "last.pt", state)
    logger = RunLogger(run)
    logger.writer.add_scalar("episode/success_ema", 0.0, 0, walltime=T0)
    for minutes, frames, value in points:
        wall = T0 + 60.0 * minutes
        logger.writer.add_scalar("curriculum/difficulty", value, frames, walltime=wall)
        logger.writer.add_scalar("episode/success_ema", value / 10, frames, walltime=wall)
    if seed in QUALITY:  # training's quality_reached record, logged once
        minutes = QUALITY[seed]
        logger.writer.add_scalar(
            "quality/reached_minutes", minutes, 4000, walltime=T0 + 60.0 * minutes
        )
    logger.close()
    if demos_s:
        (run / "demos.json").write_text(json.dumps({"seconds": demos_s}))
    return run


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("seeds")
    for seed in SYNTHETIC:
        synthetic_run(root, seed)
    return root


def aggregate(*args: str) -> int:
    return main([*args, "threads=1"])


def test_figures_per_seed_and_across_seeds(synthetic, tmp_path, capsys):
    out = tmp_path / "seeds.json"
    plot = tmp_path / "seeds.png"
    runs = f"runs=[{synthetic}/seed-*]"
    assert aggregate(runs, "episodes=5", f"out={out}", f"plot={plot}") == 0
    data = json.loads(out.read_text())
    assert set(data) == {"provenance", "kind", "config", "seeds", "metrics", "bins"}
    assert data["kind"] == "seeds" and data["seeds"] == [0, 1, 2, 3]
    assert set(data["provenance"]) == {"command", "machine", "commit", "date", "threads"}
    assert data["provenance"]["command"] == (
        f"truckrl tools aggregate '{runs}' episodes=5 out={out} plot={plot} threads=1"
    )
    assert data["provenance"]["commit"] == f"{'c' * 40}, {'c' * 40}-dirty"  # seed 3: dirty
    assert data["provenance"]["threads"] == 1
    assert data["config"].startswith("task=intersection")  # no .hydra/ records here
    m = data["metrics"]
    assert list(m) == [
        "heldout_success", "minutes_to_difficulty_6", "frames_to_difficulty_6",
        "minutes_to_quality", "final_difficulty",
    ]  # fmt: skip
    assert m["minutes_to_quality"]["per_seed"] == {"0": 7.5, "1": 9.0, "2": 12.0, "3": None}
    # sorted 7.5, 9, 12, never (inf): IQM weights 0, 1, 1, 0 over n = 4 -> (9 + 12) / 2
    assert m["minutes_to_quality"]["iqm"] == 10.5
    # first logged difficulty >= 6; seed 0's minutes include its 1 minute of demonstrations
    assert m["minutes_to_difficulty_6"]["per_seed"] == {"0": 3.0, "1": 4.0, "2": 5.0, "3": None}
    assert m["frames_to_difficulty_6"]["per_seed"] == {"0": 3000, "1": 5000, "2": 8000, "3": None}
    assert m["frames_to_difficulty_6"]["iqm"] == 6500.0  # never = inf, in the top quarter
    assert m["frames_to_difficulty_6"]["ci95"] is None  # some resamples draw never twice
    assert m["final_difficulty"]["per_seed"] == {"0": 6.0, "1": 6.5, "2": 6.0, "3": 5.5}
    assert m["final_difficulty"]["iqm"] == 6.0  # (6 + 6) / 2
    lo, hi = m["final_difficulty"]["ci95"]
    assert 5.5 <= lo <= 6.0 <= hi <= 6.5
    assert m["final_difficulty"]["unit"] == "curriculum difficulty"
    # held-out success: the checkpoint's mean action on the same scenes, run here directly
    for seed in SYNTHETIC:
        policy = load_policy(synthetic / f"seed-{seed}")
        results, _, _ = evaluate_policy(policy.actor, policy.env_config, 6.0, 5, 12345)
        expected = results["success"].float().mean().item()
        assert m["heldout_success"]["per_seed"][str(seed)] == pytest.approx(expected)
    assert max(m["heldout_success"]["per_seed"].values()) > 0.0  # a comparison that tells
    assert data["bins"], "the intersection task has bins"
    for name, b in data["bins"].items():
        assert name.split()[0] in {"route", "turn", "crossing", "trailer", "road", "goal"}, name
        assert set(b) == {"per_seed", "iqm", "ci95"} and set(b["per_seed"]) == {"0", "1", "2", "3"}
    assert "route straight on" in data["bins"]
    shown = capsys.readouterr().out
    assert "| 3 | " in shown and "never" in shown and "| final_difficulty | 6 |" in shown
    import cv2

    image = cv2.imread(str(plot))
    assert image is not None and image.shape == (480, 900, 3)


def test_runs_of_another_config_or_the_same_seed_are_refused(synthetic, tmp_path, capsys):
    other = synthetic_run(tmp_path / "other", 1, lr=0.0005)
    out = tmp_path / "x.json"
    assert aggregate(f"runs=[{synthetic}/seed-0,{other}]", f"out={out}") == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"error: runs: {synthetic}/seed-0 and {other} differ in ppo.lr: aggregate the seeds of "
        "one config"
    )
    same = synthetic_run(tmp_path / "same", 0)
    assert aggregate(f"runs=[{synthetic}/seed-0,{same}]", f"out={out}") == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: runs: {synthetic}/seed-0 and {same} both have seed 0: one run per seed"
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["out=x.json"], "error: runs is required"),
        (["runs=[nowhere]", "out=x.json"], "error: runs: 'nowhere' names no file or folder"),
        (["runs=[{root}]"], "error: out = None: a JSON file to write"),
        (["runs=[{root}]", "out=x.json", "checkpoint=best"], "error: checkpoint = best: run "),
        (["runs=[{root}/seed-0/tb]", "out=x.json"], "error: runs: '{root}/seed-0/tb' is not a "),
        (["runs=[{root}]", "out=x.json", "difficulty=99"], "error: difficulty = 99 is outside"),
    ],
)
def test_bad_input_is_one_line_before_any_work(synthetic, args, says, capsys, tmp_path):
    args = [a.replace("{root}", str(synthetic)) for a in args]
    args = [a.replace("x.json", str(tmp_path / "x.json")) for a in args]
    try:
        code = aggregate(*args)
    except SystemExit as e:  # key_value_config refuses bad values itself
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(says.replace("{root}", str(synthetic))), err
    assert not (tmp_path / "x.json").exists()


# ------------------------------------------------------------------------------- a real sweep
@pytest.mark.e2e
def test_a_real_two_seed_sweep_dir(tmp_path):
    """``truckrl train -m seed=0,1`` (tiny): each job trains its budget with its own seed and
    records its video; then ``truckrl tools aggregate`` of the sweep dir: its jobs are found, the
    shared command line is the config, and the runs never reached difficulty 6."""
    sweep = tmp_path / "sweep"
    videos = ["log.video_interval=1", "log.video_steps=5"]  # the last override wins over TINY's
    proc = run_cli(
        "train", "-m", "seed=0,1", *TINY_TRAIN, "total_frames=512", "env.max_steps=20",
        *videos, f"hydra.sweep.dir={sweep}",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    for job in ("0", "1"):
        state = load_checkpoint(sweep / job)
        assert state["counters"]["frames"] == 512
        assert yaml.safe_load(state["config"])["seed"] == int(job)
        video = sweep / job / "videos" / "iter_000001.mp4"
        assert video.is_file() and video.stat().st_size > 0
    # held-out checks by default: every 5 min, so none in a run this short
    events = EventAccumulator(str(sweep / "0" / "tb"))
    events.Reload()
    assert not [t for t in events.Tags()["scalars"] if t.startswith("eval/")]
    out = tmp_path / "seeds.json"
    # in this process (the training above needs its own): one interpreter start fewer
    assert aggregate(f"runs={sweep}", "episodes=4", f"out={out}", "x=minutes",
                     f"plot={tmp_path / 'seeds.png'}") == 0  # fmt: skip
    data = json.loads(out.read_text())
    assert data["seeds"] == [0, 1]
    assert data["config"].startswith("truckrl train experiment=demos collector.num_envs=16 ")
    assert "seed=" not in data["config"] and "hydra" not in data["config"]
    assert data["metrics"]["frames_to_difficulty_6"]["per_seed"] == {"0": None, "1": None}
    assert data["metrics"]["final_difficulty"]["iqm"] == 0.0
    assert data["metrics"]["final_difficulty"]["ci95"] == [0.0, 0.0]
    assert (tmp_path / "seeds.png").stat().st_size > 0
