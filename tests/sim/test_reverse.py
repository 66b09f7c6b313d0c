"""Reversing (v < 0): kinematics against independent answers, jack-knife, and signed speed control.

Independent answers used here (none reuses the code under test):

* straight reversing, ``delta = 0``: ``phi_dot = -v / L_ka sin(phi)`` has the exact solution
  ``tan(phi / 2) = tan(phi0 / 2) exp(-v t / L_ka)``; with ``v < 0`` the articulation *grows*
  (open-loop unstable), while the rear axle moves back exactly ``v t`` along its heading;
* constant steering: the rear axle runs on a circle of radius ``L_t / tan(delta)``, backwards,
  with ``theta(t) = theta0 + v tan(delta) / L_t t``;
* a classical RK4 integrator written here, in float64, on the ODE of the vehicle docstring;
* no-slip hitch geometry: the trailer axle, computed here by hand from the pose, moves along the
  trailer heading (reverse included);
* the control bounds ``[-max_reverse_speed, max_speed]`` per truck.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from tests.sim.test_vehicle import _rk4_reference
from truckrl.config.fields import ConfigError
from truckrl.sim.control import CONTROL_KEYS, LATERAL_MODES, LONGITUDINAL_MODES, Control
from truckrl.sim.vehicle import (
    VehicleConfig,
    jackknifed,
    kinematics_step,
    sample_vehicle_params,
)

DT = 0.1  # [s] paper


def _params(n: int, seed: int = 0, **overrides) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    p = sample_vehicle_params(VehicleConfig(), n, g, reverse=True)
    p = {k: v.to(torch.float64) for k, v in p.items()}
    for k, v in overrides.items():
        p[k] = torch.full((n,), float(v), dtype=torch.float64)
    return p


def _rollout(pose, speed, steer, params, steps, substeps=1):
    """Poses ``[steps + 1, N, 4]`` and clamp flags ``[steps, N]`` for controls held constant
    (``speed``, ``steer`` ``[N]``) or given per step (``[steps, N]``)."""
    poses, flags = [pose], []
    for t in range(steps):
        v = speed[t] if speed.dim() == 2 else speed
        d = steer[t] if steer.dim() == 2 else steer
        pose, flag = kinematics_step(pose, v, d, params, DT, substeps)
        poses.append(pose)
        flags.append(flag)
    return torch.stack(poses), torch.stack(flags)


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


# ------------------------------------------------------------------------ straight reversing
def test_straight_reversing_articulation_grows_like_the_exact_solution():
    n, steps, phi0 = 12, 50, 0.3
    p = _params(n, max_articulation=3.0)  # the stop out of reach: the pure ODE
    v = -p["max_reverse_speed"]  # 1.5 .. 3 m/s
    l_ka = p["trailer_wheelbase"]
    t = torch.arange(steps + 1, dtype=torch.float64)[:, None] * DT
    exact = 2 * torch.atan(math.tan(phi0 / 2) * torch.exp(-v * t / l_ka))
    pose = torch.zeros(n, 4, dtype=torch.float64)
    pose[:, :3] = torch.tensor([2.0, -1.0, 0.7], dtype=torch.float64)
    pose[:, 3] = phi0
    errors = {}
    for substeps in (10, 100, 1000):
        poses, flags = _rollout(pose, v, torch.zeros(n, dtype=torch.float64), p, steps, substeps)
        assert not flags.any()
        phi = poses[..., 3]
        assert (phi.diff(dim=0) > 0).all()  # grows every step: open-loop unstable
        errors[substeps] = (phi - exact).abs().amax(0)
        # the rear axle moves straight back, exactly v t along its (unchanged) heading
        torch.testing.assert_close(poses[..., 0], 2.0 + v * t * math.cos(0.7))
        torch.testing.assert_close(poses[..., 1], -1.0 + v * t * math.sin(0.7))
        assert ((poses[..., 2] - 0.7).abs() < 1e-14).all()  # up to the angle wrap's rounding
    assert (exact[-1] > 1.5 * phi0).all()  # a real growth, not a rounding effect
    assert (errors[1000] < 1e-4).all(), errors[1000]
    for coarse, fine in ((10, 100), (100, 1000)):
        ratio = errors[coarse] / errors[fine]
        assert ((ratio > 8) & (ratio < 12)).all(), (coarse, ratio)  # first order


def test_small_articulation_grows_in_reverse_and_shrinks_forward():
    n, steps = 16, 40
    p = _params(n, seed=3)
    pose = torch.zeros(n, 4, dtype=torch.float64)
    pose[:, 3] = 0.05
    zero = torch.zeros(n, dtype=torch.float64)
    back, _ = _rollout(pose, -p["max_reverse_speed"], zero, p, steps)
    ahead, _ = _rollout(pose, 0.5 * p["max_speed"], zero, p, steps)
    assert (back[-1, :, 3] > 0.05 * 1.3).all() and (back[..., 3].diff(dim=0) > 0).all()
    assert (ahead[-1, :, 3] < 0.05 / 1.3).all() and (ahead[..., 3].diff(dim=0) < 0).all()
    # exact factors: tan(phi / 2) scales by exp(-v t / L_ka) (0.05 rad: tan(x/2) ~ x / 2)
    t = steps * DT
    grow = torch.exp(p["max_reverse_speed"] * t / p["trailer_wheelbase"])
    exact = 2 * torch.atan(math.tan(0.025) * grow)
    torch.testing.assert_close(back[-1, :, 3], exact, rtol=0.02, atol=0.0)


# ---------------------------------------------------------------------- constant steering
@pytest.mark.parametrize("delta", [0.35, -0.2])
def test_constant_steering_in_reverse_runs_the_circle_backwards(delta):
    n, steps, substeps = 8, 40, 200
    p = _params(n, seed=5, max_articulation=3.0)
    v = -p["max_reverse_speed"]
    l_t = p["wheelbase"]
    x0, y0, th0 = 1.0, 2.0, -0.4
    pose = torch.tensor([[x0, y0, th0, 0.0]], dtype=torch.float64).repeat(n, 1)
    steer = torch.full((n,), delta, dtype=torch.float64)
    poses, _ = _rollout(pose, v, steer, p, steps, substeps)
    t = steps * DT
    r = l_t / math.tan(delta)  # signed radius: centre to the left for delta > 0
    th = th0 + v * math.tan(delta) / l_t * t
    x = x0 + r * (torch.sin(th) - math.sin(th0))
    y = y0 - r * (torch.cos(th) - math.cos(th0))
    end = poses[-1]
    torch.testing.assert_close(_wrap(end[:, 2] - th), torch.zeros(n, dtype=torch.float64))
    # Euler chord error per sub-step <= |v| h * |w| h / 2 -> total <= |v w| h t / 2
    h = DT / substeps
    bound = 0.5 * (v * math.tan(delta) / l_t).abs() * v.abs() * h * t
    err = torch.hypot(end[:, 0] - x, end[:, 1] - y)
    assert (err <= bound + 1e-12).all(), (err, bound)
    # on the circle centre (x0 - r sin th0, y0 + r cos th0), at distance |r|, every step
    cx, cy = x0 - r * math.sin(th0), y0 + r * math.cos(th0)
    radius = torch.hypot(poses[..., 0] - cx, poses[..., 1] - cy)
    assert ((radius - r.abs()).abs() < 0.01).all()
    # backwards: the rear axle moves against its heading
    step = poses[1:, :, :2] - poses[:-1, :, :2]
    along = step[..., 0] * torch.cos(poses[:-1, :, 2]) + step[..., 1] * torch.sin(poses[:-1, :, 2])
    assert (along < 0).all()
    # and the heading turns the other way than driving forward with the same wheel angle
    assert ((th - th0) * delta < 0).all()


# -------------------------------------------------------------------- fine RK4 reference
# the same independent RK4 oracle as the forward tests (controls held over each step)
_rk4 = _rk4_reference


def test_random_reversing_trucks_match_a_fine_rk4_reference():
    n, steps = 24, 50  # 5 s of reversing with varying speed and steering
    p = _params(n, seed=11, max_articulation=3.0)
    rng = np.random.default_rng(11)
    t = np.arange(steps)[:, None] * DT
    phase = rng.uniform(0, 2 * np.pi, n)
    vr = p["max_reverse_speed"].numpy()
    speed = -vr * (0.6 + 0.4 * np.sin(2 * np.pi * 0.1 * t + phase))  # v < 0 throughout
    steer = 0.25 * p["max_steer"].numpy() * np.sin(2 * np.pi * rng.uniform(0.1, 0.3, n) * t + phase)
    ref = _rk4(p, speed, steer, 100)
    assert np.abs(_rk4(p, speed, steer, 50) - ref).max() < 1e-9  # the reference has converged
    assert np.abs(ref[..., 3]).max() < 1.2  # no clamp, no wrap
    assert np.abs(ref[..., 3]).max() > 0.1  # but the trailer did swing
    errs = {}
    for substeps in (5, 50, 500):
        pose = torch.zeros(n, 4, dtype=torch.float64)
        poses, flags = _rollout(
            pose, torch.from_numpy(speed), torch.from_numpy(steer), p, steps, substeps
        )
        assert not flags.any()
        d = poses.numpy() - ref
        errs[substeps] = (
            np.hypot(d[..., 0], d[..., 1]).max(0),
            np.abs(_wrap(d[..., 3])).max(0),
        )
    for i in (0, 1):  # position and articulation: first order in dt / substeps
        for coarse, fine in ((5, 50), (50, 500)):
            ratio = errs[coarse][i] / errs[fine][i]
            assert ((ratio > 8) & (ratio < 12)).all(), (i, coarse, ratio)
    pos, phi = errs[500]
    assert pos.max() < 2e-3 and phi.max() < 2e-4, (pos.max(), phi.max())


def test_trailer_axle_moves_along_the_trailer_heading_in_reverse():
    # no-slip: the trailer axle's velocity has no component across the trailer; the axle is
    # computed here from the pose by hand (kingpin a behind the rear axle, axle L_ka behind it)
    n, steps, substeps = 16, 30, 400
    p = _params(n, seed=7, max_articulation=3.0)
    pose = torch.zeros(n, 4, dtype=torch.float64)
    pose[:, 3] = torch.linspace(-0.4, 0.4, n, dtype=torch.float64)
    steer = torch.linspace(-0.3, 0.3, n, dtype=torch.float64)
    poses, _ = _rollout(pose, -p["max_reverse_speed"], steer, p, steps, substeps)
    x, y, th, ph = poses.unbind(-1)
    a, l_ka = p["kingpin_offset"], p["trailer_wheelbase"]
    psi = th + ph
    ax = x - a * torch.cos(th) - l_ka * torch.cos(psi)
    ay = y - a * torch.sin(th) - l_ka * torch.sin(psi)
    dx, dy = ax.diff(dim=0), ay.diff(dim=0)
    mid = psi[:-1] + 0.5 * _wrap(psi[1:] - psi[:-1])
    across = -dx * torch.sin(mid) + dy * torch.cos(mid)
    along = dx * torch.cos(mid) + dy * torch.sin(mid)
    assert (along < 0).all()  # the trailer axle leads, backwards
    # relative to the rear axle's travel |v| dt (a phi_dot without its kingpin term would leave
    # about |k a| ~ 1e-2 of it across)
    ratio = across.abs() / (p["max_reverse_speed"] * DT)
    assert (ratio < 1e-3).all(), ratio.max()


# ------------------------------------------------------------------------------ jack-knife
def test_reversing_with_steady_steering_jackknifes_within_a_bound():
    # with k = tan(delta) / L_t > 0 and phi in [0, phi_max]:
    # phi_dot = |v| (k (1 + a / L_ka cos phi) + sin(phi) / L_ka) >= |v| k (1 - |a| / L_ka) > 0,
    # so phi reaches the stop before T = phi_max / (|v| k (1 - |a| / L_ka))
    n = 32
    p = _params(n, seed=9)
    v = -p["max_reverse_speed"]
    steer = 0.5 * p["max_steer"]
    k = torch.tan(steer) / p["wheelbase"]
    rate = v.abs() * k * (1 - p["kingpin_offset"].abs() / p["trailer_wheelbase"])
    bound = p["max_articulation"] / rate  # [s]
    steps = int(math.ceil(float(bound.max()) / DT)) + 1
    pose = torch.zeros(n, 4, dtype=torch.float64)
    pose[:, 2] = 1.0
    first_jack = torch.full((n,), -1)
    clamped_any = torch.zeros(n, dtype=torch.bool)
    for i in range(steps):
        assert not jackknifed(pose, p).any() or i > 0
        pose, clamped = kinematics_step(pose, v, steer, p, DT, substeps=10)
        clamped_any |= clamped
        jack = jackknifed(pose, p)
        first_jack = torch.where((first_jack < 0) & jack, torch.tensor(i + 1), first_jack)
    assert (first_jack > 0).all(), "every truck must jack-knife"
    assert (first_jack * DT <= bound + DT).all(), (first_jack * DT, bound)
    assert clamped_any.all()  # and the articulation reached its stop
    assert torch.allclose(pose[:, 3], p["max_articulation"])  # phi > 0 for delta > 0 in reverse
    # the same steering forward settles (no jack-knife) for the same number of steps
    fwd = torch.zeros(n, 4, dtype=torch.float64)
    for _ in range(steps):
        fwd, _ = kinematics_step(fwd, 0.5 * p["max_speed"], steer, p, DT, substeps=10)
        assert not jackknifed(fwd, p).any()
    assert (fwd[:, 3] < 0).all()  # forward, the trailer trails on the other side


# ---------------------------------------------------------------------------- signed control
LON_PAIRS = list(itertools.product(LONGITUDINAL_MODES, LATERAL_MODES[:1]))


def _control_params(n, seed):
    return _params(n, seed=seed)


def _run(ctrl, actions, params):
    state = ctrl.zero_state(actions.shape[1], dtype=torch.float64)
    out = []
    for a in actions:
        state = ctrl.step(a, state, params)
        out.append(state)
    return {k: torch.stack([s[k] for s in out]) for k in CONTROL_KEYS}


@pytest.mark.parametrize("longitudinal", LONGITUDINAL_MODES)
def test_reverse_control_reaches_and_respects_per_truck_speed_bounds(longitudinal):
    n, dt = 32, DT
    p = _control_params(n, seed=LONGITUDINAL_MODES.index(longitudinal))
    ctrl = Control({"longitudinal": longitudinal, "lateral": "rate"}, dt, reverse=True)
    torch.testing.assert_close(ctrl.speed_floor(p), -p["max_reverse_speed"])
    # random actions: always within [-max_reverse_speed, max_speed]
    g = torch.Generator().manual_seed(7)
    actions = (torch.rand(300, n, 2, generator=g, dtype=torch.float64) * 2 - 1) * 1.5
    s = _run(ctrl, actions, p)
    assert (s["speed"] >= -p["max_reverse_speed"] - 1e-12).all()
    assert (s["speed"] <= p["max_speed"] + 1e-12).all()
    assert (s["speed"] < -0.2).any()  # random driving does reverse
    # full "back" command: reaches the reverse limit exactly and stays there
    back = _run(ctrl, torch.full((120, n, 2), -1.0, dtype=torch.float64), p)["speed"]
    torch.testing.assert_close(back[-20:], (-p["max_reverse_speed"]).expand(20, n))
    assert (back >= -p["max_reverse_speed"] - 1e-12).all()
    # full "forward": reaches max_speed, never above
    ahead = _run(ctrl, torch.full((150, n, 2), 1.0, dtype=torch.float64), p)["speed"]
    torch.testing.assert_close(ahead[-20:], p["max_speed"].expand(20, n))
    assert (ahead <= p["max_speed"] + 1e-12).all()


def test_reverse_speed_mode_map_is_affine_onto_the_signed_range():
    # speed mode: u in [-1, 1] -> [-max_reverse_speed, max_speed] affinely (u = 0 is the middle
    # of that range, not standstill; standstill is u0 = (vr - vmax) / (vr + vmax))
    p = _control_params(8, seed=4)
    vr, vmax = p["max_reverse_speed"], p["max_speed"]
    ctrl = Control({"longitudinal": "speed", "lateral": "angle"}, DT, reverse=True)
    for u in (-1.0, -0.5, 0.0, 0.7, 1.0):
        a = torch.tensor([[u, 0.0]], dtype=torch.float64).expand(8, 2)
        v = ctrl.step(a, ctrl.zero_state(8, dtype=torch.float64), p)["speed"]
        torch.testing.assert_close(v, -vr + 0.5 * (u + 1) * (vmax + vr))
    u0 = ((vr - vmax) / (vr + vmax))[:, None]
    v = ctrl.step(torch.cat((u0, 0 * u0), 1), ctrl.zero_state(8, dtype=torch.float64), p)["speed"]
    assert v.abs().max() < 1e-12


def test_reverse_with_nonzero_min_speed_is_rejected():
    with pytest.raises(ConfigError, match="min_speed"):
        Control({"longitudinal": "accel", "lateral": "rate"}, DT, min_speed=0.5, reverse=True)
    with pytest.raises(ConfigError, match="min_speed"):
        Control({"longitudinal": "speed", "lateral": "rate"}, DT, min_speed=-1.0, reverse=True)


@pytest.mark.parametrize("longitudinal", LONGITUDINAL_MODES)
def test_forward_control_never_goes_below_zero(longitudinal):
    n = 32
    p = _control_params(n, seed=20)
    ctrl = Control({"longitudinal": longitudinal, "lateral": "rate"}, DT)  # reverse=False
    torch.testing.assert_close(ctrl.speed_floor(p), torch.zeros(n, dtype=torch.float64))
    g = torch.Generator().manual_seed(3)
    actions = torch.rand(300, n, 2, generator=g, dtype=torch.float64) * 2 - 1
    actions = torch.cat((actions, torch.full((60, n, 2), -1.0, dtype=torch.float64)))
    s = _run(ctrl, actions, p)["speed"]
    assert (s >= 0).all() and (s[-10:] == 0).all()
