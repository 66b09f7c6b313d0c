"""The uturn gear plan is mirror-symmetric: a scene reflected across its road axis (by hand here,
from the scene's frame alone) gets the reflected legs, the mirrored actions and the same
outcome; and the fourth leg (overrun past the goal, reverse back) ends where hand-computed."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict

from truckrl.planning import held_out_states
from truckrl.planning.gears import NUM_GEAR_PARAMS, GearPlanner
from truckrl.tasks.uturn.expert import GEAR_TASK_PARAMS

UTURN = {"task": {"name": "uturn"}, "max_steps": 1000}
#: Held-out scenes of seed 12345 at difficulty 6: 13 a left branch whose mean plan succeeds,
#: 1 a right branch whose mean plan does not.
SCENES = [13, 1]
DIFFICULTY = 6.0


def reflect(state: TensorDict) -> TensorDict:
    """``state`` reflected across the line through the mouth centre along the road heading:
    points ``o + 2 ((p - o) . u) u - (p - o)``, headings ``2 h - theta``, signed angles
    (articulation, steering and its rates) negated, the branch on the other side."""
    m = state.clone()
    r = state["route"]
    o = torch.stack((r["mouth_x"], r["mouth_y"]), -1)
    h = r["road_heading"]
    u = torch.stack((h.cos(), h.sin()), -1)

    def point(p: torch.Tensor) -> torch.Tensor:
        shape = (p.shape[0],) + (1,) * (p.dim() - 2) + (2,)
        oo, uu = o.view(shape), u.view(shape)
        d = p - oo
        return oo + 2.0 * (d * uu).sum(-1, keepdim=True) * uu - d

    def heading(a: torch.Tensor) -> torch.Tensor:
        return torch.remainder(2.0 * h - a + math.pi, 2.0 * math.pi) - math.pi

    pose, goal = state["pose"].clone(), state["goal"].clone()
    pose[:, :2], pose[:, 2], pose[:, 3] = point(pose[:, :2]), heading(pose[:, 2]), -pose[:, 3]
    goal[:, :2], goal[:, 2] = point(goal[:, :2]), heading(goal[:, 2])
    m["pose"], m["goal"] = pose, goal
    n = state["segments"].shape[0]
    m["segments"] = point(state["segments"].reshape(n, -1, 2)).reshape(n, -1, 4)
    m["segments"] = m["segments"] * state["mask"][..., None]
    for key in ("steer", "steer_rate", "steer_accel"):
        m[key] = -state[key]
    m["route", "branch_side"] = -r["branch_side"]
    m["route", "branch_left"] = 1.0 - r["branch_left"]
    m["start_heading"] = heading(state["start_heading"])
    m["turn_point"], m["pull_point"] = point(state["turn_point"]), point(state["pull_point"])
    axis = state["turn_axis"]
    m["turn_axis"] = 2.0 * (axis * u).sum(-1, keepdim=True) * u - axis
    return m


def test_a_scene_and_its_mirror_image_get_mirrored_plans():
    """Each scene and its reflection, rolled out with the mean candidate of the first prior row:
    the same success, score and length; the longitudinal actions equal, the steering ones
    negated; every leg path the reflection of the original's."""
    torch.set_num_threads(1)
    states = held_out_states(UTURN, max(SCENES) + 1, 12345, difficulty=DIFFICULTY)[SCENES]
    assert states["route", "branch_side"].tolist() == [1.0, -1.0]
    both = torch.cat((states, reflect(states)))
    planner = GearPlanner(UTURN, {"search": "gears", "compile": False})
    x = torch.zeros(len(both), planner.num_params)
    x[:, NUM_GEAR_PARAMS:] = planner.prior[0]
    acc, actions = planner.rollout(both, x, DIFFICULTY)
    k = len(SCENES)
    assert acc["success"].tolist() == [True, False] * 2
    assert torch.equal(acc["length"][:k], acc["length"][k:])
    torch.testing.assert_close(acc["best"][:k], acc["best"][k:], rtol=1e-3, atol=1e-3)
    steps = int(acc["length"].min())
    lon, lat = actions[:steps, :, 0], actions[:steps, :, 1]
    torch.testing.assert_close(lon[:, :k], lon[:, k:], rtol=0.0, atol=1e-3)
    torch.testing.assert_close(lat[:, :k], -lat[:, k:], rtol=0.0, atol=1e-3)
    paths = planner.legs(both, x)["path"]
    mirrored = reflect(states)
    o = torch.stack((mirrored["route", "mouth_x"], mirrored["route", "mouth_y"]), -1)
    h = mirrored["route", "road_heading"]
    u = torch.stack((h.cos(), h.sin()), -1)[:, None, None]
    d = paths[:k] - o[:, None, None]
    torch.testing.assert_close(
        o[:, None, None] + 2.0 * (d * u).sum(-1, keepdim=True) * u - d,
        paths[k:],
        rtol=0.0,
        atol=1e-3,
    )


def test_the_final_reverse_ends_at_the_goal_trucks_trailer_axle():
    """overrun at its top (16 m): leg 3 ends 16 m past the goal along the goal heading; leg 4
    reverses along the goal lane and ends at the goal truck's trailer axle, ``kingpin_offset +
    trailer_wheelbase`` behind the goal against its heading; at the mean (overrun 0) leg 4 has
    no length, at the goal truck's trailer axle."""
    states = held_out_states(UTURN, 2, 12345, difficulty=DIFFICULTY)
    planner = GearPlanner(UTURN, {"search": "gears", "compile": False})
    j = NUM_GEAR_PARAMS + [p[0] for p in GEAR_TASK_PARAMS].index("overrun")
    x = torch.zeros(4, planner.num_params)
    x[:2, j] = 1.0
    legs = planner.legs(torch.cat((states, states)), x)
    assert legs["gear"][0].tolist() == [1.0, -1.0, 1.0, -1.0]
    goal, p = states["goal"], states["params"]
    u = torch.stack((goal[:, 2].cos(), goal[:, 2].sin()), -1)
    axle = goal[:, :2] - (p["kingpin_offset"] + p["trailer_wheelbase"])[:, None] * u
    path = legs["path"]
    torch.testing.assert_close(path[:2, 2, -1], goal[:, :2] + 16.0 * u, rtol=0.0, atol=1e-3)
    torch.testing.assert_close(path[:2, 3, -1], axle, rtol=0.0, atol=1e-3)
    torch.testing.assert_close(path[:2, 3, 0], axle + 18.0 * u, rtol=0.0, atol=1e-3)
    torch.testing.assert_close(path[2:, 3, 0], axle, rtol=0.0, atol=1e-3)
    torch.testing.assert_close(path[2:, 3, -1], axle, rtol=0.0, atol=1e-3)
