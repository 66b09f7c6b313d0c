"""Per-category evaluation summary: bins and rates checked against hand-computed values."""

import math

import pytest
import torch

from truckrl.evaluation.categories import format_category_table, summarize_by_category
from truckrl.evaluation.interval import wilson_interval
from truckrl.sim.vehicle import VehicleConfig, sample_vehicle_params
from truckrl.tasks.intersection.bins import (
    CROSSING_EDGES_DEG,
    GOAL_DISTANCE_EDGES_M,
    ROAD_WIDTH_EDGES_M,
    TRAILER_LENGTH_EDGES_M,
    episode_bins,
    scene_info,
)
from truckrl.tasks.intersection.scene import SceneConfig, generate_scenes

F64 = torch.float64


def mask(n: int, idx: list[int]) -> list[bool]:
    return [i in idx for i in range(n)]


def as_lists(bins: dict) -> dict:
    return {dim: {name: m.tolist() for name, m in named.items()} for dim, named in bins.items()}


def hand_info(**overrides) -> dict:
    """8 episodes, float64, values chosen on and between the bin edges."""
    info = {
        "route": torch.tensor([0, 1, 2, 3, 2, 3, 2, 3], dtype=torch.int8),
        "turn_angle": torch.tensor([0, 0, 60, -120, 100, -80, 135, -45], dtype=F64) * math.pi / 180,
        "crossing_angle": torch.tensor([0, 60, 60, 60, 100, 100, 45, 135], dtype=F64)
        * math.pi
        / 180,
        "start_road_width": torch.tensor([12, 11, 15, 17, 13, 18, 10, 14], dtype=F64),
        "goal_road_width": torch.tensor([12, 11, 11, 16.5, 17, 18, 10, 16], dtype=F64),
        "goal_distance": torch.tensor([30, 45, 50, 69.9, 55, 70, 25, 40], dtype=F64),
        "trailer_length": torch.tensor([11.0, 14.0, 12.5, 7.9, 16.1, 12.8, 11.2, 9.0], dtype=F64),
    }
    info.update(overrides)
    return info


def test_episode_bins_hand_built():
    n = 8
    got = as_lists(episode_bins(hand_info()))
    expected = {
        "route": {
            "straight road": mask(n, [0]),
            "straight on": mask(n, [1]),
            "left": mask(n, [2, 4, 6]),
            "right": mask(n, [3, 5, 7]),
        },
        "turn [deg]": {
            "left 20-70": mask(n, [2]),
            "left 70-110": mask(n, [4]),
            "left 110-180": mask(n, [6]),
            "right 20-70": mask(n, [7]),
            "right 70-110": mask(n, [5]),
            "right 110-180": mask(n, [3]),
        },
        "crossing angle [deg]": {  # straight roads (episode 0) have none
            "45-70": mask(n, [1, 2, 3, 6]),
            "70-110": mask(n, [4, 5]),
            "110-135": mask(n, [7]),
        },
        "trailer length [m]": {  # [lo, hi): 11.2 and 12.8 go up; 16.1 is the closed top
            "7.9-11.2": mask(n, [0, 3, 7]),
            "11.2-12.8": mask(n, [2, 6]),
            "12.8-16.1": mask(n, [1, 4, 5]),
        },
        "road width [m]": {  # the narrower road: 12, 11, 11, 16.5, 13, 18, 10, 14
            "10-12": mask(n, [1, 2, 6]),
            "12-14": mask(n, [0, 4]),
            "14-16": mask(n, [7]),
            "16-18": mask(n, [3, 5]),
        },
        "goal distance [m]": {
            "25-40": mask(n, [0, 6]),
            "40-55": mask(n, [1, 2, 7]),
            "55-70": mask(n, [3, 4, 5]),
        },
    }
    assert list(got) == list(expected)  # dimension order
    for dim in expected:
        assert list(got[dim]) == list(expected[dim]), dim  # bin order, no extra bins
        assert got[dim] == expected[dim], dim


def test_trailer_length_from_the_vehicle_params():
    info = hand_info()
    length = info.pop("trailer_length")
    # front overhang + wheelbase + rear overhang; the sums are the lengths above, away from edges
    info["trailer_front_overhang"] = torch.tensor([1.0, 1.0, 1.5, 0.9, 1.6, 1.3, 1.2, 1.0])
    info["trailer_wheelbase"] = torch.tensor([8.0, 10.0, 9.0, 6.0, 11.0, 9.0, 8.0, 6.0])
    info["trailer_rear_overhang"] = torch.tensor([2.0, 3.0, 2.0, 1.0, 3.5, 2.6, 2.1, 2.0])
    # float32 sums 11, 14, 12.5, 7.9, 16.1, 12.9, 11.3, 9 -> 12.9 and 11.3 land like 12.8, 11.2
    got = episode_bins(info)["trailer length [m]"]
    expected = episode_bins(hand_info(trailer_length=length))["trailer length [m]"]
    assert {k: v.tolist() for k, v in got.items()} == {k: v.tolist() for k, v in expected.items()}


def test_float32_range_ends_and_out_of_range_bins():
    deg = math.pi / 180
    # episodes 0, 1: at the range ends in float32 (may round just outside); 2: beyond them
    info = {
        "route": torch.tensor([2, 3, 2], dtype=torch.int8),
        "turn_angle": torch.tensor([45 * deg, -135 * deg, 10 * deg], dtype=torch.float32),
        "crossing_angle": torch.tensor([45 * deg, 135 * deg, 30 * deg], dtype=torch.float32),
        "start_road_width": torch.tensor([10.0, 18.0, 9.0]),
        "goal_road_width": torch.tensor([10.0, 18.0, 20.0]),
        "goal_distance": torch.tensor([25.0 - 1e-5, 70.0 + 1e-5, 80.0]),
        "trailer_length": torch.tensor([7.9, 16.1, 17.0]),
    }
    got = as_lists(episode_bins(info))
    assert got["turn [deg]"] == {
        "left < 20": [False, False, True],
        "left 20-70": [True, False, False],
        "left 70-110": [False] * 3,
        "left 110-180": [False] * 3,
        "right 20-70": [False] * 3,
        "right 70-110": [False] * 3,
        "right 110-180": [False, True, False],
    }
    assert got["crossing angle [deg]"] == {
        "< 45": [False, False, True],
        "45-70": [True, False, False],
        "70-110": [False] * 3,
        "110-135": [False, True, False],
    }
    assert got["road width [m]"] == {
        "< 10": [False, False, True],
        "10-12": [True, False, False],
        "12-14": [False] * 3,
        "14-16": [False] * 3,
        "16-18": [False, True, False],
    }
    assert got["goal distance [m]"] == {
        "25-40": [True, False, False],
        "40-55": [False] * 3,
        "55-70": [False, True, False],
        "> 70": [False, False, True],
    }
    assert got["trailer length [m]"] == {
        "7.9-11.2": [True, False, False],
        "11.2-12.8": [False] * 3,
        "12.8-16.1": [False, True, False],
        "> 16.1": [False, False, True],
    }


def test_bin_edges_span_the_default_ranges():
    v, s = VehicleConfig(), SceneConfig()
    lo = v.trailer_front_overhang[0] + v.trailer_wheelbase[0] + v.trailer_rear_overhang[0]
    hi = v.trailer_front_overhang[1] + v.trailer_wheelbase[1] + v.trailer_rear_overhang[1]
    assert TRAILER_LENGTH_EDGES_M[0] == pytest.approx(lo)
    assert TRAILER_LENGTH_EDGES_M[-1] == pytest.approx(hi)
    assert (ROAD_WIDTH_EDGES_M[0], ROAD_WIDTH_EDGES_M[-1]) == pytest.approx(s.road_width)
    assert (GOAL_DISTANCE_EDGES_M[0], GOAL_DISTANCE_EDGES_M[-1]) == pytest.approx(s.goal_distance)
    degrees = tuple(math.degrees(a) for a in s.crossing_angle)
    assert (CROSSING_EDGES_DEG[0], CROSSING_EDGES_DEG[-1]) == pytest.approx(degrees)


def test_generated_scenes_fall_in_exactly_one_bin():
    g = torch.Generator().manual_seed(3)
    params = sample_vehicle_params(VehicleConfig(), 2000, generator=g)
    scenes = generate_scenes(SceneConfig(), params, generator=g)
    bins = episode_bins(scene_info(scenes, params))
    route = scenes.route.long()
    applies = {
        "turn [deg]": (route == 2) | (route == 3),
        "crossing angle [deg]": scenes.crossing,
    }
    for dim, named in bins.items():
        assert not any(name.startswith(("<", ">")) or " < " in name for name in named), dim
        hits = torch.stack(list(named.values())).sum(0)
        want = applies.get(dim, torch.ones(2000, dtype=torch.bool)).long()
        assert torch.equal(hits, want), dim
        assert all(m.any() for m in named.values()), dim  # defaults fill every bin


def hand_results() -> dict:
    """6 episodes; bin "a" = 0-3, bin "b" = 4-5."""
    return {
        "success": torch.tensor([1, 0, 0, 1, 0, 0], dtype=torch.bool),
        "collision": torch.tensor([0, 1, 0, 0, 1, 0], dtype=torch.bool),
        "jackknife": torch.tensor([0, 0, 1, 0, 0, 0], dtype=torch.bool),
        "truncated": torch.tensor([0, 0, 0, 0, 0, 1], dtype=torch.bool),
        "pos_error": torch.tensor([1.0, 2.0, 3.0, 4.0, 10.0, 20.0]),
        "tractor_heading_error": torch.tensor([30.0, 0.0, 20.0, 10.0, 5.0, 5.0]),
        "trailer_heading_error": torch.tensor([1.0, 1.0, 1.0, 1.0, 0.0, 2.0]),
    }


def test_summarize_by_category_hand_computed():
    t = torch.tensor
    bins = {
        "dim 1": {
            "a": t([1, 1, 1, 1, 0, 0], dtype=torch.bool),
            "empty": torch.zeros(6, dtype=torch.bool),
            "b": t([0, 0, 0, 0, 1, 1], dtype=torch.bool),
        },
        "dim 2": {"all": torch.ones(6, dtype=torch.bool)},
    }
    rows = summarize_by_category(hand_results(), bins)
    assert [(r["dimension"], r["bin"], r["count"]) for r in rows] == [
        ("dim 1", "a", 4),
        ("dim 1", "b", 2),
        ("dim 2", "all", 6),
    ]
    a, b, every = rows
    assert isinstance(a["count"], int)
    # a: success 0, 3; collision 1; jack-knife 2; no timeout
    assert a["success_rate"] == pytest.approx(0.5)
    assert a["collision_rate"] == pytest.approx(0.25)
    assert a["jackknife_rate"] == pytest.approx(0.25)
    assert a["timeout_rate"] == 0.0
    # p95 with linear interpolation: position 0.95 * (n - 1) in the sorted values
    assert a["pos_error_m_p95"] == pytest.approx(3.85)  # 3 + 0.85 * (4 - 3)
    assert a["tractor_heading_error_deg_p95"] == pytest.approx(28.5)  # 20 + 0.85 * 10
    assert a["trailer_heading_error_deg_p95"] == pytest.approx(1.0)
    # the success rates' 95 % Wilson intervals: 2 of 4 -> centre 0.5, half-width
    # z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / (4 n^2)) = 0.34996 (z = 1.95996)
    assert a["success_ci95"] == pytest.approx([0.15004, 0.84996], abs=1e-4)
    # 0 of 2 -> [0, z^2 / (n + z^2)] = [0, 3.8415 / 5.8415]
    assert b["success_ci95"] == pytest.approx([0.0, 0.65762], abs=1e-4)
    # b: a collision and a timeout
    assert (b["success_rate"], b["jackknife_rate"]) == (0.0, 0.0)
    assert b["collision_rate"] == pytest.approx(0.5) and b["timeout_rate"] == pytest.approx(0.5)
    assert b["pos_error_m_p95"] == pytest.approx(19.5)  # 10 + 0.95 * 10
    assert b["tractor_heading_error_deg_p95"] == pytest.approx(5.0)
    assert b["trailer_heading_error_deg_p95"] == pytest.approx(1.9)
    # all 6: sorted positions 1 2 3 4 10 20, index 4.75 -> 10 + 0.75 * 10
    assert every["success_rate"] == pytest.approx(2 / 6)
    assert every["collision_rate"] == pytest.approx(2 / 6)
    assert every["pos_error_m_p95"] == pytest.approx(17.5)
    # sorted headings 0 5 5 10 20 30, index 4.75 -> 20 + 0.75 * 10
    assert every["tractor_heading_error_deg_p95"] == pytest.approx(27.5)


def test_summarize_checks_its_inputs():
    res = hand_results()
    with pytest.raises(ValueError, match="shape"):
        summarize_by_category(res, {"d": {"x": torch.ones(5, dtype=torch.bool)}})
    del res["truncated"]
    with pytest.raises(KeyError, match="truncated"):
        summarize_by_category(res, {"d": {"x": torch.ones(6, dtype=torch.bool)}})
    info = hand_info()
    del info["trailer_length"]
    with pytest.raises(KeyError, match="trailer_length"):
        episode_bins(info)
    with pytest.raises(ValueError, match="goal_distance"):
        episode_bins(hand_info(goal_distance=torch.zeros(7)))


def test_format_category_table():
    rows = [
        {
            "dimension": "route",
            "bin": "straight road",
            "count": 4,
            "success_rate": 0.5,
            "success_ci95": [0.15, 0.85],
            "collision_rate": 0.25,
            "jackknife_rate": 0.25,
            "timeout_rate": 0.0,
            "pos_error_m_p95": 3.85,
            "tractor_heading_error_deg_p95": 28.5,
            "trailer_heading_error_deg_p95": 1.0,
        },
        {
            "dimension": "route",
            "bin": "left",
            "count": 12,
            "success_rate": 1 / 3,
            "collision_rate": 2 / 3,
            "jackknife_rate": 0.0,
            "timeout_rate": 0.0,
            "pos_error_m_p95": 19.5,
            "tractor_heading_error_deg_p95": 5.0,
            "trailer_heading_error_deg_p95": 1.9,
        },
        {
            "dimension": "goal distance [m]",
            "bin": "25-40",
            "count": 1,
            "success_rate": 1.0,
            "collision_rate": 0.0,
            "jackknife_rate": 0.0,
            "timeout_rate": 0.0,
            "pos_error_m_p95": 0.123,
            "tractor_heading_error_deg_p95": 0.0,
            "trailer_heading_error_deg_p95": 0.0,
        },
    ]
    lines = format_category_table(rows).splitlines()
    header = lines[0]
    for title in ("dimension", "bin", "n", "success %", "95 % interval", "collision %"):
        assert title in header
    for title in ("timeout %", "p95 pos m", "p95 tractor heading deg", "p95 trailer heading deg"):
        assert title in header
    assert set(lines[1]) == {"-"}
    assert len({len(line) for line in lines}) == 1  # fixed width
    first, second, third = (line.split() for line in lines[2:])
    assert first == [
        "route",
        "straight",
        "road",
        "4",
        "50.0",
        "15.0-85.0",
        "25.0",
        "25.0",
        "0.0",
        "3.85",
        "28.5",
        "1.0",
    ]
    # the dimension is named once per group
    # rows without an interval (written before rows had one): Wilson's of count and rate,
    # 4 of 12 -> 13.8-60.9 %, 1 of 1 -> 20.7-100 % (z = 1.96)
    assert second == [
        "left",
        "12",
        "33.3",
        "13.8-60.9",
        "66.7",
        "0.0",
        "0.0",
        "19.50",
        "5.0",
        "1.9",
    ]
    assert third[:6] == ["goal", "distance", "[m]", "25-40", "1", "100.0"]
    assert third[6] == "20.7-100.0"
    assert third[-3:] == ["0.12", "0.0", "0.0"]
    assert format_category_table([]).splitlines()[-1] == "(no episodes)"


def test_generic_bins_of_a_task_with_its_own_dimensions():
    """A task's ``category_dims``: edges bin (scaled) values, names label integer codes; values
    outside the edges get their own bin, every episode lands in one bin per dimension."""
    from truckrl.tasks import CategoryDim
    from truckrl.tasks.bins import generic_bins

    dims = (
        CategoryDim("bay width [m]", "bay_width", edges=(3.0, 4.0, 5.0)),
        CategoryDim(
            "start heading [deg]", "start_heading", edges=(0.0, 45.0, 90.0), scale=180 / math.pi
        ),
        CategoryDim("neighbours", "occupied", names=("none", "one", "both")),
    )
    info = {
        "bay_width": torch.tensor([3.0, 3.99, 4.0, 5.0, 5.5]),
        "start_heading": torch.tensor([0.1, 0.9, 1.5, 0.0, 0.5]),
        "occupied": torch.tensor([0, 2, 2, 1, 0]),
    }
    got = as_lists(generic_bins(info, dims))
    assert got["bay width [m]"] == {
        "3-4": [True, True, False, False, False],
        "4-5": [False, False, True, True, False],
        "> 5": [False, False, False, False, True],
    }
    # 0.1 rad = 5.7 deg, 0.9 rad = 51.6 deg, 1.5 rad = 85.9 deg, 0.5 rad = 28.6 deg
    assert got["start heading [deg]"] == {
        "0-45": [True, False, False, True, True],
        "45-90": [False, True, True, False, False],
    }
    assert got["neighbours"] == {
        "none": [True, False, False, False, True],
        "one": [False, False, False, True, False],
        "both": [False, True, True, False, False],
    }
    with pytest.raises(KeyError, match="bay_width"):
        generic_bins({}, dims[:1])
    with pytest.raises(ValueError, match="exactly one"):
        CategoryDim("x", "x")


def test_task_bins_picks_the_intersection_split_or_the_tasks_dimensions():
    from truckrl.evaluation.categories import task_bins

    assert set(task_bins("intersection", hand_info())) == set(episode_bins(hand_info()))
    assert task_bins("tests.tasks.reach", {"trailer_length": torch.ones(3)}) is None


@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [
        # Wilson's score interval at 95 %, as tabulated in R. G. Newcombe, "Two-sided confidence
        # intervals for the single proportion: comparison of seven methods", Stat. Med. 17
        # (1998), Table I (method 3) and his worked example 81 / 263
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
        (0, 20, 0.0, 0.1611),
        (1, 29, 0.0061, 0.1718),
    ],
)
def test_wilson_interval_matches_newcombes_table(k, n, lo, hi):
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=5e-5)


def test_wilson_interval_edges_and_bad_input():
    # all or none: the bound on that side is exact; the other is z^2 / (n + z^2) from it
    assert wilson_interval(0, 10) == (0.0, pytest.approx(3.8415 / 13.8415, abs=1e-5))
    assert wilson_interval(10, 10) == (pytest.approx(10 / 13.8415, abs=1e-5), 1.0)
    # narrower at a lower coverage, and a rate times n is rounded to a count
    assert wilson_interval(81, 263, level=0.9)[0] > 0.2553
    assert wilson_interval(263 * (81 / 263), 263) == wilson_interval(81, 263)
    for args, needle in (((1, 0), "n = 0"), ((5, 4), "successes = 5"), ((1, 4, 1.0), "level")):
        with pytest.raises(ValueError, match=needle):
            wilson_interval(*args)
