"""Control abstractions: bounds, hand-computed integration, self-consistency, config errors."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.sim.control import (
    CONTROL_KEYS,
    LATERAL_MODES,
    LONGITUDINAL_MODES,
    MODE_TABLE,
    Control,
    ControlConfig,
    commanded,
)
from truckrl.sim.vehicle import PARAM_KEYS, VehicleConfig, sample_vehicle_params

ROOT = Path(__file__).resolve().parents[2]
DT = 0.1  # paper: dt = 0.1 s
PAIRS = list(itertools.product(LONGITUDINAL_MODES, LATERAL_MODES))

LIMITS = {  # one hand-picked truck's limits
    "max_speed": 6.0,
    "max_accel": 2.0,
    "max_jerk": 4.0,
    "max_steer": 0.6,
    "max_steer_rate": 0.5,
    "max_steer_accel": 2.0,
}


def _limits(n=1, **overrides):
    lim = {**LIMITS, **overrides}
    return {k: torch.full((n,), v, dtype=torch.float64) for k, v in lim.items()}


def _run(ctrl, actions, params, state=None):
    """States after each action: ``{key: [T, N]}``."""
    n = actions.shape[1]
    state = state or ctrl.zero_state(n, dtype=torch.float64)
    out = []
    for a in actions:
        state = ctrl.step(a, state, params)
        out.append(state)
    return {k: torch.stack([s[k] for s in out]) for k in CONTROL_KEYS}


def _const(action, steps):
    return torch.tensor(action, dtype=torch.float64).expand(steps, 1, 2)


@pytest.mark.parametrize(("longitudinal", "lateral"), PAIRS)
def test_random_actions_stay_within_bounds(longitudinal, lateral):
    n, steps, min_speed = 64, 200, -1.5
    g = torch.Generator().manual_seed(PAIRS.index((longitudinal, lateral)))
    params = sample_vehicle_params(VehicleConfig(min_speed=min_speed), n, g)
    ctrl = Control(ControlConfig(longitudinal, lateral), DT, min_speed=min_speed)
    # persistent random walks push the chains into saturation; 3x scale exercises the action clamp
    actions = (
        torch.randn(steps, n, 2, generator=g) + 2.0 * torch.randn(1, n, 2, generator=g)
    ) * 1.5
    states = _run(ctrl, actions, params)
    tol = 1e-5
    bounds = {
        "speed": (torch.full((n,), min_speed), params["max_speed"]),
        "accel": (-params["max_accel"], params["max_accel"]),
        "jerk": (-params["max_jerk"], params["max_jerk"]),
        "steer": (-params["max_steer"], params["max_steer"]),
        "steer_rate": (-params["max_steer_rate"], params["max_steer_rate"]),
        "steer_accel": (-params["max_steer_accel"], params["max_steer_accel"]),
    }
    for key, (lo, hi) in bounds.items():
        q = states[key]
        assert q.isfinite().all()
        assert (q >= lo - tol).all() and (q <= hi + tol).all(), key
        assert ((q - lo).abs() < tol).any() or ((q - hi).abs() < tol).any(), (
            f"{key} never saturated"
        )
    # integrated levels obey q' = q + rate' dt (commanded level and below)
    prev = ctrl.zero_state(n)
    for chain, order in (
        (("speed", "accel", "jerk"), LONGITUDINAL_MODES.index(longitudinal)),
        (("steer", "steer_rate", "steer_accel"), LATERAL_MODES.index(lateral)),
    ):
        for i in range(order):
            change = torch.cat((prev[chain[i]][None], states[chain[i]])).diff(dim=0)
            rate = states[chain[i + 1]]
            limit = params[f"max_{chain[i + 1]}"]
            inside = rate.abs() < limit - tol
            # exact where the rate is inside its bounds; where it is clipped, the level below
            # changed at least as fast as the bound allows (a hard stop at a limit)
            assert ((change - rate * DT).abs() < tol)[inside].all(), chain[i]
            assert (change.abs() >= rate.abs() * DT - tol)[~inside].all(), chain[i]


def test_accel_mode_integrates_and_clamps_at_max_speed():
    ctrl = Control(ControlConfig("accel", "rate"), DT)
    s = _run(ctrl, _const([0.5, 0.0], 70), _limits())  # a = 0.5 * 2 = 1 m/s^2
    v, accel, jerk = (s[k][:, 0] for k in ("speed", "accel", "jerk"))
    torch.testing.assert_close(v[:60], torch.arange(1, 61, dtype=torch.float64) * 0.1)
    assert (v[60:] == 6.0).all()  # held at max_speed
    assert (accel[:59] == 1.0).all()
    torch.testing.assert_close(accel[59:], torch.tensor([1.0] + [0.0] * 10, dtype=torch.float64))
    assert (accel[61:] == 0.0).all()  # at max speed the realised accel is 0, not the command
    # jerk: finite difference of accel, clipped to max_jerk = 4 (raw +10 at the start, -10 at
    # the speed limit)
    torch.testing.assert_close(
        jerk, torch.tensor([4.0] + [0.0] * 59 + [-4.0] + [0.0] * 9, dtype=torch.float64)
    )
    # braking from 6 m/s at full decel 2 m/s^2 reaches the speed floor 0 after 3 s
    s2 = _run(ctrl, _const([-1.0, 0.0], 35), _limits(), state={k: s[k][-1] for k in CONTROL_KEYS})
    torch.testing.assert_close(s2["speed"][29, 0], torch.tensor(0.0, dtype=torch.float64))
    assert (s2["speed"][30:, 0] == 0.0).all() and (s2["accel"][30:, 0] == 0.0).all()


def test_accel_mode_partial_saturation_realises_rate():
    # v = 5.95, a command of 2 would reach 6.15; clipped to 6, so the realised accel is 0.5
    ctrl = Control(ControlConfig("accel", "rate"), DT)
    state = ctrl.zero_state(1, dtype=torch.float64)
    state["speed"] = torch.tensor([5.95], dtype=torch.float64)
    new = ctrl.step(torch.tensor([[1.0, 0.0]], dtype=torch.float64), state, _limits())
    assert new["speed"].item() == 6.0
    torch.testing.assert_close(new["accel"], torch.tensor([0.5], dtype=torch.float64))
    torch.testing.assert_close(new["jerk"], torch.tensor([4.0], dtype=torch.float64))  # 5 -> 4


def test_rate_mode_integrates_steer_and_clamps():
    ctrl = Control(ControlConfig("accel", "rate"), DT)
    s = _run(ctrl, _const([0.0, 1.0], 15), _limits())  # rate 0.5 rad/s, 0.05 rad per step
    steer = s["steer"][:, 0]
    torch.testing.assert_close(steer[:12], torch.arange(1, 13, dtype=torch.float64) * 0.05)
    assert (steer[12:] == 0.6).all()
    assert (s["steer_rate"][:11, 0] == 0.5).all() and (s["steer_rate"][12:, 0] == 0.0).all()
    # steer accel: 5 then -5 rad/s^2 raw, clipped to max_steer_accel = 2
    assert s["steer_accel"][0, 0] == 2.0 and s["steer_accel"][12, 0] == -2.0
    assert (s["steer_accel"][1:11, 0] == 0.0).all()
    assert (s["speed"] == 0).all() and (s["accel"] == 0).all()


def test_jerk_mode_integrates_twice():
    ctrl = Control(ControlConfig("jerk", "rate"), DT)
    s = _run(ctrl, _const([0.5, 0.0], 10), _limits())  # j = 0.5 * 4 = 2 m/s^3
    n = torch.arange(1, 11, dtype=torch.float64)
    accel = 2.0 * n * DT
    speed = 2.0 * DT**2 * n * (n + 1) / 2  # semi-implicit: v_n = sum_k a_k dt
    torch.testing.assert_close(s["jerk"][:7, 0], torch.full((7,), 2.0, dtype=torch.float64))
    torch.testing.assert_close(s["accel"][:7, 0], accel[:7])
    torch.testing.assert_close(s["speed"][:7, 0], speed[:7])
    torch.testing.assert_close(s["accel"][:, 0], accel.clamp(max=2.0))
    # max_accel 2 reached at step 10 exactly; a tighter limit cuts in earlier:
    t = _run(ctrl, _const([0.5, 0.0], 10), _limits(max_accel=1.5))
    torch.testing.assert_close(t["accel"][7:, 0], torch.full((3,), 1.5, dtype=torch.float64))
    # step 8 (index 7): accel 1.4 -> 1.5 realised, so jerk = 1.0; afterwards 0
    torch.testing.assert_close(t["jerk"][7:, 0], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(
        t["speed"][7, 0], torch.tensor(speed[6].item() + 0.15, dtype=torch.float64)
    )


def test_jerk_mode_speed_limit_rewrites_accel_and_jerk():
    # v = 5.98, a = 1.0, j command 4: a' = 1.4, v' would be 6.12 -> 6.0; realised a' = 0.2,
    # realised jerk (0.2 - 1.0) / 0.1 = -8, clipped to -4
    ctrl = Control(ControlConfig("jerk", "angle"), DT)
    state = ctrl.zero_state(1, dtype=torch.float64)
    state["speed"] = torch.tensor([5.98], dtype=torch.float64)
    state["accel"] = torch.tensor([1.0], dtype=torch.float64)
    new = ctrl.step(torch.tensor([[1.0, 0.0]], dtype=torch.float64), state, _limits())
    assert new["speed"].item() == 6.0
    torch.testing.assert_close(new["accel"], torch.tensor([0.2], dtype=torch.float64))
    torch.testing.assert_close(new["jerk"], torch.tensor([-4.0], dtype=torch.float64))


def test_speed_mode_sets_speed_and_differentiates():
    ctrl = Control(ControlConfig("speed", "angle"), DT)
    # u = -0.9 maps onto [0, 6] at 0.05 * 6 = 0.3 m/s
    s = _run(ctrl, _const([-0.9, 0.5], 3), _limits(max_accel=5.0))
    torch.testing.assert_close(s["speed"][:, 0], torch.full((3,), 0.3, dtype=torch.float64))
    torch.testing.assert_close(s["accel"][:, 0], torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(s["jerk"][:, 0], torch.tensor([4.0, -4.0, 0.0], dtype=torch.float64))
    # angle mode: u * max_steer, rate = d steer / dt = 3 rad/s clipped to 0.5
    torch.testing.assert_close(s["steer"][:, 0], torch.full((3,), 0.3, dtype=torch.float64))
    assert s["steer_rate"][0, 0] == 0.5 and s["steer_rate"][1, 0] == 0.0
    # a big jump: the realised accel is reported clipped to max_accel
    big = _run(ctrl, _const([1.0, -1.0], 1), _limits())
    assert big["speed"].item() == 6.0 and big["accel"].item() == 2.0
    assert big["steer"].item() == -0.6 and big["steer_rate"].item() == -0.5


def test_speed_mode_maps_onto_min_max_speed():
    ctrl = Control(ControlConfig("speed", "angle"), DT, min_speed=-2.0)
    lim = _limits()
    for u, v in ((-1.0, -2.0), (0.0, 2.0), (1.0, 6.0), (5.0, 6.0), (-7.0, -2.0)):
        new = ctrl.step(
            torch.tensor([[u, 0.0]], dtype=torch.float64),
            ctrl.zero_state(1, dtype=torch.float64),
            lim,
        )
        torch.testing.assert_close(new["speed"], torch.tensor([v], dtype=torch.float64))


def test_lateral_accel_mode_integrates_twice():
    ctrl = Control(ControlConfig("accel", "accel"), DT)
    s = _run(ctrl, _const([0.0, -0.5], 4), _limits())  # steer accel -1 rad/s^2
    n = torch.arange(1, 5, dtype=torch.float64)
    torch.testing.assert_close(s["steer_rate"][:, 0], -1.0 * n * DT)
    torch.testing.assert_close(s["steer"][:, 0], -1.0 * DT**2 * n * (n + 1) / 2)
    torch.testing.assert_close(s["steer_accel"][:, 0], torch.full((4,), -1.0, dtype=torch.float64))


def test_per_env_limits_and_no_cross_talk():
    ctrl = Control(ControlConfig("accel", "rate"), DT)
    lim = _limits(2)
    lim["max_accel"] = torch.tensor([1.0, 3.0], dtype=torch.float64)
    lim["max_steer_rate"] = torch.tensor([0.2, 0.4], dtype=torch.float64)
    actions = torch.tensor([[1.0, -1.0], [0.5, 0.25]], dtype=torch.float64)
    new = ctrl.step(actions, ctrl.zero_state(2, dtype=torch.float64), lim)
    torch.testing.assert_close(new["accel"], torch.tensor([1.0, 1.5], dtype=torch.float64))
    torch.testing.assert_close(new["speed"], torch.tensor([0.1, 0.15], dtype=torch.float64))
    torch.testing.assert_close(new["steer_rate"], torch.tensor([-0.2, 0.1], dtype=torch.float64))
    torch.testing.assert_close(new["steer"], torch.tensor([-0.02, 0.01], dtype=torch.float64))


def test_zero_state():
    state = Control(ControlConfig(), DT).zero_state(3)
    assert set(state) == set(CONTROL_KEYS)
    assert all(v.shape == (3,) and (v == 0).all() for v in state.values())
    assert (Control(ControlConfig(), DT, min_speed=1.0).zero_state(2)["speed"] == 1.0).all()


def test_mode_table_is_the_mode_vocabulary():
    assert LONGITUDINAL_MODES == ("speed", "accel", "jerk")
    assert LATERAL_MODES == ("angle", "rate", "accel")
    assert CONTROL_KEYS == ("speed", "accel", "jerk", "steer", "steer_rate", "steer_accel")
    assert tuple(MODE_TABLE) == ("longitudinal", "lateral")
    for modes in MODE_TABLE.values():
        assert all(limit in PARAM_KEYS for _, limit in modes.values())
    with pytest.raises(TypeError):
        MODE_TABLE["lateral"]["wheel"] = ("steer", "max_steer")  # read-only


@pytest.mark.parametrize(("lon", "lat"), PAIRS)
def test_commanded_keys_and_limits(lon, lat):
    (lon_key, lon_limit), (lat_key, lat_limit) = commanded(lon, lat)
    assert lon_key == CONTROL_KEYS[LONGITUDINAL_MODES.index(lon)]
    assert lat_key == CONTROL_KEYS[3 + LATERAL_MODES.index(lat)]
    assert lon_limit == {"speed": "max_speed", "accel": "max_accel", "jerk": "max_jerk"}[lon]
    assert lat_limit == {"angle": "max_steer", "rate": "max_steer_rate"}.get(lat, "max_steer_accel")


def test_commanded_rejects_unknown_modes():
    assert commanded("accel", "rate") == (("accel", "max_accel"), ("steer_rate", "max_steer_rate"))
    with pytest.raises(ConfigError, match="control.longitudinal"):
        commanded("brake", "rate")
    with pytest.raises(ConfigError, match="control.lateral"):
        commanded("accel", "jerk")


def test_paper_default_is_accel_rate():
    cfg = ControlConfig()
    assert (cfg.longitudinal, cfg.lateral) == ("accel", "rate")


@pytest.mark.parametrize(
    ("kwargs", "field", "allowed"),
    [
        ({"longitudinal": "brake"}, "control.longitudinal", "jerk"),
        ({"lateral": "torque"}, "control.lateral", "rate"),
        ({"lateral": "jerk"}, "control.lateral", "angle"),
    ],
)
def test_bad_control_config_names_field(kwargs, field, allowed):
    with pytest.raises(ConfigError, match=field) as info:
        ControlConfig(**kwargs)
    assert allowed in str(info.value)


def test_bad_control_arguments():
    with pytest.raises(ConfigError, match="dt"):
        Control(ControlConfig(), 0.0)
    with pytest.raises(ConfigError, match="dt"):
        Control(ControlConfig(), -0.1)
    with pytest.raises(ConfigError, match="unknown"):
        Control({"longitudinal": "accel", "steering": "rate"}, DT)
    with pytest.raises(ConfigError, match="control.lateral"):
        Control({"lateral": "wheel"}, DT)
