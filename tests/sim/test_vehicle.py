"""Tractor-trailer kinematics and vehicle config, checked against analytic and numerical answers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.vehicle import (
    VehicleConfig,
    jackknifed,
    kinematics_step,
    sample_vehicle_params,
    steady_state_articulation,
)

ROOT = Path(__file__).resolve().parents[2]


def _params(n: int, seed: int = 0, dtype=torch.float64, **overrides) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    p = {k: v.to(dtype) for k, v in sample_vehicle_params(VehicleConfig(), n, g).items()}
    for k, v in overrides.items():
        p[k] = torch.full((n,), float(v), dtype=dtype)
    return p


def _hand_truck(**overrides) -> dict[str, torch.Tensor]:
    """One truck with round numbers, so contours can be worked out by hand."""
    p = {
        "wheelbase": 3.8,
        "front_overhang": 1.4,
        "rear_overhang": 1.0,
        "tractor_width": 2.4,
        "kingpin_offset": 0.0,
        "cab_gap": 0.5,
        "trailer_wheelbase": 8.0,
        "trailer_front_overhang": 1.2,
        "trailer_rear_overhang": 2.0,
        "trailer_width": 2.5,
        "max_steer": 0.6,
        "max_articulation": 1.3,
        "max_speed": 8.0,
        "max_accel": 2.0,
        "max_jerk": 4.0,
        "max_steer_rate": 0.5,
        "max_steer_accel": 2.0,
    }
    p.update(overrides)
    return {k: torch.tensor([v], dtype=torch.float64) for k, v in p.items()}


def _rollout(pose, speeds, steers, params, dt, substeps=1):
    """Poses ``[T + 1, N, 4]`` and clamp flags ``[T, N]`` for controls ``[T, N]``."""
    poses, flags = [pose], []
    for v, d in zip(speeds, steers, strict=True):
        pose, flag = kinematics_step(pose, v, d, params, dt, substeps)
        poses.append(pose)
        flags.append(flag)
    return torch.stack(poses), torch.stack(flags)


def _angle_diff(a, b):
    return (a - b + math.pi) % (2 * math.pi) - math.pi


# --------------------------------------------------------------------------- straight driving


def test_straight_driving_is_exact():
    n, dt, steps, v = 16, 0.1, 100, 4.0
    p = _params(n)
    pose = torch.zeros(n, 4, dtype=torch.float64)
    pose[:, 0], pose[:, 1] = 3.0, -2.0
    speeds = torch.full((steps, n), v, dtype=torch.float64)
    poses, flags = _rollout(pose, speeds, torch.zeros_like(speeds), p, dt)
    t = torch.arange(steps + 1, dtype=torch.float64) * dt
    torch.testing.assert_close(poses[:, :, 0], (3.0 + v * t)[:, None].expand(-1, n))
    assert (poses[:, :, 1] == -2.0).all()
    assert (poses[:, :, 2] == 0.0).all()
    assert (poses[:, :, 3] == 0.0).all()
    assert not flags.any()


def test_straight_driving_other_heading():
    # after 2 s at 5 m/s heading 120 deg: 10 m along that heading
    p = _params(1)
    pose = torch.tensor([[1.0, 2.0, math.radians(120.0), 0.0]], dtype=torch.float64)
    speeds = torch.full((20, 1), 5.0, dtype=torch.float64)
    poses, _ = _rollout(pose, speeds, torch.zeros_like(speeds), p, 0.1)
    torch.testing.assert_close(poses[-1, 0, 0], torch.tensor(1.0 - 5.0, dtype=torch.float64))
    torch.testing.assert_close(
        poses[-1, 0, 1],
        torch.tensor(2.0 + 10.0 * math.sin(math.radians(120.0)), dtype=torch.float64),
    )


@pytest.mark.parametrize("phi0", [0.8, -1.1])
def test_initial_articulation_decays_like_analytic_solution(phi0):
    # delta = 0: phi_dot = -v / L_ka sin(phi)  =>  tan(phi / 2) = tan(phi0 / 2) exp(-v t / L_ka)
    n, dt, steps, v = 8, 0.1, 150, 5.0
    p = _params(n, max_articulation=1.5)
    l_ka = p["trailer_wheelbase"]
    t = torch.arange(steps + 1, dtype=torch.float64) * dt
    exact = 2 * torch.atan(math.tan(phi0 / 2) * torch.exp(-v * t[:, None] / l_ka))
    # Forward Euler on a contracting 1-D flow: global error <= sum of local errors
    # = h / 2 * integral |phi_ddot| dt = h / 2 * (|phi_dot(0)| - |phi_dot(T)|) (|phi_dot| decreases).
    bound = 0.5 * (v / l_ka) * abs(math.sin(phi0))
    errors = {}
    for substeps in (1, 50):
        pose = torch.zeros(n, 4, dtype=torch.float64)
        pose[:, 3] = phi0
        speeds = torch.full((steps, n), v, dtype=torch.float64)
        poses, flags = _rollout(pose, speeds, torch.zeros_like(speeds), p, dt, substeps)
        phi = poses[:, :, 3]
        assert not flags.any()
        assert (phi.sign() == math.copysign(1.0, phi0)).all()
        assert (phi.abs().diff(dim=0) < 0).all()  # monotone decay
        torch.testing.assert_close(
            poses[:, :, 0], (v * t)[:, None].expand(-1, n)
        )  # tractor unaffected
        err = (phi - exact).abs().amax(0)
        assert (err <= bound * dt / substeps).all(), (substeps, err, bound * dt / substeps)
        errors[substeps] = err
    ratio = errors[1] / errors[50]
    assert ((ratio > 40) & (ratio < 60)).all(), ratio  # first order: error ~ h


def test_one_euler_step_by_hand():
    # theta0 = 0.3, phi0 = 0.2, v = 2, delta = 0.4, dt = 0.5, L_t = 4, a = 0.25, L_ka = 10
    p = _hand_truck(wheelbase=4.0, kingpin_offset=0.25, trailer_wheelbase=10.0)
    pose = torch.tensor([[1.0, -1.0, 0.3, 0.2]], dtype=torch.float64)
    speed = torch.tensor([2.0], dtype=torch.float64)
    steer = torch.tensor([0.4], dtype=torch.float64)
    new, flag = kinematics_step(pose, speed, steer, p, 0.5)
    w = 2.0 * math.tan(0.4) / 4.0
    phi_dot = -w * (1 + 0.25 / 10.0 * math.cos(0.2)) - 2.0 / 10.0 * math.sin(0.2)
    expected = [
        1.0 + 1.0 * math.cos(0.3),
        -1.0 + 1.0 * math.sin(0.3),
        0.3 + 0.5 * w,
        0.2 + 0.5 * phi_dot,
    ]
    torch.testing.assert_close(new[0], torch.tensor(expected, dtype=torch.float64))
    assert not flag.any()


# ------------------------------------------------------------------------ constant steering


def _critical_steer(p):
    """Largest |delta| with a steady state: kingpin turning radius == L_ka."""
    k = 1.0 / torch.sqrt(p["trailer_wheelbase"] ** 2 - p["kingpin_offset"] ** 2)
    return torch.atan(k * p["wheelbase"])


def _geometric_steady_state(steer, p) -> torch.Tensor:
    """phi_ss from turning radii, in the tractor frame (rear axle at 0, heading +x)."""
    out = []
    for i in range(len(steer)):
        d = float(steer[i])
        l_t, a = float(p["wheelbase"][i]), float(p["kingpin_offset"][i])
        l_ka = float(p["trailer_wheelbase"][i])
        r1 = l_t / math.tan(abs(d))  # rear-axle turning radius
        r_k = math.hypot(r1, a)  # kingpin radius
        r2 = math.sqrt(r_k**2 - l_ka**2)  # trailer-axle radius
        # turn centre on the left; the trailer axle is on the circle of radius r2, trailing the
        # kingpin by the angle gamma seen from the centre, with its radius perpendicular to L_ka
        cx, cy = 0.0, r1
        kx, ky = -a, 0.0
        gamma = math.atan2(l_ka, r2)
        ux, uy = (kx - cx) / r_k, (ky - cy) / r_k
        c, s = math.cos(-gamma), math.sin(-gamma)
        ax, ay = cx + r2 * (c * ux - s * uy), cy + r2 * (s * ux + c * uy)
        phi = math.atan2(ky - ay, kx - ax)  # trailer heading (tractor heading is 0)
        out.append(math.copysign(1.0, d) * phi)  # mirror image for right turns
    return torch.tensor(out, dtype=torch.float64)


@pytest.mark.parametrize("fraction", [0.5, -0.8])
def test_constant_steering_converges_to_steady_state(fraction):
    n, dt, v = 12, 0.1, 5.0
    p = _params(n, seed=3)
    steer = fraction * _critical_steer(p)
    geometric = _geometric_steady_state(steer, p)
    closed_form = steady_state_articulation(steer, p)
    torch.testing.assert_close(closed_form, geometric, rtol=0, atol=1e-9)
    assert (closed_form.sign() == -steer.sign()).all()  # the trailer lags inside the turn

    pose = torch.zeros(n, 4, dtype=torch.float64)
    steps = 3000
    speeds = torch.full((steps, n), v, dtype=torch.float64)
    poses, flags = _rollout(pose, speeds, steer.expand(steps, -1), p, dt)
    assert not flags.any()
    # an equilibrium of phi_dot is also a fixed point of the Euler map, so it is hit to round-off
    torch.testing.assert_close(poses[-1, :, 3], geometric, rtol=0, atol=1e-6)
    yaw_rate = _angle_diff(poses[1:, :, 2], poses[:-1, :, 2]) / dt
    torch.testing.assert_close(
        yaw_rate, (v * torch.tan(steer) / p["wheelbase"]).expand(steps, -1), rtol=0, atol=1e-9
    )


def test_no_steady_state_beyond_critical_steer_folds_to_stop():
    n = 6
    p = _params(n, seed=5)
    steer = 1.3 * _critical_steer(p)
    assert steady_state_articulation(steer, p).isnan().all()
    assert not steady_state_articulation(0.9 * steer / 1.3, p).isnan().any()
    steps = 2000
    speeds = torch.full((steps, n), 5.0, dtype=torch.float64)
    poses, flags = _rollout(
        torch.zeros(n, 4, dtype=torch.float64), speeds, steer.expand(steps, -1), p, 0.1
    )
    assert flags[-1].all()
    torch.testing.assert_close(poses[-1, :, 3], -p["max_articulation"])
    assert jackknifed(poses[-1], p).all()


def test_steady_state_zero_steer_is_zero():
    p = _params(4)
    assert (steady_state_articulation(torch.zeros(4, dtype=torch.float64), p) == 0).all()


# ------------------------------------------------------------- convergence to a fine reference

DT, STEPS = 0.1, 100  # paper: dt = 0.1 s; 10 s horizon


def _reference_problem(n=24, seed=11):
    p = _params(n, seed=seed, max_articulation=3.0)  # stop out of reach: pure ODE, no clamp
    rng = np.random.default_rng(seed)
    t = np.arange(STEPS)[:, None] * DT
    phase = rng.uniform(0, 2 * np.pi, n)
    freq = rng.uniform(0.1, 0.3, n)
    speed = p["max_speed"].numpy() * (0.5 + 0.4 * np.sin(2 * np.pi * 0.07 * t + phase))
    steer = 0.5 * p["max_steer"].numpy() * np.sin(2 * np.pi * freq * t + phase)
    return p, speed, steer


def _rk4_reference(p, speed, steer, m) -> np.ndarray:
    """Classical RK4 with m sub-steps per control step; controls held over each step."""
    l_t, a = p["wheelbase"].numpy(), p["kingpin_offset"].numpy()
    l_ka = p["trailer_wheelbase"].numpy()

    def f(s, v, k):
        _, _, th, ph = s
        w = v * k
        return np.stack(
            (
                v * np.cos(th),
                v * np.sin(th),
                w,
                -w * (1 + a / l_ka * np.cos(ph)) - v / l_ka * np.sin(ph),
            )
        )

    s = np.zeros((4, speed.shape[1]))
    out, h = [s], DT / m
    for v, d in zip(speed, steer, strict=True):
        k = np.tan(d) / l_t
        for _ in range(m):
            k1 = f(s, v, k)
            k2 = f(s + 0.5 * h * k1, v, k)
            k3 = f(s + 0.5 * h * k2, v, k)
            k4 = f(s + h * k3, v, k)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(s)
    return np.stack(out).transpose(0, 2, 1)  # [T + 1, N, 4]


def _euler_errors(p, speed, steer, ref, substeps):
    pose = torch.zeros(speed.shape[1], 4, dtype=torch.float64)
    poses, flags = _rollout(pose, torch.from_numpy(speed), torch.from_numpy(steer), p, DT, substeps)
    assert not flags.any()
    d = poses.numpy() - ref
    pos = np.hypot(d[..., 0], d[..., 1]).max(0)
    return pos, np.abs(_angle_diff(d[..., 2], 0)).max(0), np.abs(_angle_diff(d[..., 3], 0)).max(0)


def _check_against_reference(m):
    p, speed, steer = _reference_problem()
    ref = _rk4_reference(p, speed, steer, m)
    assert np.abs(ref[..., 3]).max() < 1.0  # far from the stop and from wrapping
    l_t, a, l_ka = (p[k].numpy() for k in ("wheelbase", "kingpin_offset", "trailer_wheelbase"))
    w = speed * np.tan(steer) / l_t
    # theta_dot is constant over a step, so Euler's heading is exact and its position error is
    # the sum of per-sub-step chord errors |v| h |w| h / 2: bound = h / 2 * sum |v w| DT.
    pos_bound = 0.5 * DT * np.sum(np.abs(speed * w) * DT, axis=0)
    # phi: contracting flow (d phi_dot / d phi < 0 along the path) so global error <= sum of
    # local errors h^2 / 2 |phi_ddot|, with phi_ddot = (d phi_dot / d phi) phi_dot.
    phi = ref[:-1, :, 3]
    k = np.tan(steer) / l_t
    phi_dot = -w * (1 + a / l_ka * np.cos(phi)) - speed / l_ka * np.sin(phi)
    slope = -(speed / l_ka) * (np.cos(phi) - a * k * np.sin(phi))
    assert (slope < 0).all()
    phi_bound = 0.5 * DT * np.sum(np.abs(slope * phi_dot) * DT, axis=0)

    errs = {s: _euler_errors(p, speed, steer, ref, s) for s in (1, 2, 4, 20)}
    for s, (pos, theta, phi_err) in errs.items():
        assert (theta < 1e-9).all()
        assert (pos <= pos_bound / s).all(), (s, pos.max(), pos_bound.min() / s)
        assert (phi_err <= phi_bound / s).all(), (s, phi_err.max(), phi_bound.min() / s)
    for i in (0, 2):  # position and articulation error shrink linearly with dt / substeps
        for s, lo, hi in ((2, 1.8, 2.2), (4, 3.5, 4.5), (20, 16.0, 24.0)):
            ratio = errs[1][i] / errs[s][i]
            assert ((ratio > lo) & (ratio < hi)).all(), (i, s, ratio)
    # substeps = 20 (h = 5 ms): on this 10 s, up-to-10 m/s drive the bounds above come to a few cm
    # and ~1 mrad; the measured errors sit well inside them
    pos20, _, phi20 = errs[20]
    assert pos20.max() < 0.05 and phi20.max() < 2e-3, (pos20.max(), phi20.max())
    return ref


def test_matches_fine_rk4_reference():
    # RK4 at dt / 100: its own error is O(h^4) ~ 1e-12; shown by agreement with dt / 50
    ref = _check_against_reference(100)
    p, speed, steer = _reference_problem()
    assert np.abs(_rk4_reference(p, speed, steer, 50) - ref).max() < 1e-9


@pytest.mark.slow
def test_matches_rk4_reference_at_dt_over_1000():
    _check_against_reference(1000)


# ----------------------------------------------------------------- wrapping, clamp, jack-knife


def test_heading_wraps_to_minus_pi_pi():
    p = _params(2, max_articulation=1.3)
    pose = torch.tensor(
        [[0.0, 0.0, math.pi - 0.01, 0.0], [0.0, 0.0, -math.pi + 0.01, 0.0]], dtype=torch.float64
    )
    speed = torch.tensor([5.0, 5.0], dtype=torch.float64)
    steer = torch.tensor([0.3, -0.3], dtype=torch.float64)
    new, _ = kinematics_step(pose, speed, steer, p, 0.1)
    dtheta = 0.1 * 5.0 * math.tan(0.3) / p["wheelbase"]
    expected = torch.stack(
        (math.pi - 0.01 + dtheta[0] - 2 * math.pi, -math.pi + 0.01 - dtheta[1] + 2 * math.pi)
    )
    torch.testing.assert_close(new[:, 2], expected)
    assert ((new[:, 2] >= -math.pi) & (new[:, 2] < math.pi)).all()


def test_articulation_input_outside_pi_is_wrapped():
    p = _params(1, max_articulation=1.3)
    pose = torch.tensor([[0.0, 0.0, 0.0, 0.1 + 2 * math.pi]], dtype=torch.float64)
    zero = torch.zeros(1, dtype=torch.float64)
    new, flag = kinematics_step(pose, zero, zero, p, 0.1)
    torch.testing.assert_close(new[0, 3], torch.tensor(0.1, dtype=torch.float64))
    assert not flag.any()


def test_articulation_clamp_and_flag():
    p = _params(3, max_articulation=1.2)
    # env 0 pushed past +stop, env 1 pushed past -stop, env 2 at the stop but moving away
    pose = torch.tensor([[0, 0, 0, 1.19], [0, 0, 0, -1.19], [0, 0, 0, 1.2]], dtype=torch.float64)
    speed = torch.full((3,), 8.0, dtype=torch.float64)
    steer = torch.tensor([-0.6, 0.6, 0.6], dtype=torch.float64)  # phi_dot sign = -steer sign
    new, flag = kinematics_step(pose, speed, steer, p, 0.1)
    assert flag.tolist() == [True, True, False]
    assert new[0, 3] == 1.2 and new[1, 3] == -1.2
    assert new[2, 3] < 1.2
    assert jackknifed(new, p).tolist() == [True, True, False]


def test_clamp_with_substeps():
    # pushed past the stop in an early sub-step: flagged, and held at the stop to the end
    p = _params(1, max_articulation=1.0)
    pose = torch.tensor([[0.0, 0.0, 0.0, 0.99]], dtype=torch.float64)
    speed = torch.tensor([8.0], dtype=torch.float64)
    steer = torch.tensor([-0.6], dtype=torch.float64)
    new, flag = kinematics_step(pose, speed, steer, p, 0.1, substeps=10)
    assert flag.item() and new[0, 3].item() == 1.0


def test_not_jackknifed_straight_for_many_trucks():
    p = _params(1000, seed=7, dtype=torch.float32)
    pose = torch.zeros(1000, 4)
    pose[:, :2] = torch.randn(1000, 2) * 50
    pose[:, 2] = (torch.rand(1000) * 2 - 1) * math.pi
    assert not jackknifed(pose, p).any()


def test_jackknifed_when_trailer_corner_enters_cab():
    # Hand truck, tractor frame with the kingpin (a = 0) at the rear axle: the cab spans
    # x in [tfo + gap, L_t + front overhang] = [1.7, 5.2], |y| <= 1.2. The trailer's front-right
    # corner is (tfo, -w/2) = (1.2, -1.25) in the trailer frame, rotated by phi.
    p = _hand_truck()
    for phi, inside in ((0.8, True), (-0.8, True), (0.3, False), (-0.3, False)):
        sign = 1.0 if phi > 0 else -1.0
        cx = 1.2 * math.cos(phi) + 1.25 * math.sin(abs(phi))
        cy = 1.2 * math.sin(phi) - sign * 1.25 * math.cos(phi)
        assert ((1.7 <= cx <= 5.2) and abs(cy) <= 1.2) == inside
        pose = torch.tensor([[10.0, -4.0, 0.7, phi]], dtype=torch.float64)
        assert abs(phi) < p["max_articulation"].item()  # contour test only, not the stop
        assert jackknifed(pose, p).item() == inside, phi


def test_jackknifed_when_folded_back():
    p = _params(200, seed=2, max_articulation=3.1)
    pose = torch.zeros(200, 4, dtype=torch.float64)
    pose[:, 3] = 2.6  # trailer folded over the cab, well short of the stop
    assert jackknifed(pose, p).all()


@pytest.mark.parametrize("dt", [0.0, -0.1, float("nan"), float("inf")])
def test_bad_dt_rejected(dt):
    p = _params(1)
    zero = torch.zeros(1, dtype=torch.float64)
    with pytest.raises(ConfigError, match="dt"):
        kinematics_step(torch.zeros(1, 4, dtype=torch.float64), zero, zero, p, dt)


@pytest.mark.parametrize("substeps", [0, -1, 1.5])
def test_bad_substeps_rejected(substeps):
    p = _params(1)
    zero = torch.zeros(1, dtype=torch.float64)
    with pytest.raises(ConfigError, match="substeps"):
        kinematics_step(torch.zeros(1, 4, dtype=torch.float64), zero, zero, p, 0.1, substeps)


# --------------------------------------------------------------------------- VehicleConfig


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("tractor_width", (-2.5, 2.5)),
        ("trailer_width", (-1.0, -0.5)),
        ("max_speed", (10.0, 6.0)),
        ("wheelbase", (4.2, 3.4)),
        ("kingpin_offset", (0.0, 1.5)),  # behind the tractor's rear end (rear overhang >= 0.6)
        ("kingpin_offset", (-0.5, 0.7)),  # overlaps rear_overhang min 0.6
        ("max_steer", (0.0, 0.5)),
        ("min_speed", 7.0),  # above max_speed min
    ],
)
def test_bad_vehicle_config_names_field(field, value):
    with pytest.raises(ConfigError, match=f"vehicle.{field}"):
        VehicleConfig(**{field: value})
