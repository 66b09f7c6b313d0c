"""Curriculum: EMA promotion rule on scripted success streams."""

import math

import pytest
import torch

from truckrl.config.fields import ConfigError
from truckrl.rl.curriculum import Curriculum, CurriculumConfig, ema_trajectory


def ema_loop(y, a, xs):
    out = []
    for x in xs:
        y = a * y + (1 - a) * x
        out.append(y)
    return out


def test_ema_trajectory_matches_a_python_loop():
    g = torch.Generator().manual_seed(0)
    x = (torch.rand(10_000, generator=g) < 0.6).float()
    for a in (0.995, 0.9, 0.3):
        got = ema_trajectory(0.25, a, x)
        torch.testing.assert_close(
            got, torch.tensor(ema_loop(0.25, a, x.tolist()), dtype=torch.float64)
        )


def first_crossing(a=0.995, thr=0.70):
    # all-success stream from 0: 1 - a**n > thr  <=>  n > log(1 - thr) / log(a)
    return math.floor(math.log(1 - thr) / math.log(a)) + 1


def test_promotion_exactly_when_ema_exceeds_threshold():
    n = first_crossing()
    assert n == 241
    cur = Curriculum(CurriculumConfig())
    assert not cur.update(torch.ones(n - 1, dtype=torch.bool))
    assert cur.difficulty == 0.0
    assert cur.ema == pytest.approx(1 - 0.995 ** (n - 1)) and cur.ema <= 0.70
    assert cur.update(torch.ones(1, dtype=torch.bool))
    assert cur.difficulty == 0.5 and cur.promotions == 1
    assert cur.ema == 0.0  # restarts after a promotion


def test_failures_hold_back_and_rest_of_batch_is_dropped_after_promotion():
    cur = Curriculum(CurriculumConfig())
    stream = torch.tensor([1, 0] * 100 + [1] * 400, dtype=torch.bool)
    ref = ema_loop(0.0, 0.995, stream.float().tolist())
    k = next(i for i, y in enumerate(ref) if y > 0.70)
    assert cur.update(stream)
    assert cur.difficulty == 0.5
    assert cur.episodes == k + 1  # the outcomes after the crossing were judged at the old level
    assert cur.ema == 0.0
    # one more all-success batch of the same length cannot promote again before 241 successes
    assert not cur.update(torch.ones(240, dtype=torch.bool))
    assert cur.update(torch.ones(1, dtype=torch.bool))
    assert cur.difficulty == 1.0


def test_episodes_judged_at_another_difficulty_are_ignored():
    cur = Curriculum(CurriculumConfig(start_difficulty=1.0))
    success = torch.ones(1000, dtype=torch.bool)
    assert not cur.update(success, difficulty=torch.full((1000,), 0.5))
    assert cur.ema == 0.0 and cur.episodes == 0
    assert cur.update(success, difficulty=torch.full((1000,), 1.0))
    assert cur.difficulty == 1.5


def test_fixed_mode_and_cap_never_promote():
    fixed = Curriculum(CurriculumConfig(mode="fixed", start_difficulty=3.0))
    assert not fixed.update(torch.ones(5000, dtype=torch.bool))
    assert fixed.difficulty == 3.0
    capped = Curriculum(CurriculumConfig(max_difficulty=0.4))
    assert not capped.update(torch.ones(5000, dtype=torch.bool))
    assert capped.difficulty == 0.0


def test_state_dict_round_trip():
    a = Curriculum(CurriculumConfig())
    a.update(torch.ones(300, dtype=torch.bool))
    a.update(torch.tensor([1, 0, 1], dtype=torch.bool))
    b = Curriculum(CurriculumConfig())
    b.load_state_dict(a.state_dict())
    assert b.state_dict() == a.state_dict()


def test_bad_curriculum_config_names_field():
    with pytest.raises(ConfigError, match="curriculum.threshold"):
        CurriculumConfig(threshold=1.5)
    with pytest.raises(ConfigError, match="curriculum.mode"):
        CurriculumConfig(mode="sometimes")


def test_promotions_halve_env_tolerances_every_difficulty_level():
    from truckrl.env import TruckEnv

    env = TruckEnv(num_envs=2, seed=0)
    cur = Curriculum(CurriculumConfig())
    streak = torch.ones(first_crossing(), dtype=torch.bool)
    for promotions in range(1, 13):
        assert cur.update(streak)
        env.set_difficulty(cur.difficulty)
        pos, ang = env.tolerances()
        d = 0.5 * promotions  # paper: +0.5 per promotion
        assert cur.difficulty == d
        torch.testing.assert_close(pos, torch.full((2,), 30.0 * 2**-d))  # paper: 30 m x 2^-d
        torch.testing.assert_close(ang, torch.full((2,), math.radians(60.0) * 2**-d))
    # paper: difficulty 6 -> 0.47 m and 0.94 deg
    assert float(pos[0]) == pytest.approx(0.47, abs=0.005)
    assert math.degrees(float(ang[0])) == pytest.approx(0.94, abs=0.005)
