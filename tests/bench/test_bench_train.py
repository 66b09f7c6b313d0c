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
    argv = ["train", *TINY[:2], *(f"--override={o}" for o in TINY[2:])]
    main([*argv, "--iterations", "2", "--warmup", "0", "--profile", "3", "--output", str(out)])
    stdout = capsys.readouterr().out
    assert "frames/s" in stdout and "bench train took" in stdout
    record = json.loads(out.read_text())
    assert record["benchmark"] == "train"
    assert record["config"]["frames_per_batch"] == 64 and record["config"]["env_compile"] is False
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


def test_the_cloning_term_is_timed_on_stand_in_samples(tmp_path, capsys):
    """``demos.bc_coeff > 0`` (experiment=demos): the update runs the cloning term, on the first
    batch's observations and actions, and the record says so; without it there is none."""
    for coeff in (1.0, 0.0):
        out = tmp_path / f"bc{coeff}.json"
        argv = ["train", *TINY, f"demos.bc_coeff={coeff}", "--iterations", "1"]
        main([*argv, "--warmup", "0", "--output", str(out)])
        record = json.loads(out.read_text())
        assert record["config"]["bc_coeff"] == coeff
        assert ("loss_bc" in record["rows"][0]) == (coeff > 0)
        assert record["rows"][0].get("loss_bc", 1.0) > 0  # an MSE of random init vs actions
    capsys.readouterr()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--iterations", "0"], "error: --iterations must be >= 1 (got 0)"),
        (["--warmup", "-1"], "error: --warmup must be >= 0 (got -1)"),
        (["--threads", "0"], "error: --threads must be >= 1 (got 0)"),
        (["--profile", "-1"], "error: --profile must be >= 0 (got -1)"),
        (["nokey"], "error: override 'nokey': write KEY=VALUE"),
        (["--override", "ppo.num_epochs=0"], "error: ppo.num_epochs"),
        (["collector.no_such_field=1"], "error: "),
    ],
)
def test_bad_options_are_one_line_exit_2(args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", *args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and len(err.splitlines()) == 1, err


def test_every_option_has_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "--help"])
    assert exc.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    for opt in (
        "--override",
        "--iterations",
        "--warmup",
        "--quick",
        "--threads",
        "--output",
        "--profile",
    ):
        line = next(x for x in lines if x.strip().startswith(opt))
        assert len(line.strip()) > len(opt) + 8, opt  # followed by a description
