"""``truckrl.gym``: registration, ``make`` / ``make_vec`` with overrides, the VectorEnv against
TruckEnv stepped by hand, SAME_STEP autoreset, spaces, bad actions, tensors, rendering."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode

import truckrl.gym
from truckrl.config.fields import ConfigError
from truckrl.env.make import make_env
from truckrl.gym.vector import TruckVectorEnv
from truckrl.tasks import task_names
from truckrl.viz.draw import COLORS

ID = "truckrl/Intersection-v0"
N = 4


def _actions(steps: int, n: int = N, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, n, 2)).astype(np.float32)


def test_every_task_has_an_id_that_make_and_make_vec_build():
    assert sorted(truckrl.gym.ENV_IDS.values()) == task_names()
    assert {"truckrl/Intersection-v0", "truckrl/Dock-v0", "truckrl/UTurn-v0"} <= set(
        truckrl.gym.ENV_IDS
    )
    for id, task in truckrl.gym.ENV_IDS.items():
        assert gymnasium.spec(id).vector_entry_point == truckrl.gym.VECTOR_ENTRY_POINT
        env = gymnasium.make(id)
        assert env.unwrapped.env.config.task.name == task
        venv = gymnasium.make_vec(id, num_envs=2)
        assert isinstance(venv, TruckVectorEnv) and venv.env.config.task.name == task
        assert venv.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP


def test_module_prefixed_id_and_overrides_as_keywords():
    env = gymnasium.make(f"truckrl.gym:{ID}", difficulty=2.0, **{"lidar.num_beams": 8})
    obs, info = env.reset(seed=0)
    assert obs["lidar"].shape == (8,) and info["difficulty"] == 2.0
    venv = gymnasium.make_vec(ID, num_envs=3, lidar={"num_beams": 12}, max_steps=7)
    obs, _ = venv.reset(seed=0)
    assert obs["lidar"].shape == (3, 12) and obs["observation"].shape == (3, 26)
    assert venv.env.config.max_steps == 7 and venv.num_envs == 3
    with pytest.raises(ConfigError, match=r"\[.num_bems.\] for env.lidar"):
        gymnasium.make_vec(ID, num_envs=2, **{"lidar.num_bems": 8})


def test_spaces():
    venv = TruckVectorEnv(N, seed=0, **{"lidar.num_beams": 10})
    obs_space, act = venv.single_observation_space, venv.single_action_space
    assert set(obs_space.spaces) == {"observation", "lidar"}
    assert obs_space["observation"].shape == (26,) and obs_space["lidar"].shape == (10,)
    assert (obs_space["lidar"].low == 0).all() and (obs_space["lidar"].high == 1).all()
    assert act.shape == (2,) and (act.low == -1).all() and (act.high == 1).all()
    assert act.dtype == np.float32 and venv.action_space.shape == (N, 2)
    obs, _ = venv.reset(seed=1)
    assert venv.observation_space.contains(obs)
    obs, *_ = venv.step(_actions(1)[0])
    assert venv.observation_space.contains(obs)


def test_steps_match_truckenv_stepped_by_hand():
    """Same seed, same actions: TruckEnv's own step_and_maybe_reset gives the same arrays,
    over enough steps that trucks end and restart (short episodes)."""
    steps, overrides = 40, {"max_steps": 15}
    venv = TruckVectorEnv(N, seed=3, **overrides)
    ref = make_env(num_envs=N, seed=3, **overrides)
    obs, _ = venv.reset()
    td = ref.reset()
    ended = 0
    for a in _actions(steps):
        obs, reward, term, trunc, info = venv.step(a)
        out, td = ref.step_and_maybe_reset(td.set("action", torch.from_numpy(a)))
        np.testing.assert_array_equal(obs["observation"], td["observation"].numpy())
        np.testing.assert_array_equal(obs["lidar"], td["lidar"].numpy())
        np.testing.assert_array_equal(reward, out["next", "reward"][:, 0].numpy())
        np.testing.assert_array_equal(term, out["next", "terminated"][:, 0].numpy())
        np.testing.assert_array_equal(trunc, out["next", "truncated"][:, 0].numpy())
        np.testing.assert_array_equal(info["success"], td["success"][:, 0].numpy())
        ended += int((term | trunc).sum())
    assert ended >= N  # every truck restarted at least once on average


def test_same_step_autoreset_by_hand():
    """All N trucks time out together at step 3 (zero actions: they stand still): that step
    returns the next episodes' first observation (episodes N..2N-1 of the seed's stream, as a
    2N-truck reset draws them), info of fresh episodes, and the transition's last observation
    and info under final_obs / final_info (TruckEnv's plain step without autoreset)."""
    venv = TruckVectorEnv(N, seed=5, max_steps=3)
    plain = make_env(num_envs=N, seed=5, max_steps=3)  # steps without restarting
    wide = make_env(num_envs=2 * N, seed=5, max_steps=3)
    venv.reset()
    td = plain.reset()
    zero = np.zeros((N, 2), np.float32)
    for t in range(3):
        obs, reward, term, trunc, info = venv.step(zero)
        td = plain.step(td.set("action", torch.from_numpy(zero)))["next"]
        if t < 2:
            assert "final_obs" not in info and not (term | trunc).any()
    assert trunc.all() and not term.any()
    assert info["_final_obs"].all() and info["_final_info"].all()
    assert list(info["step_count"]) == [0] * N  # the fresh episodes
    assert list(info["final_info"]["step_count"]) == [3] * N
    assert not info["success"].any() and (info["r_progress"] == 0).all()
    np.testing.assert_array_equal(info["final_info"]["r_timeout"], td["r_timeout"][:, 0].numpy())
    for i in range(N):
        np.testing.assert_array_equal(info["final_obs"][i]["lidar"], td["lidar"][i].numpy())
        np.testing.assert_array_equal(
            info["final_obs"][i]["observation"], td["observation"][i].numpy()
        )
    first = wide.reset()
    np.testing.assert_array_equal(obs["observation"], first["observation"][N:].numpy())
    np.testing.assert_array_equal(obs["lidar"], first["lidar"][N:].numpy())
    assert reward.shape == (N,) and reward.dtype == np.float32


def test_reset_seed_is_reproducible_and_options_set_difficulty():
    venv = TruckVectorEnv(N)
    a, _ = venv.reset(seed=11)
    b, info = venv.reset(seed=11, options={"difficulty": 1.5})
    np.testing.assert_array_equal(a["lidar"], b["lidar"])
    assert (info["difficulty"] == 1.5).all() and venv.difficulty == 1.5
    c, _ = venv.reset(seed=12)
    assert not np.array_equal(a["observation"], c["observation"])
    with pytest.raises(ValueError, match="one int seeds the whole batch"):
        venv.reset(seed=[1, 2, 3, 4])


def test_set_difficulty_from_outside():
    venv = TruckVectorEnv(N, seed=0)
    venv.reset()
    venv.set_difficulty(2.0)
    *_, info = venv.step(np.zeros((N, 2)))
    assert (info["difficulty"] == 2.0).all()
    tol_pos, _ = venv.env.tolerances()
    assert torch.allclose(tol_pos, torch.full((N,), 30.0 / 4))  # 30 m * 2**-2
    with pytest.raises(ConfigError, match="difficulty"):
        venv.set_difficulty(-1.0)


def test_bad_actions_error_or_documented_clamp():
    venv = TruckVectorEnv(N, seed=2)
    twin = TruckVectorEnv(N, seed=2)
    venv.reset()
    twin.reset()
    with pytest.raises(ValueError, match=r"shape \(3, 2\); expected \(4, 2\)"):
        venv.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"shape \(8,\); expected \(4, 2\)"):
        venv.step(np.zeros(8))
    a = _actions(1)[0].astype(np.float64)
    a[1] = [np.nan, 0.3]
    a[2] = [5.0, -7.0]
    obs, _, _, _, info = venv.step(a)
    clean = a.copy()
    clean[1] = 0.0  # non-finite rows act as a zero command
    clean[2] = [1.0, -1.0]  # components clamp to [-1, 1]
    ref, _, _, _, ref_info = twin.step(clean)
    assert list(info["action_nonfinite"]) == [False, True, False, False]
    assert not ref_info["action_nonfinite"].any()
    np.testing.assert_array_equal(obs["observation"], ref["observation"])
    strict = TruckVectorEnv(N, seed=2, nonfinite_action="error")
    strict.reset()
    with pytest.raises(ValueError, match=r"non-finite action for env\(s\) \[1\]"):
        strict.step(a)


def test_tensors_on_request_hold_the_numpy_values():
    arrays, tensors = TruckVectorEnv(N, seed=4), TruckVectorEnv(N, seed=4, tensors=True)
    arrays.reset()
    tensors.reset()
    for a in _actions(5):
        o1, r1, _, _, i1 = arrays.step(a)
        o2, r2, _, _, i2 = tensors.step(torch.from_numpy(a))
        assert isinstance(o2["lidar"], torch.Tensor) and isinstance(r2, torch.Tensor)
        np.testing.assert_array_equal(o1["lidar"], o2["lidar"].numpy())
        np.testing.assert_array_equal(r1, r2.numpy())
        np.testing.assert_array_equal(i1["pos_error"], i2["pos_error"].numpy())


def test_render_draws_the_bev_frame():
    venv = gymnasium.make_vec(ID, num_envs=3, render_mode="rgb_array", render_envs=2, seed=0)
    venv.reset()
    frames = venv.render()
    assert len(frames) == 2
    for f in frames:
        assert f.shape == (640, 640, 3) and f.dtype == np.uint8
        assert (f == COLORS["background"]).all(-1).mean() > 0.3  # the scene's background
        assert (f == COLORS["tractor"]).all(-1).any()  # the truck outline
    env = gymnasium.make(ID, render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().shape == (640, 640, 3)


def test_register_a_task_outside_the_package():
    """tests/tasks/reach, a task folder truckrl never names, appends one feature (27)."""
    id = truckrl.gym.register("tests.tasks.reach")
    assert id == "truckrl/Reach-v0"
    venv = gymnasium.make_vec(id, num_envs=2, seed=0)
    obs, _ = venv.reset()
    assert venv.env.config.task.name == "tests.tasks.reach" and obs["observation"].shape == (2, 27)
