"""The ``truckrl`` command (:mod:`truckrl.__main__`): a short help without torch, every
subcommand reachable, an unknown one refused in one line with exit code 2."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from tests.conftest import ROOT
from truckrl.__main__ import HYDRA, PLAIN, TOOLS


def truckrl(*args: str, code: str = "") -> subprocess.CompletedProcess:
    """``python -m truckrl args...`` (``code`` runs after it in the same process, if given)."""
    if code:
        run = f"import sys\nfrom truckrl.__main__ import main\nrc = main({list(args)!r})\n{code}"
        argv = [sys.executable, "-c", run]
    else:
        argv = [sys.executable, "-m", "truckrl", *args]
    return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_help_lists_every_command_in_under_25_lines_without_torch():
    r = truckrl("--help", code="print(sorted(m for m in sys.modules if m.startswith('torch')))")
    assert r.returncode == 0, r.stderr
    *help_lines, imported = r.stdout.strip().splitlines()
    assert len(help_lines) < 25
    assert ast.literal_eval(imported) == []  # not even torch
    text = "\n".join(help_lines)
    for name in [*HYDRA, *PLAIN, "tools", *TOOLS]:
        assert f"{name}" in text, name


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["train", "--help"], "truckrl train [OVERRIDE ...]"),
        (["eval", "--help"], "checkpoint="),
        (["play", "--help"], "headless=true"),
        (["export", "--help"], "format"),
    ],
)
def test_each_hydra_command_answers_its_help(args, says):
    r = truckrl(*args)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert says in r.stdout


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["plan", "--help"], "usage: truckrl plan [KEY=VALUE ...]"),
        (["tools", "--help"], "usage: truckrl tools <tool>"),
        *[(["tools", t, "--help"], f"usage: truckrl tools {t} [KEY=VALUE ...]") for t in TOOLS],
    ],
)
def test_each_other_command_answers_its_help(args, says, capsys):
    """In this process (these commands read no ``sys.argv`` and start no Hydra job)."""
    from truckrl.__main__ import main

    try:
        code = main(list(args))
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    assert code in (0, None) and out.err == "", out.err
    assert says in out.out


def test_bench_reaches_the_bench_command(capsys):
    from truckrl.__main__ import main

    assert main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: truckrl bench BENCHMARK") and "  train  " in out


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["trian"], "error: no command 'trian' (did you mean train?); one of: train, eval"),
        (["tools", "path"], "error: no tool 'path' (did you mean paths?); one of: paths"),
    ],
)
def test_an_unknown_command_is_one_line_and_exit_2(args, says):
    r = truckrl(*args)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.startswith(says) and len(r.stderr.splitlines()) == 1


def test_a_hydra_command_runs_as_its_module(tmp_path):
    """``truckrl tools configs`` and ``truckrl eval`` give what the modules give."""
    r = truckrl("tools", "configs", "ppo.lr")
    assert r.returncode == 0 and r.stdout.startswith("ppo.lr ")
    r = truckrl("eval", "episodes=0")
    assert r.returncode == 2 and r.stderr.startswith("error: episodes")
    assert len(r.stderr.splitlines()) == 1
