"""Held-out evaluation during training: its schedule, seed and TensorBoard scalars."""

import numpy as np
import pytest
import torch

from truckrl.evaluation.heldout import HELDOUT_SEED, heldout_due, heldout_scalars, tag
from truckrl.rl.collection import env_seed
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.tasks import EnvConfig


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


def test_scalars_and_no_draw_from_the_global_rng():
    cfg = EnvConfig(max_steps=5)
    ac = make_actor_critic(ModelConfig(), 26, cfg.lidar.num_beams)
    rng = torch.get_rng_state()
    out = heldout_scalars(ac.actor, cfg, 2.0, 12, "cpu")
    assert torch.equal(rng, torch.get_rng_state())  # training stays reproducible
    assert out["eval/difficulty"] == 2.0
    rates = [out[f"eval/{o}_rate"] for o in ("success", "collision", "jackknife", "timeout")]
    assert sum(rates) == pytest.approx(1.0)
    routes = [k for k in out if k.startswith("eval/route/")]
    assert routes and all(k.endswith("/success") for k in routes)
    assert all(0.0 <= v <= 1.0 for k, v in out.items() if k != "eval/difficulty")
    assert out == heldout_scalars(ac.actor, cfg, 2.0, 12, "cpu")  # same scenes every time
