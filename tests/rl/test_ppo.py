"""PPO pieces: the KL learning-rate rule, the analytic KL, config checks, one update."""

import pytest
import torch
from tensordict import TensorDict

from truckrl.config.fields import ConfigError
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.rl.ppo import _UPDATE_KEYS, PPO, AdaptiveKLSchedule, PPOConfig, gaussian_kl


def test_adaptive_kl_rule_on_scripted_kls():
    s = AdaptiveKLSchedule(1e-3, desired_kl=0.01, lr_min=1e-4, lr_max=2e-3)
    # kl > 2 * target -> / 1.5 ; kl < target / 2 -> * 1.5 ; in between -> unchanged
    script = [
        (0.03, 1e-3 / 1.5),
        (0.0201, 1e-3 / 1.5**2),
        (0.02, 1e-3 / 1.5**2),  # exactly 2 * target: unchanged
        (0.01, 1e-3 / 1.5**2),
        (0.005, 1e-3 / 1.5**2),  # exactly target / 2: unchanged
        (0.0049, 1e-3 / 1.5),
        (0.0, 1e-3),
        (0.0, 1.5e-3),
        (0.0, 2e-3),  # clamped at lr_max
        (1.0, 2e-3 / 1.5),
    ]
    for kl, lr in script:
        assert s.step(kl) == pytest.approx(lr)
    for _ in range(20):
        s.step(1.0)
    assert s.lr == pytest.approx(1e-4)  # clamped at lr_min


def test_gaussian_kl_matches_torch_distributions():
    g = torch.Generator().manual_seed(1)
    loc0, loc1 = torch.randn(5, 2, generator=g), torch.randn(5, 2, generator=g)
    s0, s1 = torch.rand(5, 2, generator=g) + 0.1, torch.rand(5, 2, generator=g) + 0.1
    ref = torch.distributions.kl_divergence(
        torch.distributions.Independent(torch.distributions.Normal(loc0, s0), 1),
        torch.distributions.Independent(torch.distributions.Normal(loc1, s1), 1),
    )
    torch.testing.assert_close(gaussian_kl(loc0, s0, loc1, s1), ref)


def test_paper_numbers_minibatch_size():
    # paper: 24 envs x 512 steps, 96 minibatches -> 128 frames per minibatch
    assert PPOConfig().check_batch(24 * 512) == 128


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"lr": 0.0}, "ppo.lr"),
        ({"lr": -1e-4}, "ppo.lr"),
        ({"gamma": 1.5}, "ppo.gamma"),
        ({"clip_epsilon": 0.0}, "ppo.clip_epsilon"),
        ({"lr_schedule": "cosine"}, "ppo.lr_schedule"),
        ({"num_epochs": 0}, "ppo.num_epochs"),
    ],
)
def test_bad_ppo_config_names_field(kwargs, field):
    with pytest.raises(ConfigError, match=field):
        PPOConfig(**kwargs)


def test_minibatches_must_divide_batch():
    with pytest.raises(ConfigError, match="ppo.num_minibatches"):
        PPOConfig(num_minibatches=7).check_batch(24 * 512)


def rollout(ac, b=4, t=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    done = torch.rand(b, t, 1, generator=g) < 0.1
    td = TensorDict(
        {
            "observation": torch.randn(b, t, 26, generator=g),
            "lidar": torch.rand(b, t, 16, generator=g),
            "next": {
                "observation": torch.randn(b, t, 26, generator=g),
                "lidar": torch.rand(b, t, 16, generator=g),
                "reward": torch.randn(b, t, 1, generator=g),
                "done": done,
                "terminated": done,
            },
        },
        [b, t],
    )
    with torch.no_grad():
        ac.actor(td)
    return td


def test_update_moves_every_parameter_and_adapts_lr():
    torch.manual_seed(0)
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    ppo = PPO(ac, PPOConfig(num_minibatches=4, num_epochs=2, lr=1e-3))
    before = {k: v.clone() for k, v in ac.model.state_dict().items()}
    metrics = ppo.update(rollout(ac))
    for k, v in ac.model.state_dict().items():
        assert not torch.equal(v, before[k]), f"{k} did not change"
    assert set(metrics) >= {"loss_objective", "loss_critic", "loss_entropy", "kl", "lr"}
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    assert metrics["lr"] != 1e-3  # 8 minibatch steps of the adaptive rule moved it


def test_compiled_minibatch_loss_equals_the_eager_one_in_one_graph():
    """ppo.compile: the loss, its logged entries, the KL and every gradient as in eager mode, the
    cloning term included, from one graph with no break (a break would silently halve the gain)."""
    torch.manual_seed(0)
    ac = make_actor_critic(ModelConfig(), 26, 16)
    eager = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1))
    compiled = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1, compile=True))
    mb = eager.compute_advantages(rollout(ac, b=8)).reshape(-1).select(*_UPDATE_KEYS)
    g = torch.Generator().manual_seed(3)
    # a policy and critic that moved since the rollout: ratios and values beyond both clips
    mb["action_log_prob"] = mb["action_log_prob"] + 0.5 * torch.randn(mb.shape, generator=g)
    mb["state_value"] = mb["state_value"] + torch.randn(mb["state_value"].shape, generator=g)
    demos = mb.select("observation", "lidar", "action")[:16]
    coeff = torch.tensor(0.5)

    explained = torch._dynamo.explain(eager._minibatch_objective)(mb, demos, coeff)
    assert explained.graph_break_count == 0, explained.break_reasons

    results = []
    for ppo in (eager, compiled):
        ac.model.zero_grad(set_to_none=True)
        total, stats, kl, bc = ppo._objective(mb, demos, coeff)
        total.backward()
        grads = [p.grad.clone() for p in ac.model.parameters()]
        results.append((total.detach(), stats, kl, bc, grads))
    (t0, s0, k0, b0, g0), (t1, s1, k1, b1, g1) = results
    assert 0 < s0[-1] < 1  # clip_fraction: some ratios clipped, not all
    for a, b in ((t0, t1), (s0, s1), (k0, k1), (b0, b1), *zip(g0, g1, strict=True)):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-6)


def test_critic_loss_reaches_the_shared_trunk():
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    ppo = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1))
    batch = ppo.compute_advantages(rollout(ac)).reshape(-1)
    out = ppo.loss(batch)
    out["loss_critic"].backward()
    trunk = ac.model.module[0].module
    assert trunk.numeric[0].weight.grad.abs().sum() > 0
    assert trunk.lidar.net[0].weight.grad.abs().sum() > 0


def test_adam_stays_foreach_after_loading_an_older_optimizer_state():
    ac = make_actor_critic(ModelConfig(), 26, 16)
    ppo = PPO(ac, PPOConfig())
    state = ppo.state_dict()
    for group in state["optimizer"]["param_groups"]:
        group["foreach"] = None  # what checkpoints written before the foreach switch hold
    ppo.load_state_dict(state)
    assert all(g["foreach"] is True for g in ppo.optimizer.param_groups)


@pytest.mark.parametrize("with_values", [True, False])
def test_advantages_from_collected_values_match_torchrl_gae_with_the_critic(with_values):
    """GAE on values recorded during collection (next values shifted, critic only at episode
    ends and the last step) equals TorchRL's GAE running the critic on every observation."""
    from torchrl.objectives.value import GAE

    from truckrl.env import TruckEnv

    torch.manual_seed(0)
    env = TruckEnv(num_envs=6, seed=5, config={"max_steps": 12})  # truncations inside rows
    ac = make_actor_critic(ModelConfig(), 26, 16)
    policy = ac.rollout_policy if with_values else ac.actor
    with torch.no_grad():
        batch = env.rollout(40, policy, break_when_any_done=False)
    env.close()
    assert batch["next", "done"].any() and not batch["next", "done"][:, -1].all()
    assert ("state_value" in batch.keys()) == with_values
    cfg = PPOConfig(normalize_advantage=False)
    ours = PPO(ac, cfg).compute_advantages(batch.clone())
    ref = batch.clone().exclude("state_value")
    GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=ac.critic, average_gae=False)(ref)
    torch.testing.assert_close(ours["advantage"], ref["advantage"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(ours["value_target"], ref["value_target"], rtol=1e-5, atol=1e-6)


def test_advantages_of_rows_that_are_not_trajectories_use_the_critic_on_every_next_step():
    from torchrl.objectives.value import GAE

    ac = make_actor_critic(ModelConfig(), 26, 16)
    batch = rollout(ac)  # random next observations: the shift shortcut would be wrong here
    cfg = PPOConfig(normalize_advantage=False)
    ours = PPO(ac, cfg).compute_advantages(batch.clone())
    ref = batch.clone()
    GAE(gamma=cfg.gamma, lmbda=cfg.lmbda, value_network=ac.critic, average_gae=False)(ref)
    torch.testing.assert_close(ours["advantage"], ref["advantage"], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("max_std", [None, 0.55])
def test_max_std_bounds_the_std_that_the_entropy_bonus_grows(max_std):
    """A large entropy bonus and a fixed learning rate grow the std past 0.55 in a few steps;
    with ``model.max_std=0.55`` both the parameter and the sampled scale stop exactly there."""
    torch.manual_seed(0)
    ac = make_actor_critic(ModelConfig(init_std=0.5, max_std=max_std), num_obs=26, num_beams=16)
    cfg = PPOConfig(num_minibatches=4, num_epochs=4, lr=1e-2, lr_schedule="fixed")
    ppo = PPO(ac, PPOConfig(**{**cfg.__dict__, "entropy_coeff": 10.0}))
    metrics = ppo.update(rollout(ac))
    std = ac.gaussian.log_std.detach().exp()
    # the per-axis figures logged to TensorBoard are the two entries of the std itself
    assert metrics["action_std_longitudinal"] == pytest.approx(std[0].item())
    assert metrics["action_std_lateral"] == pytest.approx(std[1].item())
    assert metrics["action_std"] == pytest.approx(std.mean().item())
    if max_std is None:
        assert (std > 0.57).all()  # 16 Adam steps of ~1e-2 up in log-std: ~0.5 * e^0.16
    else:
        assert torch.allclose(std, torch.full((2,), 0.55))
        td = rollout(ac, seed=1)
        assert torch.allclose(td["scale"], torch.tensor(0.55))
        assert torch.allclose(ac.action_std(), torch.tensor(0.55))


def test_max_std_clamps_a_loaded_std_and_rejects_a_larger_init():
    ac = make_actor_critic(ModelConfig(max_std=1.0), num_obs=26, num_beams=16)
    with torch.no_grad():
        ac.gaussian.log_std.fill_(2.2)  # a checkpoint trained without the bound: std ~9
    assert torch.allclose(rollout(ac)["scale"], torch.tensor(1.0))
    ac.gaussian.project_()
    assert torch.allclose(ac.gaussian.log_std, torch.zeros(2))
    with pytest.raises(ConfigError, match=r"model.init_std = 2.0 must be <= model.max_std = 1.0"):
        ModelConfig(init_std=2.0, max_std=1.0)
    with pytest.raises(ConfigError, match="model.max_std"):
        ModelConfig(max_std=0.0)


def _demos(n=256, seed=2):
    """Demonstration samples whose every action is (0.5, -0.5)."""
    g = torch.Generator().manual_seed(seed)
    obs, lidar = torch.randn(n, 26, generator=g), torch.rand(n, 16, generator=g)
    action = torch.tensor([0.5, -0.5]).expand(n, 2).clone()
    return TensorDict({"observation": obs, "lidar": lidar, "action": action}, [n])


def _demo_mse(ac, demos):
    with torch.no_grad():
        loc = ac.actor(demos.select("observation", "lidar"))["loc"]
    return (loc - demos["action"]).square().mean().item()


@pytest.mark.parametrize("coeff", [0.0, 50.0])
def test_cloning_term_pulls_the_mean_to_the_demonstrated_actions(coeff):
    """``demos.bc_coeff``: with a weight the update fits the actor's mean to the demonstrated
    actions (MSE measured independently, before and after) and reports the term; with 0 it
    neither reports it nor changes the result of the same update (same seed, bit for bit)."""
    demos = _demos()
    results = []
    for attach in (False, True):
        torch.manual_seed(0)
        ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
        ppo = PPO(ac, PPOConfig(num_minibatches=4, num_epochs=4, lr=1e-3, lr_schedule="fixed"))
        if attach:
            ppo.demos, ppo.bc_coeff, ppo.bc_batch = demos, coeff, 64
        before = _demo_mse(ac, demos)
        batch = rollout(ac)
        torch.manual_seed(1)
        metrics = ppo.update(batch)
        results.append((before, _demo_mse(ac, demos), metrics))
    (b0, a0, m0), (b1, a1, m1) = results
    assert b0 == b1 and "loss_bc" not in m0
    if coeff == 0:
        assert a1 == a0 and "loss_bc" not in m1
    else:
        assert a1 < 0.5 * b1 and a1 < 0.5 * a0  # 16 steps of the cloning term
        assert 0 < m1["loss_bc"] < b1  # mean over the minibatches, each before its step


def test_cloning_weight_falls_linearly_to_zero():
    from tests.conftest import compose_config
    from truckrl.cli import to_config
    from truckrl.config.schemas import DemosConfig, TrainConfig
    from truckrl.rl.trainer import bc_weight

    dc = DemosConfig(bc_coeff=2.0, bc_frames=1_000)
    weights = [bc_weight(dc, f) for f in (0, 250, 500, 1_000, 5_000)]
    assert weights == pytest.approx([2.0, 1.5, 1.0, 0.0, 0.0])
    assert bc_weight(DemosConfig(), 0) == 0.0  # off by default
    for bad, field in (
        ("demos.bc_coeff=-1", "demos.bc_coeff"),
        ("demos.bc_frames=0", "demos.bc_frames"),
    ):
        with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
            to_config(TrainConfig, compose_config("train", bad))
