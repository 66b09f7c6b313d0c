"""``python -m truckrl.bench env``: a quick run within its budget, and one-line key errors."""

import json
import sys

import pytest

from tests.conftest import run_cli

pytestmark = pytest.mark.e2e


def test_quick_run_prints_its_time_and_writes_json(tmp_path):
    proc = run_cli("bench", "env", "quick=true", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("bench env took"))
    seconds = float(line.split()[3])
    assert seconds < 60  # budget 15 s on an idle 2-core machine; generous under CI load
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    assert {r["trucks"] for r in record["rows"]} == {1, 256}


def test_bad_option_exits_2_with_one_line(tmp_path):
    proc = run_cli("bench", "env", "workers=0", f"out={tmp_path}")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: workers = 0 is outside the allowed")


def _in_process(capsys, *argv: str) -> tuple[int, str, str]:
    """``python -m truckrl.bench argv`` in this process: (exit code, stdout, stderr)."""
    from truckrl.bench.__main__ import main

    with pytest.raises(SystemExit) as exit_:
        main(list(argv))
    out = capsys.readouterr()
    return exit_.value.code, out.out, out.err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["envs=[0]"], "envs[0] = 0"),
        (["steps=0"], "steps = 0"),
        (["device=nope"], "device = 'nope'"),
        (["peer_envs=0"], "peer_envs = 0"),
        (["parallel_envs=[1]", "workers=2"], "parallel_envs = [1]"),
        (["compile=maybe"], "compile = 'maybe'"),
        (["gym=true", "repeats=0"], "repeats = 0"),
        (["tasks=[intersection,nope]"], "tasks[1] = 'nope' is not one of"),
        (["tasks=[intersection]", "task=dock"], "tasks = ['intersection']: not with task"),
        (["difficulty=31"], "difficulty = 31"),
        (["difficulty=3", "scaling=true"], "difficulty = 3: scaling, peers and gym"),
        (["parts=true", "gym=true"], "parts=true times the batched rows"),
        (["--steps", "2"], "'--steps'"),
        (["no_such_key=1"], "unknown field(s) ['no_such_key']"),
    ],
)
def test_bad_options_are_one_line_exit_2(args, needle, tmp_path, capsys):
    code, _, err = _in_process(capsys, "env", *args, f"out={tmp_path}")
    assert code == 2
    assert err.strip().startswith(f"error: {needle}") and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())  # rejected before any work


def test_every_option_has_help(capsys):
    code, stdout, _ = _in_process(capsys, "env", "--help")
    assert code == 0
    for key in (
        "quick", "envs", "workers", "parallel_envs", "steps", "compile", "paper", "collector",
        "scaling", "eager_max_envs", "plot", "peers", "peer_envs", "device", "threads", "seed",
        "out", "gym", "repeats", "task", "tasks",
    ):  # fmt: skip
        line = next(x for x in stdout.splitlines() if x.strip().startswith(key + " "))
        assert len(line.strip()) > len(key) + 8, key  # followed by a description


def test_scaling_quick_writes_table_json_and_a_three_panel_png(tmp_path):
    import cv2

    png = tmp_path / "scaling.png"
    proc = run_cli("bench", "env", "scaling=true", "quick=true", f"out={tmp_path}", f"plot={png}")
    assert proc.returncode == 0, proc.stderr
    assert "env-steps/s scaling" in proc.stdout
    record = json.loads(next(tmp_path.glob("env-scaling-*.json")).read_text())
    axes = {(r["axis"], r["value"]) for r in record["rows"]}
    assert axes == {("trucks", 1), ("trucks", 16), ("trucks", 64), ("beams", 16), ("beams", 32),
                    ("obstacles", 0), ("obstacles", 4)}  # fmt: skip
    slots = {r["value"]: r["segment slots"] for r in record["rows"] if r["axis"] == "obstacles"}
    assert slots == {0: 8, 4: 24}  # 8 curb slots + 4 per obstacle slot
    assert all(r["steps/s"] > 0 for r in record["rows"])
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] > 2.5 * img.shape[0]  # three panels side by side


def test_gym_row_beside_the_torchrl_row(tmp_path, capsys):
    """gym=true: at each N a TorchRL row and a Gymnasium row, each the median of its alternating
    runs, and the median of the runs' pairwise ratios; the record holds the runs."""
    import statistics

    from truckrl.bench import env as bench_env

    argv = ["quick=true", "gym=true", "envs=[8]", "steps=3", "repeats=5", f"out={tmp_path}"]
    bench_env.run(bench_env.parse(argv))
    assert "gym / torchrl at N=8:" in capsys.readouterr().out
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    torchrl, gym = record["rows"]
    assert (torchrl["layout"], gym["layout"]) == ("batched", "gym") and gym["trucks"] == 8
    for row in (torchrl, gym):
        assert len(row["runs"]) == 5 and row["steps/s"] == statistics.median(row["runs"])
    pairs = [g / t for t, g in zip(torchrl["runs"], gym["runs"], strict=True)]
    assert gym["x torchrl"] == pytest.approx(statistics.median(pairs))
    assert torchrl["x torchrl"] is None and "x torchrl" in record["table"]


def test_tasks_rows_alternate_in_one_run(tmp_path, capsys):
    """tasks=[a,b]: at each N a row per task, each the median of its runs, and ``x a``, the
    median over the rounds of the task's run over a's run of the same round."""
    import statistics

    from truckrl.bench import env as bench_env

    argv = ["quick=true", "tasks=[intersection,dock]", "envs=[4]", "steps=2", "warmup=1"]
    bench_env.run(bench_env.parse([*argv, "repeats=3", f"out={tmp_path}"]))
    assert "dock / intersection at N=4:" in capsys.readouterr().out
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    first, second = record["rows"]
    assert (first["task"], second["task"]) == ("intersection", "dock")
    for row in (first, second):
        assert len(row["runs"]) == 3 and row["steps/s"] == statistics.median(row["runs"])
    pairs = [b / a for a, b in zip(first["runs"], second["runs"], strict=True)]
    assert second["x intersection"] == pytest.approx(statistics.median(pairs))
    assert first["x intersection"] == 1.0 and "x intersection" in record["table"]


def test_gym_without_gymnasium_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)  # as if not installed
    code, _, err = _in_process(capsys, "env", "gym=true", f"out={tmp_path}")
    assert code == 2
    assert err.strip().splitlines() == [
        "error: gym=true needs Gymnasium: pip install 'truckrl[gym]'"
    ]


def test_peers_without_vmas_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "vmas", None)  # as if not installed
    code, _, err = _in_process(capsys, "env", "peers=true", f"out={tmp_path}")
    assert code == 2
    assert err.strip().splitlines() == [
        "error: peers=true needs VMAS: pip install 'truckrl[bench]'"
    ]
    assert not list(tmp_path.glob("*.json"))


def test_peers_quick_side_by_side(tmp_path):
    pytest.importorskip("vmas")
    proc = run_cli("bench", "env", "peers=true", "quick=true", f"out={tmp_path}")
    assert proc.returncode == 0, proc.stderr
    record = json.loads(next(tmp_path.glob("env-peers-*.json")).read_text())
    sims = [r["simulator"] for r in record["rows"]]
    assert sims[0].startswith("VMAS") and "TruckEnv" in sims
    assert record["rows"][0]["x VMAS"] == 1.0 and all(r["steps/s"] > 0 for r in record["rows"])


def test_benchmark_names_are_checked_and_listed(capsys):
    code, _, err = _in_process(capsys, "nope")
    assert code == 2 and err.strip().startswith("error: benchmark 'nope' is not one of")
    from truckrl.bench.__main__ import main

    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(f"  {name} " in out for name in ("env", "lidar", "train"))


def test_parts_split_each_runs_step_time_and_give_the_ratio_without_draws(tmp_path, capsys):
    """parts=true: each task row holds the median ms per step of each part, which add up to its
    total, and ``x <first task> without draws``, the median over the rounds of the first task's
    step time over this one's, each with its run's draws taken out."""
    import statistics

    from truckrl.bench import env as bench_env

    argv = ["quick=true", "tasks=[intersection,dock]", "envs=[4]", "steps=6", "warmup=1"]
    runs = []
    real, make = bench_env.steps_per_second_parts, bench_env._make_env

    def recorded(*args):
        runs.append(real(*args))
        return runs[-1]

    def short_episodes(*args, **kwargs):
        # every truck restarts every 2 steps from a pool of 4: both tasks draw in every run
        return make(*args, overrides={"max_steps": 2, "episode_pool": 4}, **kwargs)

    bench_env.steps_per_second_parts, bench_env._make_env = recorded, short_episodes
    try:
        bench_env.run(bench_env.parse([*argv, "repeats=3", "parts=true", f"out={tmp_path}"]))
    finally:
        bench_env.steps_per_second_parts, bench_env._make_env = real, make
    assert "dock / intersection at N=4, draws left out:" in capsys.readouterr().out
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    first, second = record["rows"]
    parts = ("draw", "prepare", "restart", "transition", "other", "total")
    for i, row in enumerate((first, second)):
        mine = [r[2] for r in runs[i::2]]  # the runs alternate: intersection, dock, ...
        assert row["parts_ms"] == {k: statistics.median(m[k] for m in mine) for k in parts}
        for m in mine:
            assert sum(m[k] for k in parts[:-1]) == pytest.approx(m["total"])
            assert min(m[k] for k in parts[:-2]) > 0.0  # every part ran in every run
    bare = [
        (a[2]["total"] - a[2]["draw"]) / (b[2]["total"] - b[2]["draw"])
        for a, b in zip(runs[0::2], runs[1::2], strict=True)
    ]
    assert second["x intersection without draws"] == pytest.approx(statistics.median(bare))
    assert first["x intersection without draws"] == 1.0
    assert "parts_ms" not in record["table"]


def test_parts_of_a_one_task_row_stay_out_of_its_table(tmp_path, capsys):
    """parts=true without tasks: the batched row holds its parts (adding up to its total) and
    prints them; the printed table keeps its usual columns."""
    from truckrl.bench import env as bench_env

    argv = ["quick=true", "envs=[4]", "steps=3", "warmup=1", "parts=true", f"out={tmp_path}"]
    bench_env.run(bench_env.parse(argv))
    assert "N=4: ms per step: draw" in capsys.readouterr().out
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    (row,) = record["rows"]
    ms = row["parts_ms"]
    assert sum(v for k, v in ms.items() if k != "total") == pytest.approx(ms["total"])
    assert "parts_ms" not in record["table"] and "steps/s" in record["table"]


def test_difficulty_is_where_the_envs_step(tmp_path, capsys):
    """difficulty=3: the envs draw and step episodes of difficulty 3 (the network task's
    traffic is stepped there, and left out of the step at the default 0)."""
    from truckrl.bench import env as bench_env

    args = bench_env.parse(["tasks=[network]", "envs=[4]", "difficulty=3", f"out={tmp_path}"])
    env = bench_env._make_env(4, False, "cpu", 0, task="network", difficulty=args.difficulty)
    env.reset()
    assert env.difficulty == 3.0 and env._idle == ()
    idle = bench_env._make_env(4, False, "cpu", 0, task="network")
    idle.reset()
    assert idle.difficulty == 0.0 and idle._idle  # the traffic's keys, left out at 0
    argv = ["quick=true", "tasks=[network]", "envs=[4]", "steps=2", "warmup=1", "repeats=1"]
    bench_env.run(bench_env.parse([*argv, "difficulty=3", f"out={tmp_path}"]))
    record = json.loads(next(tmp_path.glob("env-*.json")).read_text())
    assert record["args"]["difficulty"] == 3.0
