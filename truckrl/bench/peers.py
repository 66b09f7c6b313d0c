"""Peer simulators for ``truckrl bench env --peers``: VMAS with the closest scene it has.

VMAS (``pip install 'truckrl[bench]'``, tested with 1.5.2) is a batched PyTorch 2-D robot
simulator. Its closest scenario to ours, written here (:func:`vmas_scenario`):

* one agent per env with VMAS's ``KinematicBicycle`` dynamics (a single rigid body: no trailer,
  no articulation, no steering-rate or jerk limits), wheelbase 4 m, width 2.5 m, 10 m/s, 35 deg;
* a 16-ray full-circle ``Lidar`` of 50 m range (our default beam count and range);
* 24 static ``Line`` landmarks of 20 m at random poses in a 200 m square (our intersection
  scene has ~30 valid segments of 72 slots, in the same span);
* ``dt = 0.1`` s as ours; VMAS's own physics step (collision forces against the lines);
* random actions; an env is done when the agent leaves the square, a LiDAR ray reads under
  1 m (it touches a line) or after 500 steps, and is then reset with ``env.reset_at(i)``
  (VMAS has no batched partial reset, so this is the loop its TorchRL wrapper runs too).

Measured like TruckEnv (random policy, resets included, after a warm-up): env-steps/s =
N x steps / wall time.
"""

from __future__ import annotations

import math
import time

import torch

#: The pip extra that installs the peers.
INSTALL_HINT = "pip install 'truckrl[bench]'"

NUM_LINES = 24
NUM_RAYS = 16
LIDAR_RANGE = 50.0  # [m]
HALF_SPAN = 100.0  # [m] half side of the square the lines and agents live in
LINE_LENGTH = 20.0  # [m]
WHEELBASE = 4.0  # [m] l_f + l_r
WIDTH = 2.5  # [m]
MAX_SPEED = 10.0  # [m/s]
MAX_STEER = math.radians(35.0)
DT = 0.1  # [s]
MAX_STEPS = 500
TOUCH = 1.0  # [m] a LiDAR reading below this ends the episode


def vmas_available() -> bool:
    """Whether the ``vmas`` package (and what it imports) can be imported."""
    try:
        import vmas  # noqa: F401
    except ImportError:
        return False
    return True


def vmas_scenario():
    """A VMAS ``BaseScenario`` instance of the scene in the module docstring."""
    from vmas.simulator.core import Agent, Box, Landmark, Line, World
    from vmas.simulator.dynamics.kinematic_bicycle import KinematicBicycle
    from vmas.simulator.scenario import BaseScenario
    from vmas.simulator.sensors import Lidar

    class TruckLikeScenario(BaseScenario):
        def make_world(self, batch_dim: int, device: torch.device, **kwargs):
            world = World(batch_dim, device, dt=DT)
            self.lines = []
            for i in range(NUM_LINES):
                line = Landmark(name=f"line_{i}", collide=True, shape=Line(length=LINE_LENGTH))
                world.add_landmark(line)
                self.lines.append(line)
            self.agent = Agent(
                name="truck",
                shape=Box(length=WHEELBASE, width=WIDTH),
                collide=True,
                u_range=[MAX_SPEED, MAX_STEER],
                u_multiplier=[1, 1],
                max_speed=MAX_SPEED,
                dynamics=KinematicBicycle(
                    world,
                    width=WIDTH,
                    l_f=WHEELBASE / 2,
                    l_r=WHEELBASE / 2,
                    max_steering_angle=MAX_STEER,
                    integration="euler",
                ),
                sensors=[Lidar(world, n_rays=NUM_RAYS, max_range=LIDAR_RANGE, render=False)],
            )
            world.add_agent(self.agent)
            self.steps = torch.zeros(batch_dim, dtype=torch.int64, device=device)
            return world

        def _place(self, entity, n: int, env_index, span: float, rot: bool) -> None:
            dev = self.world.device
            pos = (torch.rand(n, 2, device=dev) * 2 - 1) * span
            r = (torch.rand(n, 1, device=dev) * 2 - 1) * math.pi
            if env_index is not None:
                pos, r = pos[0], r[0]
            entity.set_pos(pos, batch_index=env_index)
            if rot:
                entity.set_rot(r, batch_index=env_index)

        def reset_world_at(self, env_index: int | None = None) -> None:
            n = self.world.batch_dim
            for line in self.lines:
                self._place(line, n, env_index, HALF_SPAN, rot=True)
            self._place(self.agent, n, env_index, HALF_SPAN / 4, rot=True)
            if env_index is None:
                self.steps.zero_()
            else:
                self.steps[env_index] = 0

        def observation(self, agent):
            ranges = agent.sensors[0].measure()
            return torch.cat((agent.state.pos, agent.state.vel, agent.state.rot, ranges), -1)

        def reward(self, agent):
            self.steps += 1
            return torch.zeros(self.world.batch_dim, device=self.world.device)

        def done(self):
            pos = self.agent.state.pos
            ranges = self.agent.sensors[0]._last_measurement
            out = (pos.abs() > HALF_SPAN).any(-1) | (self.steps >= MAX_STEPS)
            if ranges is not None:
                out = out | (ranges < TOUCH).any(-1)
            return out

    return TruckLikeScenario()


def vmas_steps_per_second(n: int, steps: int, warmup: int, seed: int = 0) -> dict:
    """VMAS env-steps/s at ``n`` envs (random actions, resets included) and the reset count."""
    import vmas

    env = vmas.make_env(
        vmas_scenario(), num_envs=n, device="cpu", continuous_actions=True, seed=seed
    )
    gen = torch.Generator().manual_seed(seed)
    limit = torch.tensor([MAX_SPEED, MAX_STEER])
    resets = 0

    def run(k: int) -> None:
        nonlocal resets
        for _ in range(k):
            action = (torch.rand(n, 2, generator=gen) * 2 - 1) * limit
            _, _, dones, _ = env.step([action])
            for i in dones.nonzero().view(-1).tolist():
                env.reset_at(i)
                resets += 1

    t0 = time.perf_counter()
    env.reset()
    run(warmup)
    warm = time.perf_counter() - t0
    resets = 0
    t0 = time.perf_counter()
    run(steps)
    sps = n * steps / (time.perf_counter() - t0)
    return {"steps/s": sps, "warmup_s": warm, "resets/step": resets / steps}
