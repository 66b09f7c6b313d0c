"""Held-out evaluation during training: its schedule, seed and TensorBoard scalars."""

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

from truckrl.evaluation.heldout import HELDOUT_SEED, heldout_due, heldout_scalars, tag
from truckrl.evaluation.rollout import evaluate_policy
from truckrl.rl.collection import env_seed
from truckrl.tasks import EnvConfig
from truckrl.tasks.intersection.scene import ROUTE_NAMES


def test_due_once_per_interval_from_the_session_start():
    # 1-minute interval, 25-s iterations: due at the first iteration ending after 60, 120, ... s
    ends = [25.0 * i for i in range(1, 11)]
    due = [heldout_due(1.0, t, 25.0) for t in ends]
    assert [t for t, d in zip(ends, due, strict=True) if d] == [75.0, 125.0, 200.0, 250.0]
    assert heldout_due(1.0, 60.0, 1.0) and not heldout_due(1.0, 59.9, 1.0)
    assert not heldout_due(1.0, 30.0, 100.0)  # a window before the session start counts from 0
    assert not heldout_due(0.0, 1e6, 1e6)  # 0: never


def test_heldout_seed_is_never_a_training_seed():
    assert HELDOUT_SEED >= 2**32  # env_seed returns a uint32
    seeds = [env_seed(s, it, w) for s in (0, 1, 2**40) for it in (0, 7) for w in range(3)]
    assert all(0 <= s < 2**32 for s in seeds)
    assert np.random.SeedSequence([0, 0, 0]).generate_state(1).dtype == np.uint32


def test_tags():
    assert tag("turn [deg]") == "turn_deg" and tag("left 20-70") == "left_20-70"
    assert tag("straight road") == "straight_road" and tag("7.9-11.2") == "7.9-11.2"
    assert tag("< 25") == "lt_25" and tag("> 70") == "gt_70"


def test_scalars_are_the_outcome_and_route_rates_of_the_heldout_scenes():
    # a scripted closed-loop driver (half throttle, steering against the lateral goal offset):
    # at difficulty 0 (30 m) it reaches some goals, hits some curbs and runs out of time on others
    actor = TensorDictModule(
        lambda obs: torch.stack(
            [torch.full_like(obs[:, 0], 0.6), (-0.3 * obs[:, 1]).clamp(-1, 1)], -1
        ),
        in_keys=["observation"],
        out_keys=["action"],
    )
    cfg = EnvConfig(max_steps=40)
    rng = torch.get_rng_state()
    out = heldout_scalars(actor, cfg, 0.0, 16, "cpu")
    assert torch.equal(rng, torch.get_rng_state())  # training stays reproducible
    assert out["eval/difficulty"] == 0.0
    # the same episodes run here on the held-out seed, rates counted by hand
    res, _, _ = evaluate_policy(actor, cfg, 0.0, episodes=16, seed=HELDOUT_SEED)
    flags = {"success": "success", "collision": "collision", "jackknife": "jackknife"}
    flags["timeout"] = "truncated"
    for name, key in flags.items():
        assert out[f"eval/{name}_rate"] == pytest.approx(res[key].float().mean().item()), name
    assert 0 < res["success"].sum() < 16 and res["collision"].any()  # the outcomes are mixed
    route = res["route"].long()
    for code, name in enumerate(ROUTE_NAMES):
        rate = res["success"][route == code].float().mean().item()
        assert out[f"eval/route/{name.replace(' ', '_')}/success"] == pytest.approx(rate), name
    assert out == heldout_scalars(actor, cfg, 0.0, 16, "cpu")  # same scenes every time
