"""``truckrl tools pretrained`` (:mod:`truckrl.tools.pretrained`): the refusal of a dirty tree, the
``pretrained_<task>`` presets (stopped by frames), and a tiny end-to-end build into a temp dir
that writes the policy and its card (never the shipped files)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict

import pytest

from tests.conftest import TINY_BATCH, TINY_TRAIN
from tests.reliability.harness import run_main
from truckrl import cli
from truckrl.config.schemas import TrainConfig
from truckrl.evaluation.categories import task_bins
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.policy import load_policy
from truckrl.tools import pretrained
from truckrl.tools.pretrained import TASKS, TASKS_DIR, TEMPLATE, main, template_parts

#: Per task: (frame budget, held-out checks every, difficulty it trains at in the end), as the
#: presets' comments derive them (docs/training.md, docs/reversing.md, the model cards).
PRESETS = {
    "dock": (48_000_000, 2_000_000, 7.0),
    "intersection": (200_000_000, 10_000_000, 6.0),
    "network": (60_000_000, 5_000_000, 4.0),
    "uturn": (144_000_000, 6_000_000, 4.0),
}


def shipped_digests() -> dict[str, str]:
    return {
        str(p): hashlib.sha256(p.read_bytes()).hexdigest()
        for t in TASKS
        for p in (TASKS_DIR / t / "pretrained.pt", TASKS_DIR / t / "pretrained.md")
        if p.exists()
    }


def call(*args: str) -> int:
    try:
        return main(list(args))
    except SystemExit as e:  # key_value_config refuses bad values itself
        return int(e.code)


@pytest.mark.parametrize(
    ("revision", "says"),
    [
        ({"commit": "a" * 40, "dirty": True}, "error: the work tree has uncommitted changes"),
        ({}, "error: the source is not a git checkout"),
    ],
)
def test_a_dirty_tree_is_refused_in_one_line_before_any_work(
    revision, says, monkeypatch, tmp_path, capsys
):
    monkeypatch.setattr(cli, "git_revision", lambda: revision)
    monkeypatch.setattr(pretrained, "train_child", lambda *a: pytest.fail("it trained"))
    code = call("task=dock", f"out={tmp_path / 'p.pt'}", f"run_dir={tmp_path / 'run'}")
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(says) and "allow_dirty=true" in err
    assert list(tmp_path.iterdir()) == []


def test_a_clean_tree_goes_on_to_check_the_training_config(monkeypatch, tmp_path, capsys):
    """Past the source check the training overrides are composed before any training: a bad
    one is its own one-line error (so the clean tree was accepted)."""
    monkeypatch.setattr(cli, "git_revision", lambda: {"commit": "a" * 40, "dirty": False})
    monkeypatch.setattr(pretrained, "train_child", lambda *a: pytest.fail("it trained"))
    code = call("task=dock", "train.ppo.lr=-1", f"run_dir={tmp_path / 'run'}")
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ppo.lr = -1"), err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        ([], "error: task is required: task=dock|intersection|network|uturn"),
        (["task=parking"], "error: task = 'parking' is not one of"),
        (["task=dock", "out=x.onnx"], "error: out = 'x.onnx': a .pt file to write"),
        (["task=dock", "episodes=0"], "error: episodes = 0 is outside"),
        (["task=dock", "train.threads=3"], "error: train.threads: give threads=N"),
    ],
)
def test_bad_input_is_one_line(args, says, capsys):
    assert call(*args) == 2
    err = capsys.readouterr().err
    assert err.startswith(says) and len(err.strip().splitlines()) == 1, err


def test_every_task_with_a_shipped_policy_has_a_preset_and_a_card_section():
    assert TASKS == ("dock", "intersection", "network", "uturn")
    _, sections = template_parts(TEMPLATE.read_text())
    assert set(sections) == set(TASKS)
    assert all(about.endswith(").") for about, _ in sections.values())


@pytest.mark.parametrize("task", sorted(PRESETS))
def test_presets_compose_and_stop_by_frames(task):
    frames, every, difficulty = PRESETS[task]
    tc = cli.compose_config("train", TrainConfig, [f"experiment=pretrained_{task}"])
    assert tc.env.task.name == task
    assert tc.max_minutes is None and tc.total_frames == frames
    assert tc.log.eval_interval_frames == every
    assert tc.curriculum.max_difficulty == difficulty and tc.stop_difficulty is None


def test_the_intersection_preset_is_the_default_run_but_for_its_budget():
    """experiment=demos with task=intersection as ``truckrl train`` runs it (training scenes at
    crossings included), differing only in how it stops and when it checks, and in the cloning
    term's length, which stays the one the shipped file was trained with."""
    import yaml

    default = asdict(cli.compose_config("train", TrainConfig, []))
    preset = asdict(
        cli.compose_config("train", TrainConfig, ["experiment=pretrained_intersection"])
    )
    assert (
        preset["train_env"] == default["train_env"] == {"task": {"scene": {"crossing_prob": 1.0}}}
    )
    shipped = yaml.safe_load(
        load_checkpoint(TASKS_DIR / "intersection" / "pretrained.pt")["config"]
    )
    assert preset["demos"]["bc_frames"] == shipped["demos"]["bc_frames"] == 20_000_000
    assert default["demos"]["bc_frames"] == 40_000_000
    for cfg in (default, preset):
        cfg.pop("total_frames"), cfg.pop("max_minutes"), cfg["log"].pop("eval_interval_frames")
        cfg["demos"].pop("bc_frames")
    assert preset == default


def test_the_uturn_preset_has_the_shipped_policys_config():
    """One run with the fine-tune's std bound and curriculum cap (its model card)."""
    tc = cli.compose_config("train", TrainConfig, ["experiment=pretrained_uturn"])
    shipped = load_checkpoint(TASKS_DIR / "uturn" / "pretrained.pt")
    assert tc.model.max_std == 0.5 and shipped["curriculum"]["difficulty"] == 4.0
    assert tc.env.task.observe_route and tc.env.max_steps == 1000


@pytest.mark.e2e
def test_a_tiny_build_writes_the_policy_and_its_card(tmp_path, capsys):
    before = shipped_digests()
    out = tmp_path / "ship" / "pretrained.pt"
    run_dir = tmp_path / "run"
    args = [
        "task=intersection", "allow_dirty=true", f"out={out}", f"run_dir={run_dir}",
        "episodes=6", "threads=1", f"train.total_frames={2 * TINY_BATCH}", "train.env.max_steps=20",
        "train.max_minutes=0.0001", *(f"train.{o}" for o in TINY_TRAIN),
    ]  # fmt: skip
    # stopped before its frame budget (here by a time limit; a Ctrl-C alike): nothing ships.
    # This session trains in this process; the resume below runs the real child process.
    in_process = lambda command: run_main(capsys, "train", *command[2:]).code  # noqa: E731
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pretrained, "train_child", in_process)
        assert call(*args) == 2
    assert f"run_dir={run_dir} resume=true continues it" in capsys.readouterr().err
    assert not out.exists()
    args.append("resume=true")
    assert call(*args) == 0, capsys.readouterr().err
    assert shipped_digests() == before  # the shipped files are untouched
    state = load_checkpoint(out)
    assert state["counters"]["frames"] == 2 * TINY_BATCH
    assert state["model"].keys() == load_checkpoint(run_dir)["model"].keys()
    facts = json.loads((run_dir / "pretrained.json").read_text())
    assert facts["frames"] == 2 * TINY_BATCH and facts["threads"] == 1
    assert facts["commit"].endswith("-dirty") or len(facts["commit"]) == 40
    assert set(facts["heldout"]) == {"12345", "54321"}
    # each column: the file's mean action on those scenes, run here directly
    policy = load_policy(out)
    for seed in (12345, 54321):
        results, tolerance, _ = evaluate_policy(policy.actor, policy.env_config, 6.0, 6, seed)
        assert facts["heldout"][str(seed)]["success"] == results["success"].float().mean().item()
        bins = facts["heldout"][str(seed)]["bins"]
        scenes = task_bins("intersection", results)  # the scenes of this seed, binned here
        counts = {f"{d} {b}": int(m.sum()) for d, group in scenes.items() for b, m in group.items()}
        assert {name: b["count"] for name, b in bins.items()} == counts
        assert sum(b["count"] for name, b in bins.items() if name.startswith("route ")) == 6
    assert facts["tolerance"] == pytest.approx([tolerance[0], tolerance[1]])
    card = out.with_suffix(".md").read_text()
    # the build, not its resume, and the run dir named RUN
    command = "truckrl tools pretrained " + " ".join(args[:-1]).replace(str(run_dir), "RUN")
    for text in (
        "# Shipped policy: intersection",
        command,
        "truckrl train experiment=pretrained_intersection seed=0 "
        f"total_frames={2 * TINY_BATCH} env.max_steps=20",
        "threads=1 hydra.run.dir=RUN\ntruckrl train resume=RUN threads=1 max_minutes=null",
        "stopped once and continued by the same command with `resume=true`:",
        f"| commit | `{facts['commit']}` (",
        f"| frames | {2 * TINY_BATCH} |",
        "| torch threads | 1 |",
        f"| machine | {facts['machine']} |",
        "| this file | `last.pt` of the run |",
        "| **all** | **",
        "| route straight on | ",
        f"truckrl eval checkpoint={out} difficulty=6 episodes=6 seed=54321",
        "`checkpoint=pretrained:intersection` (or `checkpoint=pretrained`: the default task)",
        "drive forward from a road shoulder",  # the task's hand-written part
    ):
        assert text in card, text
    assert "${" not in card and "<!--" not in card
    assert f"hydra.run.dir={run_dir}" not in card and f"resume={run_dir}" not in card
    assert "resume=true\n" not in card  # the build command is shown without it
    assert call(*args[:-1]) == 2  # the run dir holds a checkpoint now: refused, nothing trained
    assert "already holds a checkpoint" in capsys.readouterr().err
    assert call(*args[:-1], "seed=1", "resume=true") == 2  # another seed's run: refused
    assert "has seed = 0, this command 1" in capsys.readouterr().err
    # the finished run scored again into another file: nothing trains, its history stands
    again = tmp_path / "again" / "pretrained.pt"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pretrained, "train_child", lambda command: pytest.fail(f"trained: {command}"))
        assert call(*(a for a in args if not a.startswith("out=")), f"out={again}") == 0
    assert (
        f"{run_dir} is at its frame budget ({2 * TINY_BATCH:,} frames)" in capsys.readouterr().out
    )
    assert load_checkpoint(again)["counters"]["frames"] == 2 * TINY_BATCH
    assert "stopped once and continued by the same command" in again.with_suffix(".md").read_text()
    # a run that finished in one session (its earlier scoring says so): one training command
    facts["resumed"] = False
    (run_dir / "pretrained.json").write_text(json.dumps(facts))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pretrained, "train_child", lambda command: pytest.fail(f"trained: {command}"))
        assert call(*(a for a in args if not a.startswith("out=")), f"out={again}") == 0
    card = again.with_suffix(".md").read_text()
    assert "a time limit) in one run:" in card and "truckrl train resume=" not in card


def test_the_card_says_dirty(tmp_path):
    facts = {
        "task": "dock", "source": {"commit": "b" * 40, "dirty": True},
        "commit": "b" * 40 + "-dirty", "command": "truckrl tools pretrained task=dock",
        "train_command": "truckrl train experiment=pretrained_dock", "frames": 1234567,
        "wall_time_s": 90.0, "machine": "m", "threads": 2, "checkpoint": "best", "num_obs": 30,
        "num_beams": 16, "final_difficulty": 7.0, "difficulty": 7.0, "tolerance": [0.15, 5.73],
        "episodes": 10, "eval_commands": ["truckrl eval checkpoint=pretrained:dock"],
        "heldout": {"12345": {"success": 0.5, "episodes": 10, "bins": {
            "start apron": {"success": 0.25, "count": 4}, "bay width [m] 3.5-4": {
                "success": None, "count": 0}}}},
    }  # fmt: skip
    text = pretrained.write_card(tmp_path / "pretrained.md", facts)
    assert (
        f"| commit | `{'b' * 40}-dirty` (uncommitted changes in the work tree: built with " in text
    )
    assert "| frames | 1,234,567 |" in text and "| wall time | 1.5 min " in text
    assert "| **all** | **50.0 % (10)** |" in text and "| start apron | 25.0 % (4) |" in text
    assert "bay width" not in text  # a bin without scenes: no row
    assert "(or `checkpoint=pretrained`" not in text  # dock is not the default task
    assert "reverse a tractor-trailer into a loading bay" in text
