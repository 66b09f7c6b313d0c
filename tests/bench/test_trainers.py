"""``truckrl bench trainers``: a tiny run of the harness (every trainer advances and is scored),
the CleanRL-style PPO's GAE against a hand-computed rollout, and one-line key errors."""

from __future__ import annotations

import json

import pytest
import torch

from truckrl.bench import trainers as bench
from truckrl.bench.cleanrl_ppo import gae


@pytest.mark.e2e
def test_tiny_run_every_trainer_advances_and_is_scored(tmp_path, capsys, monkeypatch):
    """Each trainer for 0.1 s (at least one update), 2 held-out episodes: truckrl's in its own
    subprocess as the harness runs it, SB3's and CleanRL's by :func:`bench.run_one` in this
    process (the same function their subprocess calls; one interpreter start each fewer)."""
    spawn = bench._spawn
    monkeypatch.setattr(
        bench, "_spawn", lambda job, t: spawn(job, t) if job["trainer"] == "truckrl" else
        bench.run_one(job)
    )  # fmt: skip
    out = tmp_path / "trainers.json"
    opts = bench.parse(["minutes=0.002", "seeds=[3]", "envs=8", "episodes=2", f"out={out}"])
    result = bench.run(opts)
    table = capsys.readouterr().out
    record = json.loads(out.read_text())
    assert record["benchmark"] == "trainers" and record["args"]["seeds"] == [3]
    assert {"command", "load_avg_1min"} <= set(record["provenance"])
    rows = record["rows"]
    assert [r["trainer"] for r in rows] == ["truckrl", "sb3", "cleanrl"] == list(bench.TRAINERS)
    for r in rows:
        assert "error" not in r, r
        assert set(bench.COLUMNS) <= set(r)
        assert r["seed"] == 3
        # at least one full update of 8 trucks x 32 steps
        assert r["frames"] >= 8 * bench.STEPS, r
        assert r["frames/s"] == pytest.approx(r["frames"] / r["train_s"])
        assert r["difficulty"] >= 0.0
        for k in ("success_fixed", "success_reached"):
            assert r[k] in (0.0, 0.5, 1.0)  # a fraction of 2 episodes
        assert r["same_env_as_scored"] is True  # trained on the scenes it is scored on
    assert result["rows"] == rows
    header = next(line for line in table.splitlines() if line.startswith("| trainer"))
    assert [c.strip() for c in header.strip("|").split("|")] == list(bench.COLUMNS)


def test_gae_three_steps_by_hand():
    """gamma 0.9, lambda 0.8; truck 0's episode ends with step 1, truck 1's runs on.

    Truck 0, rewards (1, 2, 3), values (0.5, 1.0, 1.5), next value 2.0:
      d2 = 3 + 0.9 * 2.0 - 1.5 = 3.3                 A2 = 3.3
      d1 = 2 + 0 - 1.0 = 1.0 (done: no bootstrap)    A1 = 1.0 (nor carry)
      d0 = 1 + 0.9 * 1.0 - 0.5 = 1.4                 A0 = 1.4 + 0.72 * 1.0 = 2.12
    Truck 1, rewards (0, 0, 1), values and next value 0: A = (0.72**2, 0.72, 1).
    """
    rewards = torch.tensor([[1.0, 0.0], [2.0, 0.0], [3.0, 1.0]])
    values = torch.tensor([[0.5, 0.0], [1.0, 0.0], [1.5, 0.0]])
    dones = torch.tensor([[False, False], [True, False], [False, False]])
    adv, ret = gae(rewards, values, dones, torch.tensor([2.0, 0.0]), gamma=0.9, lam=0.8)
    expected = torch.tensor([[2.12, 0.5184], [1.0, 0.72], [3.3, 1.0]])
    torch.testing.assert_close(adv, expected)
    torch.testing.assert_close(ret, expected + values)


def _in_process(capsys, *argv: str) -> tuple[int, str]:
    """``truckrl bench trainers argv`` in this process: (exit code, stderr)."""
    from truckrl.bench.__main__ import main

    with pytest.raises(SystemExit) as exit_:
        main(["trainers", *argv])
    return exit_.value.code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["minutes=0"], "minutes = 0"),
        (["trainers=[truckrl,ppo]"], "trainers[1] = 'ppo'"),
        (["seeds=[]"], "seeds = []"),
        (["task=nope"], "task = 'nope' is not one of"),
        (["control=accel_nope"], "control = 'accel_nope' is not one of"),
        (["episodes=0"], "episodes = 0"),
        (["no_such_key=1"], "unknown field(s) ['no_such_key']"),
    ],
)
def test_bad_options_are_one_line_exit_2(args, needle, tmp_path, capsys):
    code, err = _in_process(capsys, *args, f"out={tmp_path}")
    assert code == 2
    assert err.strip().startswith(f"error: {needle}"), err
    assert len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())  # rejected before any work
