"""``truckrl tools diagnose`` and its parts: which body touched what, the trailer's depth into
the branch, and the per-episode record of a scripted drive whose outcome is known in advance."""

import math

import pytest
import torch

from tests.rl.test_uturn_driver import FIXED_TRUCK
from truckrl.sim.collision import touching
from truckrl.tasks import EnvConfig
from truckrl.tasks.uturn.diagnosis import (
    OUTCOME_NAMES,
    diagnose,
    summarize_diagnosis,
    trailer_depth,
)
from truckrl.tasks.uturn.scene import DEAD_END_SLOT, SEGMENT_NAMES
from truckrl.tools.diagnose import main

# FIXED_TRUCK (wheelbase 3.8, overhangs 1.4 / 0.9, kingpin 0, trailer 8.5 + 1.25 / 2.25),
# straight, rear axle at the origin heading +x: tractor from x = -0.9 to 3.8 + 1.4 = 5.2, half
# width 1.225; trailer axle at x = -8.5, trailer from 1.25 to -10.75, half width 1.25


def test_touching_names_the_body_by_hand():
    params = {k: torch.tensor([v]) for k, v in FIXED_TRUCK.items()}
    pose = torch.zeros(1, 4)
    segs = torch.tensor(
        [
            [
                [5.5, -3.0, 5.5, 3.0],  # across the road 0.3 m ahead of the bumper
                [-10.5, -3.0, -10.5, 3.0],  # across the trailer's rear end only
                [-5.0, 1.24, -3.0, 1.24],  # along the trailer's side, inside it by 1 cm
                [-5.0, 1.30, -3.0, 1.30],  # 5 cm outside it
            ]
        ]
    )
    tractor, trailer = touching(pose, params, segs)
    assert tractor.tolist() == [[False, False, False, False]]
    assert trailer.tolist() == [[False, True, True, False]]
    tractor, trailer = touching(pose, params, segs, along=0.5, across=0.5)
    assert tractor.tolist() == [[True, False, False, False]]
    assert trailer.tolist() == [[False, True, True, True]]
    tractor, trailer = touching(pose, params, segs, along=0.5)  # longer only
    assert tractor.tolist() == [[True, False, False, False]]
    assert trailer.tolist() == [[False, True, True, False]]


def test_trailer_depth_by_hand():
    """Road heading 90 deg (the road runs along +y), centreline through (10, 0), 8 m wide, a left
    branch: the branch-side curb line is x = 10 - 4 = 6 and 'into the branch' is -x. A truck
    heading -x with its rear axle at (2, 5): trailer axle 8.5 m behind it, at x = 10.5, which is
    4.5 m on the road side of the curb line: depth -4.5 - 4 = -8.5 - ... computed below."""
    params = {k: torch.tensor([v]) for k, v in FIXED_TRUCK.items()}
    info = {
        "mouth_x": torch.tensor([10.0]),
        "mouth_y": torch.tensor([0.0]),
        "road_heading": torch.tensor([math.pi / 2]),
        "road_width": torch.tensor([8.0]),
        "branch_side": torch.tensor([1.0]),
    }
    pose = torch.tensor([[2.0, 5.0, math.pi, 0.0]])  # trailer axle at (10.5, 5)
    # across the road towards the branch side (left of +y is -x): 10 - 10.5 = -0.5 m from the
    # centreline, so 0.5 + 4 = 4.5 m short of the curb line
    assert trailer_depth(pose, params, info).item() == pytest.approx(-4.5, abs=1e-5)
    pose = torch.tensor([[-8.0, 5.0, math.pi, 0.0]])  # trailer axle at (0.5, 5): 5.5 m beyond
    assert trailer_depth(pose, params, info).item() == pytest.approx(5.5, abs=1e-5)
    info["branch_side"] = torch.tensor([-1.0])  # a right branch: the other way
    assert trailer_depth(pose, params, info).item() == pytest.approx(-9.5 - 4.0, abs=1e-5)


def full_ahead(td):
    """Full forward acceleration, steering held: the truck drives straight down its lane."""
    td["action"] = torch.tensor([1.0, 0.0]).expand(td.batch_size[0], 2).clone()
    return td


def test_a_straight_drive_is_recorded_as_it_must_end():
    """Driving straight ahead from the road start: every truck pulls past the branch, never turns
    round or enters the branch; in a dead end it hits the dead-end wall with its tractor (and
    nothing else), on the open road it times out."""
    cfg = EnvConfig(task={"name": "uturn", "start": {"enabled": False}}, max_steps=300)
    d = diagnose(full_ahead, cfg, difficulty=4.0, episodes=24, seed=3)
    from truckrl.env import TruckEnv

    env = TruckEnv(num_envs=24, config=cfg, seed=3)
    env.reset()
    dead = env.get_state()["route", "dead_end"] > 0.5
    assert dead.any() and (~dead).any()
    assert (d["outcome"][dead] == 2).all() and (d["outcome"][~dead] == 0).all()
    assert d["pulled"].all() and not d["turned"].any() and (d["depth"] < 0).all()
    assert d["tractor_hit"][dead, DEAD_END_SLOT].all()
    others = [e for e in range(len(SEGMENT_NAMES)) if e != DEAD_END_SLOT]
    assert not d["tractor_hit"][:, others].any() and not d["trailer_hit"].any()
    rows = summarize_diagnosis(d)
    crash = [r for r in rows if r["outcome"] == "collision"]
    assert sum(r["episodes"] for r in crash) == int(dead.sum())
    assert all(set(r["touched"]) == {"tractor: dead-end wall"} for r in crash)


def full_back(td):
    """Full reverse acceleration, steering held: the truck backs straight down its lane."""
    td["action"] = torch.tensor([-1.0, 0.0]).expand(td.batch_size[0], 2).clone()
    return td


def test_the_closest_approach_is_the_nearest_state_after_any_step():
    """``closest`` against a brute-force pass of the same drive: the rear axle's distance to the
    goal, and the heading errors, computed here from the poses after every step until the
    episode ends; ``reached`` against the tolerance of the difficulty (30 m / 2**2). Reversing
    straight from the road start passes the goal's lane end and goes on, so the nearest state
    lies tens of steps in, a different one per scene, and some scenes come within 7.5 m."""
    from truckrl.env import TruckEnv
    from truckrl.sim.geometry import wrap_angle

    cfg = EnvConfig(task={"name": "uturn", "start": {"enabled": False}}, max_steps=120)
    d = diagnose(full_back, cfg, difficulty=2.0, episodes=12, seed=5)
    env = TruckEnv(num_envs=12, config=cfg, seed=5)
    env.set_difficulty(2.0)
    td = env.reset()
    goal = env.get_state()["goal"]
    best = torch.full((12,), math.inf)
    step = torch.zeros(12, dtype=torch.long)
    at = torch.zeros(12, 4)
    live = torch.ones(12, dtype=torch.bool)
    for t in range(cfg.max_steps):
        nxt = env.step(full_back(td))["next"]
        pose = env.get_state()["pose"]
        dist = torch.sqrt((goal[:, 0] - pose[:, 0]) ** 2 + (goal[:, 1] - pose[:, 1]) ** 2)
        nearer = live & (dist < best)
        best = torch.where(nearer, dist, best)
        step = torch.where(nearer, t + 1, step)
        at = torch.where(nearer[:, None], pose, at)
        live &= ~nxt["done"].squeeze(-1)
        if not live.any():
            break
        td = nxt
    assert (step > 10).all() and len(set(step.tolist())) > 3  # not the first state
    assert d["reached"].any() and not d["reached"].all()
    torch.testing.assert_close(d["closest"], best, atol=1e-4, rtol=0)
    assert torch.equal(d["closest_step"], step)
    tractor = wrap_angle(goal[:, 2] - at[:, 2]).abs()
    trailer = wrap_angle(goal[:, 2] - at[:, 2] - at[:, 3]).abs()
    torch.testing.assert_close(d["closest_tractor"], tractor, atol=1e-4, rtol=0)
    torch.testing.assert_close(d["closest_trailer"], trailer, atol=1e-4, rtol=0)
    assert torch.equal(d["reached"], best <= 30.0 / 4)
    rows = summarize_diagnosis(d)
    for r in rows:
        m = (d["left"] == (r["branch"] == "left")) & (
            d["outcome"] == OUTCOME_NAMES.index(r["outcome"])
        )
        assert r["closest_median_m"] == pytest.approx(float(best[m].median()), abs=1e-4)
        assert r["reached"] == pytest.approx(float((best[m] <= 30.0 / 4).float().mean()))


def _code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # a bad KEY=VALUE exits at parsing
        return e.code


def test_cli_refuses_bad_input_in_one_line(capsys):
    assert _code(["checkpoint=pretrained", "episodes=0"]) == 2
    assert "episodes = 0" in capsys.readouterr().err
    assert _code(["checkpoint=pretrained", "episodes=2"]) == 2  # the shipped intersection policy
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "task 'intersection' has no diagnosis" in err
    assert _code(["checkpoint=no/such/checkpoint.pt"]) == 2
    assert capsys.readouterr().err.startswith("error: ")
    assert _code(["episodes=2"]) == 2
    assert "checkpoint is required" in capsys.readouterr().err
    assert _code(["pretrained"]) == 2  # the old positional style
    assert "KEY=VALUE" in capsys.readouterr().err


def test_cli_finds_the_diagnosis_of_the_checkpoints_task(capsys, tmp_path):
    import json

    out = tmp_path / "rows.json"
    assert main(["checkpoint=pretrained:uturn", "episodes=2", f"out={out}"]) == 0
    printed = capsys.readouterr().out
    assert "uturn/pretrained.pt: 2 scenes (seed 12345)" in printed
    # the file holds the printed rows: one per (branch, outcome), the 2 episodes between them
    rows = json.loads(out.read_text())
    assert sum(r["episodes"] for r in rows) == 2
    for r in rows:
        assert r["branch"] in ("left", "right") and r["outcome"] in OUTCOME_NAMES
        assert f"{r['branch']:7s}{r['outcome']:12s}{r['episodes']:9d}" in printed
        if r["outcome"] == "collision":  # a collided truck touched something
            assert sum(r["touched"].values()) >= r["episodes"]


def test_a_diagnosis_without_the_whole_contract_is_one_line(tmp_path, monkeypatch):
    """A task folder outside the package (dotted name) whose diagnosis.py lacks two functions."""
    from truckrl.config.fields import ConfigError
    from truckrl.tools.diagnose import diagnosis_module

    folder = tmp_path / "mypkg" / "half"
    folder.mkdir(parents=True)
    for d in (folder.parent, folder):
        (d / "__init__.py").write_text("")
    (folder / "diagnosis.py").write_text("def diagnose(*a):\n    return {}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError, match=r"mypkg.half.diagnosis lacks summarize_diagnosis\(\), "):
        diagnosis_module("mypkg.half", "ckpt")
