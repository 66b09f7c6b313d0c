"""Bad inputs through the entry points (in-process): every row one line ``error: ...``, exit 2, no
traceback, nothing silent, no stray run dir.

Checkpoints go through ``train resume=``, ``evaluate checkpoint=`` and ``play checkpoint=``;
config values through Hydra's composition and the schemas' validation.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
import pickle
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
import yaml

from tests.conftest import compose_config
from tests.reliability.harness import (
    BATCH,
    TINY,
    Result,
    assert_one_line_error,
    run_main,
    run_session,
    tiny_config,
)
from truckrl.cli import one_line_errors
from truckrl.config.fields import ConfigError
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.network import ModelConfig, make_actor_critic
from truckrl.rl.ppo import PPO, PPOConfig

ENTRIES = ("train", "evaluate", "play")


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict:
    """A consistent 2-iteration checkpoint from a real session, as loaded."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        run = tmp_path_factory.mktemp("good")
        run_session(run, f"total_frames={2 * BATCH}")
    finally:
        torch.set_num_threads(threads)
    return load_checkpoint(run)


def saved(state: dict, path: Path) -> Path:
    torch.save(state, path)
    return path


def with_config(state: dict, **changes) -> dict:
    cfg = yaml.safe_load(state["config"])
    for dotted, value in changes.items():
        node = cfg
        *parents, last = dotted.split("__")
        for p in parents:
            node = node[p]
        node[last] = value
    return {**state, "config": yaml.safe_dump(cfg)}


def other_optimizer(state: dict) -> dict:
    """The Adam state of a model with other layer widths (same parameter count)."""
    ac = make_actor_critic(ModelConfig(fusion_dim=32), 26, 16)
    ppo = PPO(ac, PPOConfig(num_minibatches=1, num_epochs=1))
    sum(p.sum() for p in ac.model.parameters()).backward()
    ppo.optimizer.step()
    return {**state, "ppo": ppo.state_dict()}


class Unsafe:  # pickled by reference: a weights_only load must refuse it
    pass


def write_text(path: Path, text: str | bytes) -> Path:
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def truncated(state: dict, path: Path) -> Path:
    full = saved(state, path)
    full.write_bytes(full.read_bytes()[:300])
    return full


def without(key: str) -> Callable:
    return lambda s, p: saved({k: v for k, v in s.items() if k != key}, p)


def counters(**c) -> Callable:
    return lambda s, p: saved({**s, "counters": {**s["counters"], **c}}, p)


#: name: (make the file from the good state, entries it applies to, fragments of the message)
CHECKPOINTS: dict[str, tuple[Callable[[dict, Path], Path], tuple[str, ...], tuple[str, ...]]] = {
    "yaml text file": (
        lambda s, p: write_text(p, "seed: 0\nppo:\n  lr: 1e-4\n"),
        ENTRIES,
        ("not a truckrl checkpoint", "text file"),
    ),
    "empty file": (lambda s, p: write_text(p, ""), ENTRIES, ("not a truckrl checkpoint", "empty")),
    "truncated": (truncated, ENTRIES, ("not a truckrl checkpoint", "truncated or corrupt")),
    "unsafe pickle": (
        lambda s, p: saved({**s, "extra": Unsafe()}, p),
        ENTRIES,
        ("not a truckrl checkpoint", "safe load refuses"),
    ),
    "plain pickle": (
        lambda s, p: write_text(p, pickle.dumps({"a": 1})),
        ENTRIES,
        ("not a truckrl checkpoint",),
    ),
    "not a dict": (lambda s, p: saved([1, 2], p), ENTRIES, ("not a truckrl checkpoint",)),
    "other version": (lambda s, p: saved({**s, "version": 1}, p), ENTRIES, ("version",)),
    "config missing": (without("config"), ENTRIES, ("'config' missing",)),
    "ppo missing": (without("ppo"), ENTRIES, ("'ppo' missing",)),
    "rng missing": (without("rng"), ENTRIES, ("'rng' missing",)),
    "negative iteration": (counters(iteration=-1), ENTRIES, ("bad counters", "iteration")),
    "frames not a number": (counters(frames="many"), ENTRIES, ("bad counters", "frames")),
    "fewer frames than iterations": (counters(frames=1), ENTRIES, ("bad counters",)),
    "counters ahead of the optimizer": (
        counters(iteration=3, frames=3 * BATCH),
        ("train",),
        ("bad counters", "optimizer took 8 steps"),
    ),
    "config not yaml": (
        lambda s, p: saved({**s, "config": "a: [1, 2\n"}, p),
        ENTRIES,
        ("saved config is not YAML",),
    ),
    "config value invalid": (
        lambda s, p: saved(with_config(s, env__dt=-1.0), p),
        ENTRIES,
        ("saved config", "env.dt"),
    ),
    "weights do not fit the config": (
        lambda s, p: saved(with_config(s, model__fusion_dim=32), p),
        ENTRIES,
        ("weights do not fit",),
    ),
    "beam count metadata differs": (  # the good run has the default 32 beams
        lambda s, p: saved({**s, "num_beams": 48}, p),
        ENTRIES,
        ("48", "LiDAR beams"),
    ),
    "optimizer of another model": (
        lambda s, p: saved(other_optimizer(s), p),
        ("train",),
        ("optimizer state does not fit",),
    ),
    "run dir without checkpoint": (
        lambda s, p: (p.parent / "empty-run").mkdir() or p.parent / "empty-run",
        ENTRIES,
        ("no checkpoint in run dir",),
    ),
    "missing file": (lambda s, p: p.parent / "nope.pt", ENTRIES, ("not found", "nope.pt")),
}

ROWS = [(name, entry) for name, (_, entries, _) in CHECKPOINTS.items() for entry in entries]


@functools.cache
def base_config():
    return tiny_config()


def through(entry: str, path: Path, job_dir: Path) -> None:
    """What ``train resume=`` / ``evaluate checkpoint=`` / ``play checkpoint=`` run with a
    checkpoint, after Hydra's composition (the table's rows skip it: it costs ~1 s a row; the
    full command lines are checked below)."""
    if entry == "train":
        from truckrl.rl.session import prepare_argv
        from truckrl.train import run

        prepare_argv([f"resume={path}"])
        run(dataclasses.replace(base_config(), resume=str(path)), job_dir, explicit_dir=False)
    elif entry == "evaluate":
        from truckrl.rl.policy import load_policy

        load_policy(path)
    else:
        from truckrl.config.schemas import PlayConfig
        from truckrl.play import build_runner

        build_runner(PlayConfig(checkpoint=str(path), headless=True))


@pytest.mark.parametrize(("name", "entry"), ROWS)
def test_bad_checkpoint_is_one_line(name, entry, good, tmp_path, capsys):
    make, _, fragments = CHECKPOINTS[name]
    path = make(copy.deepcopy({k: v for k, v in good.items() if k != "path"}), tmp_path / "x.pt")
    before = sorted(os.listdir(tmp_path))
    code = 0
    capsys.readouterr()
    try:
        with one_line_errors(in_task=True):
            through(entry, path, tmp_path / "job")
    except SystemExit as e:
        code = e.code
    captured = capsys.readouterr()
    r = Result(code, captured.out, captured.err)
    print(f"\n[{name} / {entry}] " + assert_one_line_error(r, *fragments))
    assert sorted(os.listdir(tmp_path)) in (before, sorted([*before, "job"]))
    assert not [p for p in (tmp_path / "job").rglob("*") if p.is_file()]  # nothing written


@pytest.mark.parametrize("entry", ENTRIES)
@pytest.mark.parametrize("name", ["yaml text file", "weights do not fit the config"])
def test_bad_checkpoint_on_the_command_line(name, entry, good, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make, _, fragments = CHECKPOINTS[name]
    path = make(copy.deepcopy({k: v for k, v in good.items() if k != "path"}), tmp_path / "x.pt")
    r = run_main(capsys, entry, *ARGS[entry](path))
    assert_one_line_error(r, *fragments)
    assert sorted(os.listdir(tmp_path)) == ["x.pt"]  # no outputs/ or eval files left behind


ARGS = {
    "train": lambda c: [*TINY, f"resume={c}"],
    "evaluate": lambda c: [f"checkpoint={c}", "episodes=2"],
    "play": lambda c: [f"checkpoint={c}", "headless=true", "max_frames=2"],
}

#: (entry, override, fragments): Hydra's composition errors and the schemas' checks alike.
CONFIGS = [
    ("train", "env.lidar.num_beams=sixteen", ("env.lidar.num_beams", "whole number", "[1, 4096]")),
    ("train", "env.vehicle=default", ("env.vehicle", "group of fields")),
    ("train", "env.lidr.num_beams=8", ("unknown field env.lidr", "did you mean env.lidar")),
    ("train", "nosuch=1", ("unknown field nosuch",)),
    ("train", "task=nosuch", ("task=nosuch", "intersection")),
    ("train", "experiment=fastest", ("experiment=fastest", "fast", "paper")),
    ("train", "+launch=nope", ("launch=nope", "slurm")),
    ("train", "seed=1.5", ("seed", "whole number")),
    ("train", "log.progress_bar=maybe", ("log.progress_bar", "true or false")),
    ("train", "env.task.scene.road_width=[a,b]", ("env.task.scene.road_width", "[min, max]")),
    ("train", "env.task.scene.road_width=[18,12]", ("env.task.scene.road_width", "min")),
    ("train", "ppo.lr=abc", ("ppo.lr", "a number")),
    ("train", "ppo.lr=-1", ("ppo.lr", "range")),
    ("train", "ppo.num_minibatches=7", ("ppo.num_minibatches",)),
    ("train", "curriculum.mode=3", ("curriculum.mode", "ema")),
    ("train", "max_minutes=null", ("total_frames", "max_minutes")),
    ("train", "device=gpu0", ("device", "torch device")),
    ("train", "x=(", ("cannot parse the override",)),
    ("evaluate", "episodes=abc", ("episodes", "whole number")),
    ("evaluate", "difficulty=-1", ("difficulty",)),
    ("evaluate", "threads=0", ("threads", "1")),
    ("evaluate", "episodes=5", ("checkpoint is required",)),
    ("play", "view.size_px=5", ("view.size_px",)),
    ("play", "on_done=later", ("on_done",)),
    ("play", "headless=maybe", ("headless", "true or false")),
    ("play", "control=fast", ("control=fast", "accel_rate")),
]
SCHEMAS = {"train": "TrainConfig", "evaluate": "EvaluateConfig", "play": "PlayConfig"}


@pytest.mark.parametrize(("entry", "override", "fragments"), CONFIGS)
def test_bad_config_value_is_one_line(entry, override, fragments):
    """The message the command line prints (composition through Hydra's compose API; the full
    command line for a few rows below)."""
    import truckrl.cli as cli
    import truckrl.config.schemas

    schema = getattr(truckrl.config.schemas, SCHEMAS[entry])
    cli._SCHEMA[:] = [schema]
    try:
        cli.to_config(schema, compose_config(entry, override))
    except ConfigError as e:
        line = str(e)
    except Exception as e:  # Hydra's and OmegaConf's composition errors
        line = cli.describe_hydra_error(e)
    else:
        pytest.fail(f"{override} accepted")
    finally:
        cli._SCHEMA.clear()
    assert line and "\n" not in line, line
    for f in fragments:
        assert f in line, (f, line)
    print(f"\n[{entry} {override}] error: {line}")


@pytest.mark.parametrize(
    ("entry", "override", "fragments"),
    [row for row in CONFIGS if row[1] in ("env.lidar.num_beams=sixteen", "env.vehicle=default",
                                          "ppo.num_minibatches=7", "x=(", "episodes=abc",
                                          "control=fast")],
)  # fmt: skip
def test_bad_config_on_the_command_line(entry, override, fragments, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = run_main(capsys, entry, override)
    assert_one_line_error(r, *fragments)
    assert os.listdir(tmp_path) == []  # no outputs/DATE/TIME for a rejected config


def test_rejected_sweep_leaves_no_sweep_dir(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = run_main(capsys, "train", "-m", "ppo.lr=1e-4,abc")
    assert_one_line_error(r, "ppo.lr", "a number")
    assert os.listdir(tmp_path) == []  # not even outputs/multirun/DATE/TIME/multirun.yaml
