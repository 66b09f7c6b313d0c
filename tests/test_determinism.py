"""Same seed, same threads, same result: two ``truckrl train seed=S threads=T`` runs write the
same checkpoints bit for bit and log the same scalars, and resuming the same checkpoint twice
does too.

What a run draws from is seeded from ``seed`` alone: the global generators
(``truckrl.cli.seed_everything``: network init, action noise, minibatch order), the training
envs (:func:`truckrl.rl.collection.env_seed`), the held-out scenes (a fixed seed) and, on
resume, the generator states saved in the checkpoint. What is not: the wall clock, which decides
when ``log.eval_interval_min`` runs a held-out check (and so which checkpoint becomes best.pt;
``log.eval_interval_frames`` counts frames instead, as these runs do) and the ``perf/*``
scalars (:data:`WALL_CLOCK`); and the float rounding of a reduction, which depends on the
thread count (``threads``: a config value, so the same config reruns the same arithmetic; on a
CPU at several threads only because training fixes the compiled backward's summation order,
:func:`truckrl.rl.trainer.fixed_order_gradients`).

Runs are tiny and eager, in subprocesses (each with fresh global state, as users run them).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import TINY_BATCH, TINY_TRAIN, compose_config, run_cli
from truckrl.cli import to_config
from truckrl.config.schemas import TrainConfig
from truckrl.rl.checkpoint import load_checkpoint

pytestmark = pytest.mark.e2e

#: Logged scalars that measure the wall clock (frames/s and seconds), left out of the comparison.
WALL_CLOCK = frozenset({"perf/fps", "perf/fps_collect", "perf/collect_s", "perf/learn_s"})
#: Checkpoint entries that differ between identical runs: the session's wall clock [s] and the
#: path it was loaded from.
UNSHARED = frozenset({("counters", "wall_time_s"), ("path",)})
#: Three iterations with a held-out check after the second (best.pt) and a seed of its own.
RUN = [*TINY_TRAIN, "seed=7", "threads=1", "checkpoint.interval=1"]
RUN += [f"log.eval_interval_frames={2 * TINY_BATCH}", "log.eval_episodes=4", "env.max_steps=20"]


def train(run_dir: Path, *args: str) -> None:
    proc = run_cli("train", *RUN, *args, f"hydra.run.dir={run_dir}")
    assert proc.returncode == 0, proc.stdout + proc.stderr


def leaves(x: Any, key: tuple = ()) -> dict[tuple, Any]:
    """Every leaf of a nested checkpoint (dicts, lists, tensors) by its key path."""
    if isinstance(x, dict):
        return {k: v for name, item in x.items() for k, v in leaves(item, (*key, name)).items()}
    if isinstance(x, list | tuple):
        return {k: v for i, item in enumerate(x) for k, v in leaves(item, (*key, i)).items()}
    return {key: x}


def checkpoint_differences(a: Path, b: Path) -> list[str]:
    """The leaves of two checkpoint files that differ (tensors bit for bit: dtype, shape and
    bytes), but for :data:`UNSHARED`."""
    la, lb = leaves(load_checkpoint(a)), leaves(load_checkpoint(b))
    out = ["/".join(map(str, key)) for key in set(la) ^ set(lb)]  # in one of them only
    for key, va in la.items():
        if key in UNSHARED or key not in lb:
            continue
        vb = lb[key]
        if isinstance(va, torch.Tensor):
            same = (
                isinstance(vb, torch.Tensor)
                and va.dtype == vb.dtype
                and va.shape == vb.shape
                and va.numpy().tobytes() == vb.numpy().tobytes()
            )
        else:  # NaN (a metric with no episode yet) equals NaN here
            same = va == vb or (isinstance(va, float) and va != va and vb != vb)
        if not same:
            out.append("/".join(map(str, key)))
    return out


def scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every logged scalar but :data:`WALL_CLOCK`: ``{tag: [(frames, value), ...]}``."""
    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    tags = sorted(set(acc.Tags()["scalars"]) - WALL_CLOCK)
    return {t: [(e.step, e.value) for e in acc.Scalars(t)] for t in tags}


def assert_same_run(a: Path, b: Path) -> None:
    """Runs ``a`` and ``b`` wrote the same checkpoints (bit for bit) and scalars (exactly)."""
    names = sorted(p.name for p in (a / "checkpoints").glob("*.pt"))
    assert names == sorted(p.name for p in (b / "checkpoints").glob("*.pt"))
    for name in names:
        diff = checkpoint_differences(a / "checkpoints" / name, b / "checkpoints" / name)
        assert not diff, f"{name} differs in {len(diff)} entries: {', '.join(diff[:8])} ..."
    sa, sb = scalars(a), scalars(b)
    assert sorted(sa) == sorted(sb), set(sa) ^ set(sb)
    diff = [tag for tag in sa if sa[tag] != sb[tag]]
    assert not diff, f"logged scalars differ: {diff}"


@pytest.fixture(scope="module")
def twins(tmp_path_factory) -> tuple[Path, Path]:
    """Two runs of the same command line (:data:`RUN`, three iterations) in two run dirs."""
    a, b = tmp_path_factory.mktemp("a"), tmp_path_factory.mktemp("b")
    for d in (a, b):
        train(d, f"total_frames={3 * TINY_BATCH}")
    return a, b


def test_the_same_seed_and_threads_give_the_same_run(twins):
    a, b = twins
    assert load_checkpoint(a)["counters"]["iteration"] == 3
    assert load_checkpoint(a / "checkpoints" / "best.pt")["heldout"]["frames"] == 2 * TINY_BATCH
    assert "train/kl" in scalars(a) and "eval/success_rate" in scalars(a)
    assert_same_run(a, b)
    # the comparison sees a difference where there is one: iteration 3 against iteration 2
    diff = checkpoint_differences(a / "checkpoints" / "last.pt", a / "checkpoints" / "best.pt")
    assert "model/module.1.module.0.module.mean.weight" in diff and "counters/frames" in diff


def test_resuming_the_same_checkpoint_twice_gives_the_same_run(twins, tmp_path):
    """One twin's last.pt (iteration 3) continued twice for two iterations, each time into a new
    run dir (a branch: ``resume=<file> hydra.run.dir=<new>``), on two threads (a resume takes
    ``threads`` from its command line): a reduction split over threads is split the same way
    each time, so this is bit-exact too."""
    last = twins[0] / "checkpoints" / "last.pt"
    c, d = tmp_path / "c", tmp_path / "d"
    for run in (c, d):
        train(run, f"resume={last}", f"total_frames={5 * TINY_BATCH}", "threads=2")
    assert load_checkpoint(c)["counters"]["iteration"] == 5
    assert_same_run(c, d)


def test_threads_are_set_before_the_run_builds_anything(monkeypatch, tmp_path):
    """``threads=3``: torch runs on 3 threads by the time the trainer is made (what the run dir
    line of the log then reports); null leaves torch's own count."""
    import truckrl.rl.trainer
    from truckrl.train import train as train_session

    seen = []

    class Built(Exception):
        pass

    def trainer(*args, **kwargs):
        seen.append(torch.get_num_threads())
        raise Built

    monkeypatch.setattr(truckrl.rl.trainer, "Trainer", trainer)
    before = torch.get_num_threads()
    try:
        for threads in ("threads=3", "threads=null"):
            tc = to_config(TrainConfig, compose_config("train", *TINY_TRAIN, threads))
            with pytest.raises(Built):
                train_session(tc, tmp_path)
    finally:
        torch.set_num_threads(before)
    assert seen == [3, 3]


@pytest.mark.slow
def test_another_thread_count_moves_the_run_by_rounding_only(twins, tmp_path):
    """Not bit-exact: the same run on 2 threads instead of 1 sums some reductions in another
    order. Over these three iterations the weights move by float32 rounding (measured: 3e-8,
    against weights up to 1.0) and the losses by 5e-7 of 11; the bound is 1e-6. Over a long
    run the difference can grow until an episode ends otherwise, and then the runs part."""
    train(tmp_path, f"total_frames={3 * TINY_BATCH}", "threads=2")
    one, two = load_checkpoint(twins[0])["model"], load_checkpoint(tmp_path)["model"]
    moved = max((one[k] - two[k]).abs().max().item() for k in one)
    assert moved <= 1e-6, moved
    s1, s2 = scalars(twins[0]), scalars(tmp_path)
    for tag in ("loss/critic", "loss/objective", "train/kl"):
        assert [s for s, _ in s1[tag]] == [s for s, _ in s2[tag]]
        for (_, v1), (_, v2) in zip(s1[tag], s2[tag], strict=True):
            assert v1 == pytest.approx(v2, rel=1e-6, abs=1e-6), tag
