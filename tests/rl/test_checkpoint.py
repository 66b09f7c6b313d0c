"""Checkpoints: atomic writes, weights_only round trip, clear errors, RNG restore."""

import os
import random

import numpy as np
import pytest
import torch

from truckrl.rl import checkpoint as ckpt
from truckrl.rl.curriculum import Curriculum, CurriculumConfig
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.rl.ppo import PPO, PPOConfig


def training_state():
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    ppo = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1))
    loss = sum(p.sum() for p in ac.model.parameters())
    loss.backward()
    ppo.optimizer.step()  # non-empty Adam state
    return {
        "version": ckpt.CHECKPOINT_VERSION,
        "model": ac.model.state_dict(),
        "ppo": ppo.state_dict(),
        "curriculum": Curriculum(CurriculumConfig()).state_dict(),
        "counters": {"iteration": 3, "frames": 4096, "wall_time_s": 1.5},
        "rng": ckpt.capture_rng(),
        "env_seed": 7,
        "config": "seed: 7\n",
    }


def test_round_trip_with_weights_only(tmp_path):
    state = training_state()
    path = ckpt.save_checkpoint(tmp_path / "checkpoints" / "last.pt", state)
    raw = torch.load(path, weights_only=True)  # the plain loader must accept it
    assert raw["counters"] == state["counters"]
    loaded = ckpt.load_checkpoint(tmp_path)  # a run dir resolves to checkpoints/last.pt
    for k, v in state["model"].items():
        torch.testing.assert_close(loaded["model"][k], v)
    assert loaded["ppo"]["optimizer"]["state"].keys() == state["ppo"]["optimizer"]["state"].keys()
    assert loaded["config"] == "seed: 7\n"


def test_interrupted_write_keeps_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "last.pt"
    ckpt.save_checkpoint(path, {"version": ckpt.CHECKPOINT_VERSION, "x": torch.zeros(3)})

    def dying_save(obj, f):
        f.write(b"partial garbage")
        raise KeyboardInterrupt

    monkeypatch.setattr(torch, "save", dying_save)
    with pytest.raises(KeyboardInterrupt):
        ckpt.save_checkpoint(path, {"version": ckpt.CHECKPOINT_VERSION, "x": torch.ones(3)})
    assert os.listdir(tmp_path) == ["last.pt"]  # no temp file left behind
    torch.testing.assert_close(ckpt.load_checkpoint(path)["x"], torch.zeros(3))


def test_missing_and_corrupt_checkpoints_raise_checkpoint_error(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="not found"):
        ckpt.load_checkpoint(tmp_path / "nope.pt")
    with pytest.raises(ckpt.CheckpointError, match="no checkpoint in run dir"):
        ckpt.load_checkpoint(tmp_path)
    good = ckpt.save_checkpoint(tmp_path / "good.pt", training_state())
    bad = tmp_path / "bad.pt"
    bad.write_bytes(good.read_bytes()[:200])
    with pytest.raises(ckpt.CheckpointError, match="cannot read"):
        ckpt.load_checkpoint(bad)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.ones(1)}, other)
    with pytest.raises(ckpt.CheckpointError, match="not a truckrl checkpoint"):
        ckpt.load_checkpoint(other)


def test_rng_restore_replays_all_three_generators(tmp_path):
    torch.manual_seed(1)
    np.random.seed(2)  # noqa: NPY002
    random.seed(3)
    ckpt.save_checkpoint(
        tmp_path / "r.pt", {"version": ckpt.CHECKPOINT_VERSION, "rng": ckpt.capture_rng()}
    )
    first = (torch.rand(4), np.random.rand(4), [random.random() for _ in range(4)])  # noqa: NPY002
    ckpt.restore_rng(ckpt.load_checkpoint(tmp_path / "r.pt")["rng"])
    again = (torch.rand(4), np.random.rand(4), [random.random() for _ in range(4)])  # noqa: NPY002
    torch.testing.assert_close(first[0], again[0])
    np.testing.assert_array_equal(first[1], again[1])
    assert first[2] == again[2]


def test_checkpoint_mode_follows_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        path = ckpt.save_checkpoint(tmp_path / "last.pt", {"version": ckpt.CHECKPOINT_VERSION})
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o640  # not mkstemp's 0o600


def test_text_and_unsafe_files_say_why_without_suggesting_an_unsafe_load(tmp_path):
    text = tmp_path / "config.yaml"
    text.write_text("seed: 0\n")
    with pytest.raises(ckpt.CheckpointError, match="not a truckrl checkpoint: it is a text file"):
        ckpt.load_checkpoint(text)
    unsafe = tmp_path / "unsafe.pt"
    torch.save({"version": ckpt.CHECKPOINT_VERSION, "x": ckpt.Path("x")}, unsafe)
    with pytest.raises(ckpt.CheckpointError) as err:
        ckpt.load_checkpoint(unsafe)
    assert "safe load refuses" in str(err.value) and "weights_only" not in str(err.value)


def test_optimizer_state_of_another_model_is_refused_before_the_first_step():
    state = training_state()
    other = make_actor_critic(ModelConfig(fusion_dim=32), num_obs=26, num_beams=16)
    ppo = PPO(other, PPOConfig(num_minibatches=1, num_epochs=1))
    with pytest.raises(ckpt.CheckpointError, match="optimizer state does not fit"):
        ckpt.check_optimizer_state(ppo.optimizer, state["ppo"]["optimizer"], "x.pt", None)
    ac = make_actor_critic(ModelConfig(), num_obs=26, num_beams=16)
    same = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1))
    ckpt.check_optimizer_state(same.optimizer, state["ppo"]["optimizer"], "x.pt", 1)  # fits
    with pytest.raises(ckpt.CheckpointError, match="bad counters"):
        ckpt.check_optimizer_state(same.optimizer, state["ppo"]["optimizer"], "x.pt", 2)
