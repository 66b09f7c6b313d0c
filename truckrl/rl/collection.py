"""Data collection: environments (seeding per worker, in-process or ParallelEnv, the curriculum
difficulty sent to every worker) and the ``Collector`` that steps them with the rollout policy."""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.collectors import Collector
from torchrl.envs import EnvBase, ParallelEnv

from truckrl.env import TruckEnv
from truckrl.rl.network import ActorCritic
from truckrl.tasks import EnvConfig


def env_seed(seed: int, iteration: int, worker: int) -> int:
    """Independent, reproducible seed per (run seed, session start iteration, worker)."""
    return int(np.random.SeedSequence([seed, iteration, worker]).generate_state(1)[0])


def make_env(
    env_cfg: EnvConfig,
    workers: int,
    num_envs: int,
    seed: int,
    iteration: int = 0,
    device: str | torch.device = "cpu",
) -> EnvBase:
    """One in-process TruckEnv (``workers=1``) or a ParallelEnv of ``workers`` batched TruckEnvs,
    each of ``num_envs`` trucks, seeded from ``(seed, iteration, worker)``."""
    make = functools.partial(TruckEnv, num_envs=num_envs, device=device, config=env_cfg)
    if workers == 1:
        return make(seed=env_seed(seed, iteration, 0))
    fns = [functools.partial(make, seed=env_seed(seed, iteration, w)) for w in range(workers)]
    env = ParallelEnv(workers, fns, device=device)
    env.start()
    return env


def set_difficulty(env: EnvBase, difficulty: float) -> tuple[float, float]:
    """Send the difficulty to every worker; return ``(position [m], heading [deg])`` tolerances
    read back from the (first) environment."""
    env.set_difficulty(difficulty)
    tol = env.tolerances()
    pos, ang = tol[0] if isinstance(env, ParallelEnv) else tol
    return float(pos.reshape(-1)[0]), math.degrees(float(ang.reshape(-1)[0]))


def check_difficulty(batch, difficulty: float) -> None:
    """Raise if a collected batch ``[..., T]`` was not run at ``difficulty`` at its last step."""
    reached = batch["next", "difficulty"][..., -1, :]
    if not torch.isclose(reached, torch.full_like(reached, difficulty)).all():
        raise RuntimeError(f"difficulty {difficulty} did not reach every environment worker")


class CompiledRollout(TensorDictModuleBase):
    """:attr:`ActorCritic.rollout_policy <truckrl.rl.network.ActorCritic.rollout_policy>`
    under ``torch.compile`` (``collector.compile_policy``): the trunk, both heads, the Gaussian
    sample and its log-prob in one graph.

    Forward: a ``[*B]`` tensordict with the policy's in_keys, "observation" ``[*B, num_obs]`` and
    "lidar" ``[*B, R]`` (the collector's carrier, any other entries included) -> the same
    tensordict with :data:`~truckrl.rl.network.ROLLOUT_KEYS` written, as the eager policy
    writes them.

    Only the policy's in_keys enter the compiled call (the carrier's other entries would
    each add guards). ``fallback_random``: the action noise comes from torch's own generator, as
    in the eager policy, so a seeded run draws the same actions either way (equal to float
    rounding; ``tests/rl/test_collection.py``). The parameters are the eager policy's own
    objects: the optimiser's steps reach the compiled calls without copying weights.
    """

    def __init__(self, policy: TensorDictModuleBase) -> None:
        super().__init__()
        self.in_keys = list(policy.in_keys)  # observation and lidar
        self.out_keys = list(policy.out_keys)  # ROLLOUT_KEYS
        self.policy = policy
        # kept out of the module tree: its parameters are self.policy's, registered once
        self.__dict__["_compiled"] = torch.compile(
            policy, dynamic=False, options={"fallback_random": True}
        )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = self._compiled(tensordict.select(*self.in_keys))
        return tensordict.update(out.select(*self.out_keys))


def make_collector(
    env: EnvBase,
    ac: ActorCritic,
    frames_per_batch: int,
    compile_policy: bool = False,
    device: str | torch.device = "cpu",
) -> Collector:
    """The training ``Collector``: ``env`` stepped with the actor-critic's rollout policy (actor
    and value head: GAE reuses the collected values), :class:`CompiledRollout` with
    ``compile_policy``; ``frames_per_batch`` frames per batch, without end.
    """
    policy = CompiledRollout(ac.rollout_policy) if compile_policy else ac.rollout_policy
    return Collector(
        env,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=-1,
        device=device,
        auto_register_policy_transforms=False,  # the policy is stateless: no InitTracker needed
    )
