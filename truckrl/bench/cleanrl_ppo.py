"""A CleanRL-style single-file PPO on the batched trucks: the reference trainer of ``truckrl bench
trainers``.

Read top to bottom: :class:`Agent` (two MLPs on the concatenated Dict observation), :func:`gae`,
:func:`ppo_loss`, then :func:`train`, the rollout loop and the minibatch epochs, after CleanRL's
``ppo_continuous_action.py`` (Huang et al., "CleanRL", JMLR 23(274), 2022). Plain torch over
:class:`~truckrl.gym.vector.TruckVectorEnv` ``(tensors=True)``: the trucks are one batch, the
rollout stays in tensors. The difficulty curriculum is the same rule as truckrl's trainer
(:class:`~truckrl.rl.curriculum.Curriculum`, the paper's), fed each rollout's finished episodes in
time order and applied through ``set_difficulty`` before the next rollout.

What it leaves out of CleanRL's script, to stay minimal and on a par with the SB3 recipe
(:data:`truckrl.gym.sb3.PPO_KWARGS`): observation and reward normalisation, learning-rate
annealing (a wall-clock budget has no known end) and value-loss clipping. What it adds:
truncated episodes bootstrap from the value of their last observation (as SB3 does), since the
env's timeout is not a terminal state.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from truckrl.env.spec import LIDAR_KEY, OBS_KEY


@dataclass(frozen=True)
class PPOSettings:
    """The PPO numbers; the defaults are the SB3 recipe's (``truckrl.gym.sb3.PPO_KWARGS``,
    experiment=quick's numbers)."""

    steps: int = 32  # rollout length per truck [steps]
    minibatch: int = 1024  # [frames]
    epochs: int = 5
    lr: float = 3e-4
    gamma: float = 0.998
    gae_lambda: float = 0.95
    clip: float = 0.2
    ent_coef: float = 0.005
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    hidden: tuple[int, ...] = (128, 64)
    init_std: float = 0.5


def _mlp(inputs: int, hidden: tuple[int, ...], out: int, gain: float) -> nn.Sequential:
    """tanh MLP with orthogonal init (CleanRL's ``layer_init``); the last layer's gain ``gain``."""
    layers: list[nn.Module] = []
    for width in hidden:
        layer = nn.Linear(inputs, width)
        nn.init.orthogonal_(layer.weight, math.sqrt(2))
        nn.init.zeros_(layer.bias)
        layers += [layer, nn.Tanh()]
        inputs = width
    last = nn.Linear(inputs, out)
    nn.init.orthogonal_(last.weight, gain)
    nn.init.zeros_(last.bias)
    return nn.Sequential(*layers, last)


class Agent(nn.Module):
    """Gaussian actor and critic, separate tanh MLPs on ``cat(observation [N, F], lidar [N, R])``;
    a state-independent log std ``[A]``."""

    def __init__(self, features: int, beams: int, actions: int, s: PPOSettings) -> None:
        super().__init__()
        self.actor = _mlp(features + beams, s.hidden, actions, 0.01)
        self.critic = _mlp(features + beams, s.hidden, 1, 1.0)
        self.log_std = nn.Parameter(torch.full((actions,), math.log(s.init_std)))

    def value(self, obs: Tensor, lidar: Tensor) -> Tensor:
        """``[N]`` state values."""
        return self.critic(torch.cat([obs, lidar], -1)).squeeze(-1)

    def dist(self, obs: Tensor, lidar: Tensor) -> torch.distributions.Normal:
        """The action distribution, ``[N, A]``."""
        mean = self.actor(torch.cat([obs, lidar], -1))
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))

    @torch.no_grad()
    def act(self, obs: Tensor, lidar: Tensor) -> Tensor:
        """The mean action ``[N, A]`` (evaluation: ``(observation, lidar) -> action``)."""
        return self.actor(torch.cat([obs, lidar], -1))


def gae(
    rewards: Tensor, values: Tensor, dones: Tensor, next_value: Tensor, gamma: float, lam: float
) -> tuple[Tensor, Tensor]:
    """Generalised advantage estimation (Schulman et al. 2016, eq. 16) over a rollout.

    Args:
        rewards: ``[T, N]`` reward of transition ``t``.
        values: ``[T, N]`` value of the state transition ``t`` starts from.
        dones: ``[T, N]`` bool, the episode ended with transition ``t`` (the next state belongs
            to a new episode: no bootstrap across it).
        next_value: ``[N]`` value of the state after the last transition.

    Returns:
        ``(advantages [T, N], returns [T, N])``, returns = advantages + values.
    """
    steps = rewards.shape[0]
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(steps)):
        following = next_value if t == steps - 1 else values[t + 1]
        alive = 1.0 - dones[t].float()
        delta = rewards[t] + gamma * following * alive - values[t]
        last = delta + gamma * lam * alive * last
        advantages[t] = last
    return advantages, advantages + values


def ppo_loss(agent: Agent, batch: dict[str, Tensor], s: PPOSettings) -> Tensor:
    """The clipped surrogate + value + entropy loss of one minibatch (advantages normalised
    within it)."""
    dist = agent.dist(batch["obs"], batch["lidar"])
    logp = dist.log_prob(batch["action"]).sum(-1)
    ratio = (logp - batch["logp"]).exp()
    adv = batch["adv"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    policy = -torch.min(ratio * adv, ratio.clamp(1 - s.clip, 1 + s.clip) * adv).mean()
    value = 0.5 * (agent.value(batch["obs"], batch["lidar"]) - batch["ret"]).pow(2).mean()
    entropy = dist.entropy().sum(-1).mean()
    return policy + s.vf_coef * value - s.ent_coef * entropy


def train(
    env: Any,
    curriculum: Any,
    seconds: float,
    s: PPOSettings = PPOSettings(),
    seed: int = 0,
    on_iteration: Callable[[int, float], None] | None = None,
) -> tuple[Agent, int]:
    """PPO on ``env`` (a ``TruckVectorEnv(tensors=True)`` of N trucks) until ``seconds`` of wall
    clock have passed (checked between iterations).

    Args:
        curriculum: :class:`~truckrl.rl.curriculum.Curriculum` (or any object with its
            ``difficulty`` and ``update(success, difficulty) -> bool``); the env's difficulty
            follows it.
        on_iteration: called after each iteration with ``(frames, difficulty)``.

    Returns:
        ``(agent, frames)``: the trained agent and the env steps taken (all trucks).
    """
    torch.manual_seed(seed)
    n, steps = env.num_envs, s.steps
    features = env.single_observation_space[OBS_KEY].shape[0]
    beams = env.single_observation_space[LIDAR_KEY].shape[0]
    agent = Agent(features, beams, 2, s)
    optimizer = torch.optim.Adam(agent.parameters(), lr=s.lr, eps=1e-5)
    env.set_difficulty(curriculum.difficulty)
    obs, _ = env.reset(seed=seed)

    # rollout storage, [T, N, ...]
    buf_obs = torch.zeros(steps, n, features)
    buf_lidar = torch.zeros(steps, n, beams)
    buf_action = torch.zeros(steps, n, 2)
    buf_logp = torch.zeros(steps, n)
    buf_reward = torch.zeros(steps, n)
    buf_done = torch.zeros(steps, n, dtype=torch.bool)
    buf_value = torch.zeros(steps, n)
    buf_success = torch.zeros(steps, n, dtype=torch.bool)
    buf_judged = torch.zeros(steps, n)

    frames, deadline = 0, time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        # 1. rollout: T steps of all N trucks with the current policy
        with torch.no_grad():
            for t in range(steps):
                o, li = obs[OBS_KEY], obs[LIDAR_KEY]
                dist = agent.dist(o, li)
                action = dist.sample()
                buf_obs[t], buf_lidar[t], buf_action[t] = o, li, action
                buf_logp[t] = dist.log_prob(action).sum(-1)
                buf_value[t] = agent.value(o, li)
                obs, reward, terminated, truncated, info = env.step(action)
                done = terminated | truncated
                # a timeout is not a terminal state: bootstrap from the last observation
                last = info["final_obs"]
                cut = (truncated & ~terminated).float()
                reward = reward + s.gamma * cut * agent.value(last[OBS_KEY], last[LIDAR_KEY])
                buf_reward[t], buf_done[t] = reward, done
                buf_success[t] = info["final_info"]["success"] & done
                buf_judged[t] = info["final_info"]["difficulty"]
            next_value = agent.value(obs[OBS_KEY], obs[LIDAR_KEY])
        frames += steps * n

        # 2. curriculum: this rollout's finished episodes, in time order
        ended = buf_done.reshape(-1)
        if curriculum.update(buf_success.reshape(-1)[ended], buf_judged.reshape(-1)[ended]):
            env.set_difficulty(curriculum.difficulty)

        # 3. advantages, then minibatch epochs of the clipped loss
        adv, ret = gae(buf_reward, buf_value, buf_done, next_value, s.gamma, s.gae_lambda)
        data = {
            "obs": buf_obs.reshape(-1, features),
            "lidar": buf_lidar.reshape(-1, beams),
            "action": buf_action.reshape(-1, 2),
            "logp": buf_logp.reshape(-1),
            "adv": adv.reshape(-1),
            "ret": ret.reshape(-1),
        }
        for _ in range(s.epochs):
            order = torch.randperm(steps * n)
            for idx in order.split(s.minibatch):
                loss = ppo_loss(agent, {k: v[idx] for k, v in data.items()}, s)
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), s.max_grad_norm)
                optimizer.step()
        if on_iteration is not None:
            on_iteration(frames, curriculum.difficulty)
    return agent, frames
