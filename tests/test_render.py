"""docs/render.py: committed JSON into Markdown fragments (tables and provenance lines).

The fixtures under ``tests/fixtures/render/`` are small files of each kind: an aggregate over
seeds with its own provenance, an evaluation and a benchmark record as their commands write them
(no provenance object). Every expected string is written out by hand.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "render"


@pytest.fixture(scope="module")
def render():
    spec = importlib.util.spec_from_file_location("docs_render", ROOT / "docs" / "render.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def out(render, tmp_path):
    (tmp_path / "stale.md").parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / "stale.md").write_text("left from an earlier build")
    render.render(FIXTURES, tmp_path)
    return tmp_path


def test_the_out_folder_holds_exactly_the_fragments(out):
    names = sorted(str(p.relative_to(out)) for p in out.rglob("*.md"))
    assert names == [
        "benchmarks/env-parts-parts.md",
        "benchmarks/env-parts.md",
        "benchmarks/env-tasks.md",
        "benchmarks/env.md",
        "results/dock-bins.md",
        "results/dock.md",
        "seeds.md",
        "seeds/demos-bins.md",
        "seeds/demos.md",
    ]


def test_seeds_aggregate_table_and_provenance(out):
    text = (out / "seeds" / "demos.md").read_text()
    assert text == (
        "| metric | IQM | 95 % CI | per seed | n seeds |\n"
        "|---|---:|---:|---:|---:|\n"
        "| heldout_success | 97.4 % | [97.0 %, 98.1 %] | 0: 97.1 %, 1: 97.4 %, 2: 98.1 % | 3 |\n"
        "| minutes_to_difficulty_6 [min] | 15.8 | [9.3, 16.5] | 0: 15.8, 1: 16.5, 2: 9.3 | 3 |\n"
        "| frames_to_difficulty_6 [frames] | – | [–, –] "
        "| 0: 30,100,000, 1: –, 2: 12,700,000 | 3 |\n"
        "\n"
        "*Provenance:* `truckrl tools aggregate 'runs=[outputs/seeds/seed-0,outputs/seeds/seed-1,"
        "outputs/seeds/seed-2]' out=docs/data/seeds/demos.json` · machine: Linux 6.18, x86_64, "
        "2 CPUs, Python 3.11.7, torch 2.13.0+cpu · torch threads: 2 · commit `0123456789-dirty` · "
        "date: 2030-01-02 10:00:00 +0000\n"
    )


def test_seeds_bins_and_the_seeds_page_fragment(out):
    bins = (out / "seeds" / "demos-bins.md").read_text()
    row = (
        "| turn [deg] right 110-180 | 88.9 % | [87.3 %, 92.1 %] | 0: 88.9 %, 1: 92.1 %, 2: 87.3 % "
    )
    row += "| 3 |"
    assert row in bins
    page = (out / "seeds.md").read_text()
    assert page.startswith("### experiment=demos\n\n| metric | IQM |")
    assert page.count("*Provenance:*") == 2


def test_no_aggregate_names_the_command(render, tmp_path):
    data = tmp_path / "data"
    (data / "results").mkdir(parents=True)
    (data / "results" / "dock.json").write_text((FIXTURES / "results" / "dock.json").read_text())
    render.render(data, tmp_path / "out")
    text = (tmp_path / "out" / "seeds.md").read_text()
    assert "No aggregate over seeds is committed yet" in text
    assert "`truckrl tools aggregate runs=[RUN_DIR,...] out=docs/data/seeds/NAME.json`" in text


def test_evaluation_summary_bins_and_reconstructed_provenance(out):
    line = (
        "*Provenance:* `truckrl eval checkpoint=pretrained:dock difficulty=7 episodes=1000 "
        "seed=12345` (reconstructed) · machine: not recorded · commit: not recorded · "
        "date: not recorded\n"
    )
    summary = (out / "results" / "dock.md").read_text()
    assert summary == (
        "| difficulty (tolerance) | episodes | success | 95 % interval | collision | jack-knife "
        "| timeout | trailer rear error [m] mean / p95 |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|\n"
        "| 7 (0.15 m, 5.73°) | 1,000 | 81.6 % | 79.1–83.9 % | 11.4 % | 0.2 % | 6.8 % "
        "| 2.62 / 14.6 |\n"
        "\n" + line
    )
    bins = (out / "results" / "dock-bins.md").read_text()
    assert bins == (
        "| dimension | bin | episodes | success | 95 % interval | collision | jack-knife "
        "| timeout |\n"
        "|---|---|---:|---:|---:|---:|---:|---:|\n"
        "| neighbours | none | 280 | 87.9 % | 83.5–91.2 % | 5.0 % | 0.0 % | 7.1 % |\n"
        "|  | both | 390 | 72.6 % | 67.9–76.8 % | 20.0 % | 0.4 % | 7.0 % |\n"
        "| bay width [m] | 3.5-4 | 500 | 79.0 % | 75.2–82.3 % | 13.0 % | 0.0 % | 8.0 % |\n"
        "\n" + line
    )


def test_bench_env_pivots_compile_modes_and_reads_provenance_from_the_record(out):
    text = (out / "benchmarks" / "env.md").read_text()
    assert text == (
        "| layout | processes × trucks | eager | compiled |\n"
        "|---|---|---:|---:|\n"
        "| one batched TruckEnv | 1 × 4,096 | 336,544 | 659,706 |\n"
        "| ParallelEnv of batched TruckEnvs | 2 × 512 | – | 163,271 |\n"
        "\n"
        "*Provenance:* `truckrl bench env envs=[4096] parallel_envs=[1024] workers=2 steps=50 "
        "warmup=5 compile=both collector=false device=cuda paper=false` (reconstructed) · "
        "machine: NVIDIA H100 80GB HBM3, 16 CPU cores, torch 2.11.0+cu130, load average 3.2 · "
        "torch threads: 16 · commit: not recorded · date: 2030-01-02 07:47\n"
    )


def test_bench_env_over_several_tasks_names_each_task_and_its_ratio_to_intersection(out):
    table = (out / "benchmarks" / "env-tasks.md").read_text().split("\n\n")[0]
    assert table == (
        "| task | layout | processes × trucks | eager | compiled | × intersection |\n"
        "|---|---:|---:|---:|---:|---:|\n"
        "| intersection | one batched TruckEnv | 1 × 1,024 | – | 400,000 | 100.0 % |\n"
        "| network | one batched TruckEnv | 1 × 1,024 | – | 60,000 | 15.0 % |"
    )


def test_bench_env_parts_get_their_own_table_with_the_ratio_without_draws(out):
    """``parts=true``: ms per step of each part, per task, and the ratio to the first task with
    the draws left out of both, as the record holds them (the fixture's numbers)."""
    parts = (out / "benchmarks" / "env-parts-parts.md").read_text()
    table, line = parts.split("\n\n")
    assert table == (
        "| task | episode draws | their preparation | restarts | transition | the rest | total "
        "| × intersection, draws left out |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|\n"
        "| intersection | 0.25 | 0.05 | 0.50 | 3.50 | 0.70 | 5.00 | 100.0 % |\n"
        "| network | 5.25 | 0.20 | 1.50 | 8.00 | 1.05 | 16.00 | 40.0 % |"
    )
    assert "tasks=[intersection,network]" in line and "parts=true" in line
    # a run without parts has no such fragment
    assert not (out / "benchmarks" / "env-tasks-parts.md").exists()


def test_bench_env_parts_of_one_task_are_labelled_by_trucks(render):
    doc = {
        "benchmark": "env",
        "rows": [
            {"layout": "batched", "workers": 1, "envs/worker": 256, "trucks": 256,
             "compile": True, "steps/s": 1000.0,
             "parts_ms": {"draw": 1.0, "prepare": 0.5, "restart": 0.25, "transition": 2.0,
                          "other": 0.25, "total": 4.0}},
        ],
    }  # fmt: skip
    header, rows = render.env_tables(doc)["-parts"]
    assert header[0] == "trucks" and len(header) == 7  # no ratio column for one task
    assert rows == [["256", "1.00", "0.50", "0.25", "2.00", "0.25", "4.00"]]


def test_an_unknown_file_is_refused_by_name(render, tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    (data / "odd.json").write_text('{"rows": []}')
    with pytest.raises(SystemExit, match="odd.json: not a seeds aggregate"):
        render.render(data, tmp_path / "out")


def test_an_evaluation_with_smoothness_gets_its_percentile_table(render):
    doc = {
        "difficulty": 6.0, "tolerance_position_m": 0.46875, "tolerance_heading_deg": 0.9375,
        "episodes": 10, "success_rate": 0.5, "collision_rate": 0.5, "jackknife_rate": 0.0,
        "timeout_rate": 0.0, "categories": [],
        "smoothness": {"steps": 1234, "jerk_m/s^3_p50": 0.5, "jerk_m/s^3_p95": 3.25,
                       "steer_rate_rad/s_p50": 0.0125, "steer_rate_rad/s_p95": 0.5},
    }  # fmt: skip
    table = render.fragments(doc)["-smoothness"].split("\n\n")[0]
    assert table == (
        "| magnitude over 1,234 steps of successes | p50 | p95 |\n"
        "|---|---:|---:|\n"
        "| jerk [m/s^3] | 0.5 | 3.25 |\n"
        "| steer rate [rad/s] | 0.0125 | 0.5 |"
    )
    assert "-smoothness" not in render.fragments({**doc, "smoothness": None})


def test_an_evaluation_shows_the_success_rates_interval_even_from_an_older_file(render):
    """Files written before eval recorded the interval get it from their rate and count: 5 of
    10 -> Wilson's 23.66-76.34 % (R. G. Newcombe, Stat. Med. 17, 1998), 1 of 1 -> 20.7-100 %."""
    doc = {
        "difficulty": 6.0, "tolerance_position_m": 0.46875, "tolerance_heading_deg": 0.9375,
        "episodes": 10, "success_rate": 0.5, "collision_rate": 0.5, "jackknife_rate": 0.0,
        "timeout_rate": 0.0,
        "categories": [{"dimension": "turn", "bin": "left", "count": 1, "success_rate": 1.0,
                        "collision_rate": 0.0, "jackknife_rate": 0.0, "timeout_rate": 0.0}],
    }  # fmt: skip
    frags = render.fragments(doc)
    head, _, row = frags[""].split("\n\n")[0].splitlines()
    assert head.startswith("| difficulty (tolerance) | episodes | success | 95 % interval |")
    assert row.startswith("| 6 (0.469 m, 0.938°) | 10 | 50.0 % | 23.7–76.3 % | 50.0 % |")
    bins = frags["-bins"].split("\n\n")[0].splitlines()
    assert bins[2] == "| turn | left | 1 | 100.0 % | 20.7–100.0 % | 0.0 % | 0.0 % | 0.0 % |"
