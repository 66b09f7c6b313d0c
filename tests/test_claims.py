"""Claims of the README and docs that the rest of the default suite does not run.

* The default ``truckrl train`` compiles the env (``env.compile=true``, experiment=demos), while
  every other end-to-end run here is eager: the compiled env is checked against the eager one
  on the training env's own config, and a tiny compiled ``truckrl train`` runs to a checkpoint.
* ``slow``: the CEM planner with ``planner.steer_prior=alternate`` solves the share of
  difficulty-6 scenes docs/planner.md reports (98.8 % of seed 2024, 98.9 % of seed 12345).

The compiled check and the compiled run use the same env config and batch (:data:`COMPILED`),
so the run finds the check's kernels in inductor's on-disk cache (``/tmp/torchinductor_$USER``)
and pays only dynamo's tracing; a cold cache adds the C++ builds to the first of them.
"""

from __future__ import annotations

import dataclasses
import json
import sys

import pytest
import torch
import yaml

from tests.conftest import TINY_TRAIN, compose_config, run_cli
from truckrl.cli import to_config
from truckrl.config.schemas import TrainConfig
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.collection import make_env
from truckrl.tasks.config import with_env_overrides

#: A tiny compiled training run: 8 trucks, 4-step episodes (a reset every few steps), a pool of
#: 16 episodes (refilled during a rollout, through the compiled observation of a symbolic batch).
TRUCKS = 8
COMPILED = [*TINY_TRAIN, "env.compile=true", f"collector.num_envs={TRUCKS}", "env.max_steps=4"]
COMPILED += ["env.episode_pool=16"]
#: Compiled and eager agree to this (absolute and relative): the slow test of
#: tests/test_env.py uses it too; inductor fuses float32 arithmetic in another order, which
#: moves the last bits (about 6e-7 measured over these steps), while a wrong step moves a
#: pose, reward or beam by centimetres or more.
TOL = 1e-4


def test_compiled_env_equals_the_eager_env_across_partial_resets():
    """The training env of a compiled ``truckrl train`` (experiment=demos' env with its
    ``train_env``, :data:`COMPILED`) against the same env eager: same seed, same random actions,
    12 steps; every output, the reset rows and the full state agree to :data:`TOL`; done flags
    and step counts exactly. In the first steps some trucks are restarted by a partial reset
    (``_reset``), so their episodes time out at staggered steps: each later step resets some
    trucks while the others drive on, and the 16-episode pool is refilled."""
    tc = to_config(TrainConfig, compose_config("train", *COMPILED))
    cfg = with_env_overrides(tc.env, tc.train_env, fixed=True, where="train_env")
    assert cfg.compile
    compiled = make_env(cfg, 1, TRUCKS, tc.seed)
    eager = make_env(dataclasses.replace(cfg, compile=False), 1, TRUCKS, tc.seed)
    td_c, td_e = compiled.reset(), eager.reset()
    gen = torch.Generator().manual_seed(0)
    sizes = set()

    def close(a: torch.Tensor, b: torch.Tensor, what: str) -> None:
        if a.dtype in (torch.bool, torch.int64, torch.int32):
            assert torch.equal(a, b), what
        else:
            torch.testing.assert_close(a, b, atol=TOL, rtol=TOL, msg=lambda m: f"{what}: {m}")

    for step in range(12):
        action = torch.rand(TRUCKS, 2, generator=gen) * 2.4 - 1.2
        out_c, td_c = compiled.step_and_maybe_reset(td_c.set("action", action))
        out_e, td_e = eager.step_and_maybe_reset(td_e.set("action", action))
        for key in out_e["next"].keys(include_nested=True, leaves_only=True):
            close(out_c["next", key], out_e["next", key], f"step {step} next/{key}")
        for key in td_e.keys(include_nested=True, leaves_only=True):  # the reset rows
            close(td_c[key], td_e[key], f"step {step} {key} after the reset")
        state_c, state_e = compiled.get_state(), eager.get_state()
        for key in state_e.keys(include_nested=True, leaves_only=True):
            close(state_c[key], state_e[key], f"step {step} state {key}")
        sizes.add(int(out_e["next", "done"].sum()))
        if step + 1 < cfg.max_steps:  # restart trucks step + 1, step + 5, ...: staggered ends
            restart = (torch.arange(TRUCKS) % cfg.max_steps == step + 1)[:, None]
            td_c = compiled.reset(td_c.set("_reset", restart))
            td_e = eager.reset(td_e.set("_reset", restart))
            for key in td_e.keys(include_nested=True, leaves_only=True):
                close(td_c[key], td_e[key], f"step {step} {key} after a partial reset")
    compiled.close()
    eager.close()
    assert sizes & set(range(1, TRUCKS)), sizes  # some trucks reset while others drove on


def test_a_compiled_training_run_writes_its_checkpoint(tmp_path):
    """``truckrl train`` as by default, with the compiled env (:data:`COMPILED`, two
    iterations): it completes and its checkpoint says it was compiled."""
    batch = TRUCKS * 16
    args = [*COMPILED, f"total_frames={2 * batch}", f"hydra.run.dir={tmp_path}"]
    proc = run_cli("train", *args)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    state = load_checkpoint(tmp_path)
    assert state["counters"]["iteration"] == 2 and state["counters"]["frames"] == 2 * batch
    assert yaml.safe_load(state["config"])["env"]["compile"] is True
    assert all(torch.isfinite(v).all() for v in state["model"].values())


#: docs/planner.md: ``truckrl plan episodes=1000 seed=12345 difficulty=6 planner.iterations=30
#: threads=2 planner.steer_prior=alternate`` solves 98.9 % (98.8 % on seed 2024). The first 200
#: of those scenes (199 solved) took 680 s of CPU on 2 threads here. Floor: were the 200 a fresh
#: sample of scenes each solved with probability p = 0.988, the count would be Binomial(200, p),
#: with P(X < 193) = 0.3 % and P(X < 194) = 1.1 %, so 193 of 200 (96.5 %) is the floor a
#: planner at its documented share meets. 200 scenes cannot resolve a point: a planner at 94 %
#: passes 8 % of the time, at 96 % 45 % (the knots alone, 97.7 %, 91 %).
PLANNER_SCENES, PLANNER_FLOOR = 200, 193


@pytest.mark.slow
def test_the_planner_solves_the_documented_share_of_difficulty_6_scenes(tmp_path):
    out = tmp_path / "plan.json"
    args = [f"episodes={PLANNER_SCENES}", "seed=12345", "difficulty=6", "planner.iterations=30"]
    args += ["threads=2", "planner.steer_prior=alternate", "quiet=true", f"out={out}"]
    proc = run_cli("plan", *args, timeout=3600)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    report = json.loads(out.read_text())
    solved = sum(bool(e["success"]) for e in report["per_episode"])
    assert report["planned"] == PLANNER_SCENES and report["replay_mismatches"] == 0
    print(f"planner: {solved} of {PLANNER_SCENES} solved", file=sys.stderr)
    assert solved >= PLANNER_FLOOR, f"{solved} of {PLANNER_SCENES} solved, floor {PLANNER_FLOOR}"
