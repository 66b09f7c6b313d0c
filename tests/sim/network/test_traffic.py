"""Traffic on road networks (issue 42, item 2) against answers that do not reuse the code under
test: vehicle poses recomputed in numpy from ``(lane, s)`` by walking the lane polylines, box
overlap by a numpy separating-axis test on the boxes' corners, gaps and zone radii by hand."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim import (
    VehicleConfig,
    lidar_scan,
    sample_vehicle_params,
    truck_boxes,
    truck_collides,
)
from truckrl.sim.network import NetworkConfig, random_network
from truckrl.sim.network.layout import network_from_blocks
from truckrl.sim.network.traffic import (
    TrafficConfig,
    ego_boxes,
    place_vehicles,
    spawn_traffic,
    step_traffic,
    traffic_segments,
    with_traffic,
)
from truckrl.sim.vehicle import trailer_rear_offset

DT = 0.1


# ------------------------------------------------------------------------------ numpy oracle
def poses(net, tr) -> tuple[np.ndarray, np.ndarray]:
    """Centres ``[n, M, 2]`` and headings ``[n, M]`` of the vehicles, walked along the lane
    polylines in float64 numpy from ``tr.lane`` and ``tr.s``."""
    lanes = net.lanes.double().numpy()
    n, M = tr.s.shape
    pts = lanes[np.arange(n)[:, None], tr.lane.numpy()]  # [n, M, Q, 2]
    seg = np.diff(pts, axis=2)
    step = np.linalg.norm(seg, axis=-1)
    cum = np.concatenate((np.zeros((n, M, 1)), np.cumsum(step, -1)), -1)
    s = tr.s.double().numpy()
    real = np.where(step > 1e-6, np.arange(step.shape[-1]), -1).max(-1)
    k = np.minimum(np.clip((cum[..., 1:] <= s[..., None]).sum(-1), 0, None), real)
    k = np.minimum(k, real)
    take = lambda a: np.take_along_axis(a, k[..., None], -1)[..., 0]  # noqa: E731
    t = (s - take(cum[..., :-1])) / np.maximum(take(step), 1e-9)
    d = np.stack((take(seg[..., 0]), take(seg[..., 1])), -1)
    p0 = np.stack((take(pts[..., :-1, 0]), take(pts[..., :-1, 1])), -1)
    return p0 + t[..., None] * d, np.arctan2(d[..., 1], d[..., 0])


def corners(xy, heading, length, width) -> np.ndarray:
    """``[..., 4, 2]`` corners of boxes centred at ``xy`` along ``heading``."""
    u = np.stack((np.cos(heading), np.sin(heading)), -1)
    v = np.stack((-u[..., 1], u[..., 0]), -1)
    hl, hw = (0.5 * length)[..., None], (0.5 * width)[..., None]
    return np.stack(
        (xy + hl * u + hw * v, xy - hl * u + hw * v, xy - hl * u - hw * v, xy + hl * u - hw * v),
        -2,
    )


def overlapping_pairs(c: np.ndarray, active: np.ndarray) -> np.ndarray:
    """``[n, M, M]`` bool: boxes ``i != j`` of one network (corners ``c [n, M, 4, 2]``) overlap,
    both active: no edge normal of either separates their corner projections."""
    e = np.roll(c, -1, axis=2) - c  # [n, M, 4, 2] edges
    normals = np.stack((-e[..., 1], e[..., 0]), -1)[:, :, :2]  # two per box suffice
    n, M = c.shape[:2]
    ax = np.concatenate(
        (
            np.broadcast_to(normals[:, :, None], (n, M, M, 2, 2)),
            np.broadcast_to(normals[:, None, :], (n, M, M, 2, 2)),
        ),
        3,
    )  # [n, i, j, 4 axes, 2]
    a = ax[:, :, :, :, None]  # [n, i, j, axes, 1, 2]
    pi = (c[:, :, None, None] * a).sum(-1)  # [n, i, j, axes, corners]
    pj = (c[:, None, :, None] * a).sum(-1)
    apart = (pi.max(-1) <= pj.min(-1) + 1e-9) | (pj.max(-1) <= pi.min(-1) + 1e-9)
    hit = ~apart.any(-1)
    hit &= active[:, :, None] & active[:, None, :] & ~np.eye(M, dtype=bool)
    return hit


def lane_gaps(net, tr) -> np.ndarray:
    """Bumper gaps [m] between each vehicle and the next one ahead on its lane (inf: none)."""
    lane, s, ln = tr.lane.numpy(), tr.s.double().numpy(), tr.length.double().numpy()
    act = tr.present().numpy()
    same = (lane[:, :, None] == lane[:, None, :]) & act[:, :, None] & act[:, None, :]
    d = s[:, None, :] - s[:, :, None]
    gap = d - 0.5 * (ln[:, :, None] + ln[:, None, :])
    return np.where(same & (d > 0), gap, np.inf).min(-1)


def rollout(net, cfg, tr, steps, ego=None):
    """The traffic after each of ``steps`` steps (``ego``: the truck's boxes)."""
    out = []
    for _ in range(steps):
        tr = step_traffic(tr, cfg, DT, ego)
        out.append(tr)
    return out


# ---------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def random_run():
    """120 random networks with dense traffic, 200 steps (20 s)."""
    g = torch.Generator().manual_seed(1)
    net = random_network(NetworkConfig(), 120, g)
    cfg = TrafficConfig(density=(2.0, 4.0))
    tr = spawn_traffic(net, cfg, g)
    return net, cfg, [tr, *rollout(net, cfg, tr, 200)]


def straight(length=60.0, width=9.0):
    return network_from_blocks(
        {"road_width": width, "blocks": [{"type": "straight", "length": length}]}
    )


def two(lane, s, length, width, v0):
    t = lambda x, d=torch.float32: torch.tensor([x], dtype=d)  # noqa: E731
    return t(lane, torch.long), t(s), t(length), t(width), t(v0)


# ------------------------------------------------------------------------------------- tests
def test_vehicles_never_overlap_and_follow_their_lanes(random_run):
    net, cfg, states = random_run
    assert states[0].active.sum() > 5 * len(net)  # dense: most networks hold 6 to 8
    lanes = net.lanes.double().numpy()
    for k, tr in enumerate(states):
        xy, heading = poses(net, tr)
        act = tr.present().numpy()
        c = corners(xy, heading, tr.length.double().numpy(), tr.width.double().numpy())
        hit = overlapping_pairs(c, act)
        assert not hit.any(), (
            f"step {k}: vehicles overlap in networks {np.flatnonzero(hit.any((1, 2)))[:5]}"
        )
        if k % 50 == 0:
            # the emitted outlines are the boxes at the numpy poses, on the lane centre-lines
            seg, mask = traffic_segments(tr)
            ends = seg.double().numpy().reshape(*act.shape, 4, 4)[..., :2]
            np.testing.assert_allclose(ends[act], np.roll(c, 1, axis=-2)[act], atol=2e-3)
            assert (mask.numpy().reshape(*act.shape, 4) == act[..., None]).all()
            centre = ends.mean(-2)[act]  # [V, 2]
            pts = lanes[np.nonzero(act)[0], tr.lane.numpy()[act]]  # [V, Q, 2]
            a, b = pts[:, :-1], pts[:, 1:]
            d = b - a
            f = ((centre[:, None] - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)
            q = a + np.clip(f, 0.0, 1.0)[..., None] * d
            assert np.linalg.norm(centre[:, None] - q, axis=-1).min(-1).max() < 1e-3


def test_speeds_stay_in_range_and_traffic_moves(random_run):
    net, cfg, states = random_run
    act = states[0].active
    v0 = states[0].v0[act]
    assert (v0 >= cfg.speed[0]).all() and (v0 <= cfg.speed[1]).all()
    v = torch.stack([tr.v[act] for tr in states])
    assert (v >= 0).all() and (v <= v0 + 1e-5).all()
    assert v.mean() > 0.3 * v0.mean()  # most of it flows


def test_vehicles_keep_the_configured_gap(random_run):
    net, cfg, states = random_run
    worst = min(lane_gaps(net, tr).min() for tr in states)
    assert worst >= 0.9 * cfg.min_gap


def test_a_follower_stops_behind_a_stopped_leader():
    net, cfg = straight(), TrafficConfig()
    lane, s, length, width, v0 = (
        torch.tensor([[0, 0]]), torch.tensor([[5.0, 40.0]]), torch.tensor([[4.0, 5.0]]),
        torch.tensor([[1.8, 1.8]]), torch.tensor([[10.0, 0.0]]),
    )  # fmt: skip
    tr = place_vehicles(net, cfg, lane, s, length, width, v0)
    states = rollout(net, cfg, tr, 300)
    end = states[-1]
    gap = float(end.s[0, 1] - end.s[0, 0]) - 0.5 * (4.0 + 5.0)
    assert float(end.s[0, 1]) == 40.0  # the leader never moved
    assert cfg.min_gap - 1e-3 <= gap <= cfg.min_gap + 0.3
    assert float(end.v[0, 0]) < 0.05
    assert max(float(t.v[0, 0]) for t in states) > 4.0  # it drove there


def test_a_vehicle_stops_behind_the_ego_truck_standing_on_its_lane():
    w = 9.0
    net, cfg = straight(60.0, w), TrafficConfig()
    params = sample_vehicle_params(VehicleConfig(), 1, torch.Generator().manual_seed(0))
    pose = torch.tensor([[40.0, -0.25 * w, 0.0, 0.0]])  # on lane 0, facing along it
    tractor, trailer, _ = truck_boxes(pose, params)
    ego = ego_boxes(tractor, trailer)
    tail = 40.0 - float(trailer_rear_offset(params)[0])  # the trailer's rear end (x)
    tr = place_vehicles(net, cfg, *(t.unsqueeze(0) for t in two(0, 5.0, 4.0, 1.8, 10.0)))
    end = rollout(net, cfg, tr, 300, ego)[-1]
    gap = tail - (float(end.s[0, 0]) + 2.0)
    assert cfg.min_gap - 1e-3 <= gap <= cfg.min_gap + 0.3 and float(end.v[0, 0]) < 0.05


def test_a_vehicle_yields_at_a_crossing_while_another_is_in_it():
    w = 9.0
    net = network_from_blocks(
        {"road_width": w, "blocks": [{"type": "crossing", "angle_deg": 90, "arm": 30}]}
    )
    cfg = TrafficConfig()
    # entered at the origin along +x, the crossing is centred on (30, 0); lane 0 runs along road
    # 0 (+x, y = -w/4), lane 2 along road 1 (+y, x = 30 + w/4); A stands at the centre, B comes
    # from 25 m south
    tr = place_vehicles(
        net, cfg, torch.tensor([[0, 2]]), torch.tensor([[30.0, 5.0]]),
        torch.tensor([[4.5, 4.5]]), torch.tensor([[1.8, 1.8]]), torch.tensor([[0.0, 10.0]]),
    )  # fmt: skip
    radius = 0.5 * w * math.sqrt(2.0) + cfg.zone_margin  # the zone: the square's corner + margin
    centre = np.array([30.0, 0.0])
    states = rollout(net, cfg, tr, 200)
    for t in states:
        xy, _ = poses(net, t)
        assert np.linalg.norm(xy[0, 1] - centre) >= radius + 2.25 - 1e-3  # B never enters
    assert float(states[-1].v[0, 1]) < 0.05
    assert (
        np.linalg.norm(poses(net, states[-1])[0][0, 1] - centre) < radius + 2.25 + cfg.min_gap + 0.5
    )
    # A drives off: B goes through
    go = replace(states[-1], v0=torch.tensor([[10.0, 10.0]]))
    after = rollout(net, cfg, go, 150)
    assert max(float(t.s[0, 1]) for t in after) > 30.0 + 5.0


def test_a_vehicle_yields_at_a_crossing_while_the_truck_is_in_it():
    """The truck's box in a zone holds the vehicles outside it as another vehicle does, even out
    of their corridors; with the truck away they drive through."""
    w = 9.0
    net = network_from_blocks(
        {"road_width": w, "blocks": [{"type": "crossing", "angle_deg": 90, "arm": 30}]}
    )
    cfg = TrafficConfig()
    # B comes from 25 m south on lane 2 (+y, x = 30 + w/4); the ego box (10 m x 2.5 m along +x)
    # stands on road 0 with its centre 6 m before the crossing's centre: inside the zone
    # (6.4 m < radius + 5 m) and 8.25 m to the side of B's path, beyond B's corridor
    # (0.9 + 5 + corridor_margin = 6.4 m)
    tr = place_vehicles(
        net, cfg, torch.tensor([[2]]), torch.tensor([[5.0]]), torch.tensor([[4.5]]),
        torch.tensor([[1.8]]), torch.tensor([[10.0]]),
    )  # fmt: skip
    radius = 0.5 * w * math.sqrt(2.0) + cfg.zone_margin
    centre = np.array([30.0, 0.0])

    def box(x: float) -> torch.Tensor:
        return torch.tensor([[[x, -0.25 * w, 1.0, 0.0, 5.0, 1.25]]])

    assert math.hypot(6.0, 0.25 * w) < radius + 5.0
    held = rollout(net, cfg, tr, 200, box(24.0))
    for t in held:
        assert np.linalg.norm(poses(net, t)[0][0, 0] - centre) >= radius + 2.25 - 1e-3
    assert float(held[-1].v[0, 0]) < 0.05
    free = rollout(net, cfg, tr, 200, box(0.0))
    assert max(float(t.s[0, 0]) for t in free) > 30.0 + 5.0


def test_a_vehicle_waiting_to_reappear_inside_a_zone_holds_nobody_at_it():
    """A vehicle off the road whose home lane starts inside a junction zone, kept off by the
    truck near that start, is no rival at the zone: a later slot drives through the crossing."""
    w = 9.0
    net = network_from_blocks(
        {
            "road_width": w,
            "blocks": [
                {"type": "straight", "length": 40},
                {"type": "crossing", "angle_deg": 90, "arm": 20},
            ],
        }
    )
    # the crossing is centred on (60, 0); lane 11 runs north at x = 62.25 from y = -20, so its
    # reappearance spot (2.25 m in) is 17.75 m from the centre, inside the zone's reach
    # (0.5 w sqrt(2) + zone_margin + 2.25 = 20.6 m at zone_margin 12); lane 0 runs east on the
    # straight into the crossing
    cfg = TrafficConfig(zone_margin=12.0)
    assert math.hypot(2.25, 17.75) < 0.5 * w * math.sqrt(2.0) + 12.0 + 2.25
    tr = place_vehicles(
        net, cfg, torch.tensor([[11, 0]]), torch.tensor([[30.0, 5.0]]),
        torch.tensor([[4.5, 4.5]]), torch.tensor([[1.8, 1.8]]), torch.tensor([[10.0, 10.0]]),
    )  # fmt: skip
    tr = replace(tr, waiting=torch.tensor([[True, False]]))
    # the truck, a 10 m box standing south of the crossing: 27 m from slot 0's spot (within
    # appear_clearance + 5 m: slot 0 stays off), 45 m from the centre (not in the zone), 40 m
    # beside slot 1's lane (not in its corridor)
    ego = torch.tensor([[[62.25, -45.0, 0.0, 1.0, 5.0, 1.25]]])
    assert math.hypot(0.0, 45.0 - 17.75) < 5.0 + cfg.appear_clearance
    states = rollout(net, cfg, tr, 200, ego)
    assert all(bool(t.waiting[0, 0]) for t in states)  # slot 0 never reappears
    assert max(float(poses(net, t)[0][0, 1, 0]) for t in states) > 60.0 + 0.5 * w  # slot 1 crossed


def test_at_an_open_road_end_a_vehicle_leaves_and_reappears_on_its_home_lane():
    net, cfg = straight(40.0), TrafficConfig()
    tr = place_vehicles(net, cfg, *(t.unsqueeze(0) for t in two(0, 30.0, 4.0, 1.8, 10.0)))
    states = rollout(net, cfg, tr, 60)
    gone = [k for k, t in enumerate(states) if bool(t.waiting[0, 0])]
    assert gone, "it never left"
    k = gone[0]
    assert float(states[k - 1].s[0, 0]) > 40.0 - 10.0 * DT  # it left from the road end
    assert not traffic_segments(states[k])[1].any()  # off the road: no outline
    back = states[k + 1]  # the start was clear: it is back, at rest, its rear on the road start
    assert not bool(back.waiting[0, 0]) and int(back.lane[0, 0]) == 0
    assert float(back.s[0, 0]) == pytest.approx(2.0) and float(back.v[0, 0]) == 0.0


def test_a_vehicle_does_not_reappear_near_the_truck():
    """A truck parked in the other lane within ``appear_clearance`` of the home lane's start
    keeps the vehicle off the road; one farther away does not."""
    w, cfg = 9.0, TrafficConfig()
    net = straight(60.0, w)
    tr = place_vehicles(net, cfg, *(t.unsqueeze(0) for t in two(0, 50.0, 4.0, 1.8, 10.0)))

    def parked(x: float) -> torch.Tensor:  # a 16 m box in lane 1 (along -x, left of centre)
        return torch.tensor([[[x, 0.25 * w, -1.0, 0.0, 8.0, 1.25]]])

    near, far = rollout(net, cfg, tr, 40, parked(20.0)), rollout(net, cfg, tr, 40, parked(50.0))
    assert any(bool(t.waiting[0, 0]) for t in near), "it never left"
    assert bool(near[-1].waiting[0, 0])  # the truck's end is about 10 m from the spot: < 30 m
    back = [k for k, t in enumerate(far) if not bool(t.waiting[0, 0]) and float(t.s[0, 0]) < 10]
    assert back, "it never came back with the truck 50 m away"
    assert (50.0 - 8.0) - 2.0 > cfg.appear_clearance > math.hypot(20.0 - 2.0, 0.5 * w) - 8.0


def test_lidar_sees_a_car_and_touching_one_collides():
    w = 9.0
    net = straight(60.0, w)
    cfg = TrafficConfig()
    tr = place_vehicles(net, cfg, *(t.unsqueeze(0) for t in two(0, 30.0, 4.0, 2.0, 0.0)))
    seg, mask, kind = with_traffic(net.segments, net.mask, net.kind, tr)
    y = -0.25 * w  # lane 0: along +x, a quarter width right of the road's centre-line
    beam = torch.tensor([0.0])
    origin, heading = torch.tensor([[10.0, y]]), torch.tensor([0.0])
    assert float(lidar_scan(origin, heading, net.segments, net.mask, beam, 50.0)) == 50.0
    assert float(lidar_scan(origin, heading, seg, mask, beam, 50.0)) == pytest.approx(
        18.0, abs=1e-3
    )
    assert int(kind[0, -1]) == 1 and mask[0, -4:].all()
    params = sample_vehicle_params(VehicleConfig(), 1, torch.Generator().manual_seed(0))
    front = float(params["wheelbase"][0] + params["front_overhang"][0])
    rear = 30.0 - 2.0  # the car's rear bumper

    def pose(x: float) -> torch.Tensor:
        return torch.tensor([[x, y, 0.0, 0.0]])

    assert not truck_collides(pose(rear - front - 0.01), params, net.segments, net.mask)
    assert not truck_collides(pose(rear - front - 0.01), params, seg, mask)
    assert truck_collides(pose(rear - front + 0.05), params, seg, mask)


def test_spawns_keep_out_of_junctions_and_reserved_discs():
    g = torch.Generator().manual_seed(2)
    net = random_network(NetworkConfig(), 100, g)
    cfg = TrafficConfig(density=(5.0, 5.0))
    first = net.lanes[:, 0, 0]  # reserve a 15 m disc round the start of each network's lane 0
    reserved = torch.cat((first, torch.full((100, 1), 15.0)), -1).unsqueeze(1)
    tr = spawn_traffic(net, cfg, g, reserved)
    xy, _ = poses(net, tr)
    act = tr.present().numpy()
    assert act.sum() > 4 * len(net)
    d = np.linalg.norm(xy - first.double().numpy()[:, None], axis=-1)
    assert (d[act] > 15.0).all()
    # no vehicle centre within a junction's road surface (hand radii, as in the yield test)
    t, p = net.block_type.numpy(), net.block_params.double().numpy()
    sock = net.sockets.double().numpy()[..., :2]
    w = net.road_width.double().numpy()
    for i in range(len(net)):
        for k in np.flatnonzero((t[i] == 2) | (t[i] == 3)):
            c = 0.5 * (sock[i, k, 0] + sock[i, k, 1])
            r = (
                0.5
                * w[i]
                * (
                    math.sqrt(2 + 2 * abs(math.cos(p[i, k, 0]))) / math.sin(p[i, k, 0])
                    if t[i, k] == 2
                    else math.sqrt(2)
                )
            )
            assert (np.linalg.norm(xy[i][act[i]] - c, axis=-1) > r).all()


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("density", (3.0, 1.0), "traffic.density"),
        ("max_vehicles", -1, "traffic.max_vehicles"),
        ("speed", (0.0, 0.0), "traffic.speed"),
        ("truck_share", 1.5, "traffic.truck_share"),
    ],
)
def test_bad_config_is_a_one_line_error(field, value, needle):
    with pytest.raises(ConfigError, match=needle) as e:
        TrafficConfig(**{field: value})
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_no_overlap_on_1000_networks_over_400_steps():
    g = torch.Generator().manual_seed(3)
    net = random_network(NetworkConfig(), 1000, g)
    cfg = TrafficConfig(density=(2.0, 4.0))
    tr = spawn_traffic(net, cfg, g)
    for k in range(401):
        if k:
            tr = step_traffic(tr, cfg, DT)
        xy, heading = poses(net, tr)
        c = corners(xy, heading, tr.length.double().numpy(), tr.width.double().numpy())
        assert not overlapping_pairs(c, tr.present().numpy()).any(), f"step {k}"
        assert lane_gaps(net, tr).min() >= 0.9 * cfg.min_gap
