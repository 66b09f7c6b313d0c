"""Run dirs: resuming an older checkpoint branches (newer state is never overwritten), a run dir
with a checkpoint is never reused silently, ``resume=auto``, stale temp files, file modes, and
file-system faults (one line, exit 2, checked before any work where possible)."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
import torch
import yaml

from tests.reliability.harness import (
    BATCH,
    TINY,
    assert_consistent,
    assert_one_line_error,
    run_main,
    run_session,
)
from truckrl.rl import checkpoint as ckpt
from truckrl.rl.session import override_paths, prepare_argv, resumed_config

ROOT_USER = os.geteuid() == 0  # root ignores permission bits


@pytest.fixture(scope="module")
def old_run(tmp_path_factory) -> Path:
    """A run of 4 iterations keeping iter_000002.pt and iter_000004.pt."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # module scope: before conftest's per-test setting
    try:
        run = tmp_path_factory.mktemp("old")
        run_session(
            run, f"total_frames={4 * BATCH}", "checkpoint.interval=1", "checkpoint.keep_every=2"
        )
    finally:
        torch.set_num_threads(threads)
    return run


def snapshot(run: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(run)): (p.stat().st_size, p.stat().st_mtime_ns) for p in run.rglob("*")
    }


def test_resuming_an_older_checkpoint_branches_into_a_new_run_dir(old_run, tmp_path):
    before = snapshot(old_run)
    old = old_run / "checkpoints" / "iter_000002.pt"
    assert prepare_argv([f"resume={old}"]) == [f"resume={old}"]  # no continuing in the old dir
    branch = tmp_path / "branch"
    run_session(branch, f"total_frames={3 * BATCH}", f"resume={old}")
    assert snapshot(old_run) == before  # the newer state of the parent is untouched
    assert assert_consistent(branch)["iteration"] == 3
    parent = json.loads((branch / "parent.json").read_text())
    assert parent["run_dir"] == str(old_run) and parent["iteration"] == 2
    assert parent["checkpoint"] == str(old)


def test_resuming_the_newest_checkpoint_continues_in_its_run_dir(old_run, tmp_path):
    newest = old_run / "checkpoints" / "iter_000004.pt"  # same iteration as last.pt
    argv = prepare_argv([f"resume={newest}"])
    assert argv[1] == f"hydra.run.dir={old_run}" and "hydra.output_subdir=null" in argv
    elsewhere = tmp_path / "elsewhere"  # another dir named explicitly: a branch, not a takeover
    run_session(elsewhere, f"total_frames={5 * BATCH}", f"resume={newest}")
    parent = json.loads((elsewhere / "parent.json").read_text())
    assert parent["run_dir"] == str(old_run) and parent["iteration"] == 4
    assert parent["checkpoint"] == str(newest)
    assert assert_consistent(elsewhere)["iteration"] == 5  # one iteration on from the parent
    assert ckpt.load_checkpoint(old_run)["counters"]["iteration"] == 4


def test_starting_in_a_run_dir_with_a_checkpoint_is_refused(old_run, capsys):
    before = snapshot(old_run)
    r = run_main(capsys, "train", *TINY, f"hydra.run.dir={old_run}")
    assert_one_line_error(r, str(old_run), f"resume={old_run}", "overwrite=true")
    assert snapshot(old_run) == before  # Hydra never wrote into it


def test_overwrite_starts_anew_and_resume_auto_continues(tmp_path):
    run_session(tmp_path, f"total_frames={2 * BATCH}")
    run_session(tmp_path, f"total_frames={1 * BATCH}", "overwrite=true")
    assert assert_consistent(tmp_path)["iteration"] == 1
    run_session(tmp_path, f"total_frames={2 * BATCH}", "resume=auto")
    assert assert_consistent(tmp_path)["iteration"] == 2
    fresh = tmp_path / "fresh"
    run_session(fresh, f"total_frames={1 * BATCH}", "resume=auto")  # nothing there: a new run
    assert assert_consistent(fresh)["iteration"] == 1


def test_stale_temp_files_are_cleaned_and_modes_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        run_session(tmp_path, f"total_frames={BATCH}")
        stale = tmp_path / "checkpoints" / ".last.pt.abc123.tmp"
        stale.write_bytes(b"half a checkpoint")
        run_session(tmp_path, f"total_frames={2 * BATCH}", f"resume={tmp_path}")
    finally:
        os.umask(old)
    assert not stale.exists()
    mode = (tmp_path / "checkpoints" / "last.pt").stat().st_mode & 0o777
    assert mode == (tmp_path / "source.json").stat().st_mode & 0o777 == 0o644


# ---------------------------------------------------------------------------------- faults
def a_file(tmp_path: Path) -> Path:
    f = tmp_path / "plain-file"
    f.write_text("not a dir")
    return f


TRAIN_FAULTS = {
    "run dir is a file": (lambda t: a_file(t), "is a file"),
    "run dir under a file": (lambda t: a_file(t) / "run", "is a file"),
    "run dir in /proc": (lambda t: Path("/proc/truckrl-test/run"), "not writable"),
}


@pytest.mark.parametrize("case", sorted(TRAIN_FAULTS))
def test_unusable_run_dir_is_one_line(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make, fragment = TRAIN_FAULTS[case]
    path = make(tmp_path)
    r = run_main(capsys, "train", *TINY, f"hydra.run.dir={path}")
    assert_one_line_error(r, str(path), fragment)
    assert not (tmp_path / "outputs").exists()


def test_checkpoint_dir_that_is_a_file_is_one_line(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoints").write_text("oops")
    r = run_main(capsys, "train", *TINY, f"hydra.run.dir={run}")
    assert_one_line_error(r, "checkpoint dir", "is a file")


def test_unwritable_checkpoint_dir_is_found_at_start(tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    if ROOT_USER:  # simulate what chmod would do for another user
        import tempfile

        real = tempfile.TemporaryFile

        def refuse(*args, dir=None, **kwargs):  # noqa: A002
            if dir is not None and Path(dir).name == "checkpoints":
                raise PermissionError(errno.EACCES, "Permission denied")
            return real(*args, dir=dir, **kwargs)

        monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    else:
        (run / "checkpoints").chmod(0o500)
    try:
        r = run_main(capsys, "train", *TINY, f"hydra.run.dir={run}")
    finally:
        (run / "checkpoints").chmod(0o700)
    assert_one_line_error(r, "checkpoint dir", "not writable", "Permission denied")
    assert not list((run / "checkpoints").iterdir())


def test_full_disk_at_a_checkpoint_write_is_one_line_and_keeps_the_last_one(
    tmp_path, capsys, monkeypatch
):
    saves = {"n": 0}
    real = torch.save

    def save(obj, f, *args, **kwargs):
        saves["n"] += 1
        if saves["n"] == 2:
            f.write(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", save)
    run = tmp_path / "run"
    args = [*TINY, "total_frames=1000000", "checkpoint.interval=1", f"hydra.run.dir={run}"]
    r = run_main(capsys, "train", *args)
    assert_one_line_error(r, "cannot write checkpoint", "No space left on device", "intact")
    assert assert_consistent(run)["iteration"] == 1  # the first save survives whole
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["last.pt"]


PLAY_FAULTS = {
    "record under a file": (lambda t: ("record", a_file(t) / "x.mp4"), "is a file"),
    "record is a dir": (lambda t: ("record", t), "is a directory"),
    "record in /proc": (lambda t: ("record", Path("/proc/truckrl-test/x.mp4")), "not writable"),
    "strip under a file": (lambda t: ("strip", a_file(t) / "x.png"), "is a file"),
}


@pytest.mark.parametrize("case", sorted(PLAY_FAULTS))
def test_unwritable_play_output_is_one_line(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    field, path = PLAY_FAULTS[case][0](tmp_path)
    r = run_main(capsys, "play", "headless=true", "max_frames=3", f"{field}={path}")
    assert_one_line_error(r, f"{field}={path}", PLAY_FAULTS[case][1])
    assert sorted(os.listdir(tmp_path)) == (["plain-file"] if "file" in case else [])


def test_a_requeued_sweep_job_resumes_its_own_run_dir(tmp_path, capsys, monkeypatch):
    """What a requeued SLURM job does (conf/launch/slurm.yaml sets resume: auto): the same
    sweep job, run again in the same job dir, continues its checkpoint."""
    monkeypatch.chdir(tmp_path)
    sweep = tmp_path / "sweep"
    args = ["-m", *TINY, "resume=auto", f"hydra.sweep.dir={sweep}"]
    assert run_main(capsys, "train", *args, f"total_frames={BATCH}").code == 0
    assert run_main(capsys, "train", *args, f"total_frames={2 * BATCH}").code == 0
    assert assert_consistent(sweep / "0")["iteration"] == 2
    assert "resumed" in (sweep / "0" / "train.log").read_text()


# ------------------------------------------------------------------ what a resume keeps
def test_resumed_config_takes_from_the_command_line_only_what_it_sets():
    """Hand-built configs: a key of ``keep`` comes from the command line at the paths it names
    (and ``resume`` / ``overwrite`` always), the rest from the checkpoint; without the paths
    (a caller with no command line) every key of ``keep`` comes from the command line."""
    import logging

    saved = {"total_frames": 100, "max_minutes": None, "log": {"a": 1, "b": 2}, "ppo": {"lr": 1},
             "resume": None, "overwrite": True}  # fmt: skip
    current = {"total_frames": None, "max_minutes": 60, "log": {"a": 9, "b": 8}, "ppo": {"lr": 5},
               "resume": "R", "overwrite": False}  # fmt: skip
    keep = ("total_frames", "max_minutes", "log", "resume", "overwrite")
    log = logging.getLogger("test")
    given = ("resume", "log.b", "ppo.lr")
    assert resumed_config(saved, current, keep, log, given) == {
        "total_frames": 100, "max_minutes": None, "log": {"a": 1, "b": 8}, "ppo": {"lr": 1},
        "resume": "R", "overwrite": False}  # fmt: skip
    assert saved["log"] == {"a": 1, "b": 2}  # the checkpoint's config is not written to
    assert resumed_config(saved, current, keep, log) == {
        "total_frames": None, "max_minutes": 60, "log": {"a": 9, "b": 8}, "ppo": {"lr": 1},
        "resume": "R", "overwrite": False}  # fmt: skip
    assert override_paths(["+log.backend_args.x=1", "~demos", "resume=a=b", "seed=3"]) == (
        "log.backend_args.x", "resume", "seed")  # fmt: skip


def test_a_resume_keeps_the_frame_budget_and_log_values_its_command_line_does_not_set(
    tmp_path, capsys
):
    """A frame-budgeted run resumed with ``truckrl train resume=RUN`` stops at its own budget
    (the default ``max_minutes`` must not replace it) and keeps its held-out check cadence."""
    run = tmp_path / "run"
    evals = "log.eval_interval_frames=1000000"
    r = run_main(capsys, "train", *TINY, f"total_frames={2 * BATCH}", evals, f"hydra.run.dir={run}")
    assert r.code == 0, r.err
    r = run_main(capsys, "train", *TINY, "max_minutes=0.05", f"resume={run}")
    assert r.code == 0, r.err
    assert "stopped: total_frames reached" in r.out + r.err
    state = ckpt.load_checkpoint(run)
    assert state["counters"]["frames"] == 2 * BATCH  # trained no further
    cfg = yaml.safe_load(state["config"])  # the resumed session's config, saved at its stop
    assert (cfg["total_frames"], cfg["max_minutes"]) == (2 * BATCH, 0.05)
    assert cfg["log"]["eval_interval_frames"] == 1_000_000 and cfg["log"]["progress_bar"] is False
    # a resume may unset the budget only where the run then still stops: one line, exit 2
    unset = ["max_minutes=null", "total_frames=null", "stop_difficulty=0"]  # (no hang if not)
    r = run_main(capsys, "train", *TINY, *unset, f"resume={run}")
    assert r.code == 2 and r.err.strip().endswith("(both are null: the run might never stop)")
    assert ckpt.load_checkpoint(run)["counters"]["frames"] == 2 * BATCH
