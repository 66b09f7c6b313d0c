"""What the entry points show: help texts, the progress bar, the last lines of a run, the final
HPARAMS values, log files with content, no stray output dirs, and the start-up time (printed)."""

from __future__ import annotations

import ast
import logging
import os
import statistics
import subprocess
import sys
import time

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from tests.conftest import ROOT
from tests.reliability.harness import BATCH, ENV, TINY, run_main, run_session
from truckrl.rl.checkpoint import load_checkpoint
from truckrl.rl.progress import Progress, stop_lines


@pytest.mark.parametrize(
    ("entry", "must", "must_not"),
    [
        ("train", ["stop_difficulty=null", "demos.episodes=600", "demos.bc_coeff=1", "max_minutes=60", "total_frames=null", "experiment=",
                   "control=", "task=", "device=", "seed=", "resume=", "Examples"], []),
        ("evaluate", ["checkpoint=", "difficulty=", "episodes=", "seed=", "threads=null", "Examples"],
         ["ppo."]),
        ("play", ["checkpoint=", "headless=true", "record=", "difficulty=", "Keys", "Examples"],
         ["ppo.", "collector.", "hydra", "max_minutes"]),
    ],
)  # fmt: skip
def test_help_says_what_matters(entry, must, must_not, capsys):
    r = run_main(capsys, f"{entry}", "--help")
    assert r.code == 0 and r.err == ""
    for text in must:
        assert text in r.out, text
    for text in must_not:
        assert text not in r.out, text
    assert len(r.out.splitlines()) < 50  # not Hydra's 197-line config dump
    assert "Powered by Hydra" not in r.out


def test_progress_bar_measures_the_binding_criterion():
    p = Progress(total_frames=None, max_minutes=60, stop_difficulty=6.0, enabled=True)
    p.update(5_000_000, 12.5, 2.5, 0.43, 14_200)
    assert p.bar.bar_format.startswith("12.5/60 min |")
    assert "difficulty 2.5/6, success EMA 0.43, 14.2k frames/s" in p.bar.bar_format
    assert p.bar.n == 208
    p = Progress(total_frames=10_000_000, max_minutes=60, stop_difficulty=None, enabled=True)
    p.update(5_000_000, 1.0, 1.0, 0.1, 90_000)  # frames will end it first
    assert p.bar.bar_format.startswith("5.0M/10.0M frames |") and p.bar.n == 500
    p.close()


@pytest.mark.parametrize(
    ("overrides", "reason"),
    [
        ([f"total_frames={2 * BATCH}"], "total_frames reached"),
        (["max_minutes=0.0001", "total_frames=null"], "max_minutes reached"),
        (["curriculum=none", "curriculum.start_difficulty=1.5", "stop_difficulty=1.5"],
         "stop_difficulty reached"),
    ],
)  # fmt: skip
def test_last_lines_say_why_where_and_what_next(overrides, reason, tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="truckrl.train")
    run_session(tmp_path, *overrides)
    lines = [r.getMessage() for r in caplog.records]
    i = next(i for i, ln in enumerate(lines) if ln.startswith("stopped"))
    assert lines[i].startswith(f"stopped: {reason} at iteration")
    assert lines[i + 1] == f"run dir: {tmp_path} (checkpoint {tmp_path}/checkpoints/last.pt)"
    assert lines[i + 2] == f"evaluate: truckrl eval checkpoint={tmp_path}"
    assert lines[i + 3] == f"play: truckrl play checkpoint={tmp_path}"
    assert lines[i + 4] == f"tensorboard: tensorboard --logdir {tmp_path}/tb"
    assert load_checkpoint(tmp_path)  # the checkpoint the lines name exists


def test_signal_stop_line_is_one_line(monkeypatch):
    monkeypatch.chdir(ROOT)  # paths are shown relative to the working dir
    lines = stop_lines("SIGTERM", ROOT / "outputs" / "x", 3, 768, 0.2, 1.5)
    assert lines == [
        "stopped by SIGTERM at iteration 3, 768 frames, 0.2 min, difficulty 1.5; checkpoint "
        "outputs/x/checkpoints/last.pt; resume: truckrl train resume=outputs/x"
    ]


def test_hparams_table_gets_the_final_values(tmp_path):
    run_session(tmp_path, f"total_frames={2 * BATCH}", "curriculum=none",
                "curriculum.start_difficulty=2.5")  # fmt: skip
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    final = load_checkpoint(tmp_path)["curriculum"]
    assert acc.Scalars("hparam/difficulty")[-1].value == pytest.approx(2.5)
    assert acc.Scalars("hparam/success_ema")[-1].value == pytest.approx(final["ema"])
    assert acc.Scalars("hparam/difficulty")[-1].step == 2 * BATCH  # written at the end


def test_train_log_has_the_run_and_nothing_strays(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "run"
    r = run_main(capsys, "train", *TINY, f"total_frames={BATCH}", f"hydra.run.dir={run}")
    assert r.code == 0, r.err
    log = (run / "train.log").read_text()
    assert "run dir:" in log and "stopped: total_frames reached" in log
    r = run_main(capsys, "train", *TINY, f"total_frames={2 * BATCH}", f"resume={run}")
    assert r.code == 0, r.err
    assert "resumed" in (run / "train.log").read_text()  # the same log, a second session
    r = run_main(capsys, "play", "headless=true", "max_frames=3", "view.size_px=64")
    assert r.code == 0, r.err
    out = tmp_path / "e.json"
    r = run_main(capsys, "evaluate", f"checkpoint={run}", "episodes=2", f"output={out}")
    assert r.code == 0, r.err
    assert sorted(os.listdir(tmp_path)) == ["e.json", "run"]  # no outputs/, play.log, eval dirs


def median_seconds(*args: str, runs: int = 3) -> float:
    times = []
    for _ in range(runs):
        t0 = time.monotonic()
        subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, env=ENV)
        times.append(time.monotonic() - t0)
    return statistics.median(times)


@pytest.mark.e2e
def test_start_up_time_of_help():
    help_s = median_seconds("truckrl.train", "--help")
    print(f"\nstart-up: train --help {help_s:.2f} s (median of 3)")
    assert help_s < 3.0  # no torch: measured 0.1 s


def heavy_modules_after(code: str) -> set[str]:
    """Top-level packages among torch, tensordict and torchrl that ``code`` left imported."""
    probe = f"{code}\nimport sys\nprint(sorted({{m.split('.')[0] for m in sys.modules}}))"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, env=ENV
    )
    assert out.returncode == 0, out.stderr
    return set(ast.literal_eval(out.stdout.strip().splitlines()[-1])) & {
        "torch",
        "tensordict",
        "torchrl",
    }


@pytest.mark.parametrize("entry", ["train", "evaluate", "play", "export"])
def test_help_imports_no_torch(entry):
    code = (
        f"import runpy, sys\nsys.argv = ['truckrl.{entry}', '--help']\n"
        f"try:\n    runpy.run_module('truckrl.{entry}', run_name='__main__')\n"
        "except SystemExit as e:\n    assert e.code == 0, e.code"
    )
    assert heavy_modules_after(code) == set()


def test_config_schemas_import_no_tensordict_or_torchrl():
    # A rejected value is reported after composing and validating these schemas: keeping
    # tensordict (which loads torch._dynamo) and torchrl out of that path halves start-up.
    assert heavy_modules_after("import truckrl.config.schemas") == {"torch"}
