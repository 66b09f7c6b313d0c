"""``python -m truckrl.bench train``: a tiny run's JSON record, and one-line option errors."""

import json

import pytest

from truckrl.bench.__main__ import main
from truckrl.bench.train import PARTS

#: Two iterations of 8 trucks x 8 steps, one epoch of two minibatches, eager env.
TINY = [
    "collector.num_envs=8",
    "collector.steps_per_env=8",
    "ppo.num_minibatches=2",
    "ppo.num_epochs=1",
    "env.compile=false",
    "ppo.compile=false",
    "collector.compile_policy=false",
]


def test_tiny_run_writes_the_parts_of_each_iteration(tmp_path, capsys):
    out = tmp_path / "record.json"
    main(["train", *TINY, "iterations=2", "warmup=0", "profile=3", f"out={out}"])
    stdout = capsys.readouterr().out
    assert "frames/s" in stdout and "bench train took" in stdout
    record = json.loads(out.read_text())
    assert record["benchmark"] == "train"
    assert record["config"]["frames_per_batch"] == 64 and record["config"]["env_compile"] is False
    assert record["args"]["iterations"] == 2 and record["config"]["overrides"] == TINY
    assert record["summary"]["torch_threads"] >= 1
    assert len(record["profile"]) == 3 and record["profile"][0]["self_cpu_ms"] > 0
    assert [r["iteration"] for r in record["rows"]] == [1, 2, "profiled"]
    rows = record["rows"][:2]
    for r in rows:
        assert set(r) >= {"frames/s", "total_s", "other_s", *PARTS}
        assert r["frames"] == 64
        assert all(r[p] >= 0.0 for p in PARTS)
        assert sum(r[p] for p in PARTS) <= r["total_s"] * (1 + 1e-9)
        assert r["frames/s"] == pytest.approx(64 / r["total_s"])
        assert r["loss_forward_s"] > 0 and r["backward_s"] > 0 and r["collect_s"] > 0
        assert r["log_s"] > 0  # log.interval=1: the real iteration writes its scalars


def test_the_timed_iteration_is_the_trainers(tmp_path, capsys, monkeypatch):
    """What is timed is :meth:`Trainer.iterate`, the training loop's own step."""
    from truckrl.rl.trainer import Trainer

    calls = []
    original = Trainer.iterate

    def counted(self, timings=None):
        calls.append(timings is not None)
        return original(self, timings)

    monkeypatch.setattr(Trainer, "iterate", counted)
    main(["train", *TINY, "iterations=2", "warmup=1", f"out={tmp_path}"])
    capsys.readouterr()
    assert calls == [True, True, True]
    assert len(list(tmp_path.glob("train-*.json"))) == 1  # out= a folder: a stamped name in it


def test_the_cloning_term_is_timed_on_stand_in_samples(tmp_path, capsys):
    """``demos.bc_coeff > 0`` (experiment=demos): the update runs the cloning term, on stand-in
    observations and actions, and the record says so; without it there is none."""
    for coeff in (1.0, 0.0):
        out = tmp_path / f"bc{coeff}.json"
        main(["train", *TINY, f"demos.bc_coeff={coeff}", "iterations=1", "warmup=0", f"out={out}"])
        record = json.loads(out.read_text())
        assert record["config"]["bc_coeff"] == coeff
        assert ("loss_bc" in record["rows"][0]) == (coeff > 0)
        assert record["rows"][0].get("loss_bc", 1.0) > 0  # an MSE of random init vs actions
    capsys.readouterr()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["iterations=0"], "error: iterations = 0 is outside the allowed range [1"),
        (["warmup=-1"], "error: warmup = -1 is outside the allowed range [0"),
        (["threads=0"], "error: threads = 0 is outside the allowed range [1"),
        (["profile=-1"], "error: profile = -1 is outside the allowed range [0"),
        (["quick=maybe"], "error: quick = 'maybe' must be true or false"),
        (["nokey"], "error: 'nokey': arguments are KEY=VALUE"),
        (["--iterations", "2"], "error: '--iterations': arguments are KEY=VALUE"),
        (["ppo.num_epochs=0"], "error: ppo.num_epochs"),
        (["collector.no_such_field=1"], "error: "),
    ],
)
def test_bad_options_are_one_line_exit_2(args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and len(err.splitlines()) == 1, err


def test_every_key_has_help_and_the_overrides_are_explained(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    for key in ("iterations", "warmup", "quick", "threads", "out", "profile"):
        line = next(x for x in lines if x.strip().startswith(key + " "))
        assert len(line.strip()) > len(key) + 8, key  # followed by a description
    assert "Hydra override" in out
