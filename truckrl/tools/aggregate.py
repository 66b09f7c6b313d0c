"""``truckrl tools aggregate``: one config's training runs over seeds, as per-seed figures and
their interquartile mean with a 95 % bootstrap interval (:mod:`truckrl.tools.stats`).

    truckrl tools aggregate runs=[outputs/seeds/seed-0,outputs/seeds/seed-1] out=seeds.json
    truckrl tools aggregate runs=outputs/multirun/DATE/TIME out=seeds.json plot=seeds.png
    truckrl tools aggregate runs="[outputs/seeds/*]" out=seeds.json

``runs`` lists run dirs (holding ``checkpoints/last.pt``), globs of them, or folders whose
subfolders are runs (a Hydra multirun dir). The runs must share their training config but for
:data:`PER_RUN` (the seed above all) and have distinct seeds. For each run (seed):

* ``heldout_success``: the success of its ``checkpoint`` (last.pt or best.pt) with the mean
  action on the ``episodes`` scenes of scene seed ``seed`` at ``difficulty``, as ``truckrl eval``
  scores them, and the same per scene bin of the task (``bins``);
* ``minutes_to_difficulty_6`` and ``frames_to_difficulty_6``: the first logged
  ``curriculum/difficulty`` of at least 6 (null: never reached); the minutes are the wall clock
  of its TensorBoard events since the first one, plus the demonstrations' ``seconds`` from
  ``demos.json`` (planned and cloned before the first event), so they count from the run's start
  as docs/training.md does (a resumed run's pause between sessions does not count:
  :func:`truckrl.viz.curves.load_scalars`);
* ``minutes_to_quality``: minutes from the run's start to its ``quality_reached`` (training's
  held-out check first at or above ``log.quality_target`` at ``log.quality_difficulty``; the
  ``quality/reached_minutes`` scalar; null: never);
* ``final_difficulty``: the curriculum difficulty of its last.pt.

Across seeds: the IQM and a 95 % percentile bootstrap interval of each (a seed that never
reached difficulty 6 counts as never: the IQM and interval are null where that seed weighs in).
It prints a per-seed table and the IQM table, and writes ``out`` (JSON, :func:`result`);
``plot=FILE.png`` draws the curriculum difficulty and success EMA of every seed against frames
(or minutes, ``x=minutes``) as the median with the interquartile band, up to where the shortest
run ends. Bad input prints one line and exits with code 2 before any evaluation.
"""

from __future__ import annotations

import glob
import json
import math
import re
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from truckrl.config.fields import ConfigError, param, validate
from truckrl.tasks import MAX_DIFFICULTY

PROG = "truckrl tools aggregate"
ABOUT = "Training runs of one config over seeds: per-seed figures, their IQM and 95 % interval."

#: The level whose first arrival the time metrics measure (the paper's goal).
TARGET_DIFFICULTY = 6.0
#: Training config fields that may differ between the runs of one config: what makes it a
#: different seed (``seed``), how a run was resumed, where it logs and saves, and the hardware
#: it ran on (device, torch threads).
PER_RUN = ("seed", "resume", "overwrite", "log", "checkpoint", "device", "threads")
#: Metric name -> unit, in the JSON's order.
UNITS = {
    "heldout_success": "fraction of held-out scenes",
    "minutes_to_difficulty_6": "min (wall clock from the run's start, demonstrations included)",
    "frames_to_difficulty_6": "frames",
    "minutes_to_quality": "min (wall clock from the run's start to quality_reached: held-out "
    "success >= log.quality_target at log.quality_difficulty)",
    "final_difficulty": "curriculum difficulty",
}
#: Metrics whose null means "never" (a censored time): infinite for the IQM and interval.
NEVER_IS_INFINITE = ("minutes_to_difficulty_6", "frames_to_difficulty_6", "minutes_to_quality")
#: Scalars drawn by ``plot=``: TensorBoard tag -> panel title, y range.
CURVES = {
    "curriculum/difficulty": ("curriculum difficulty", (0.0, None)),
    "episode/success_ema": ("success EMA", (0.0, 1.0)),
}


@dataclass
class AggregateConfig:
    """Which runs, how to score them, and where the results go."""

    runs: tuple[str, ...] = param(
        (), min_len=0, doc="run dirs, globs of them, or multirun dirs of them; required"
    )
    difficulty: float = param(
        6.0, lo=0.0, hi=MAX_DIFFICULTY, doc="difficulty of the held-out scenes"
    )
    episodes: int = param(1000, lo=1, hi=1_000_000, doc="held-out scenes per run")
    seed: int = param(12345, lo=0, hi=2**62, doc="scene seed (evaluate's by default)")
    checkpoint: str = param("last", choices=("last", "best"), doc="which checkpoint of each run")
    out: str | None = param(None, doc="JSON file to write; required")
    plot: str | None = param(None, doc="PNG of the curves over seeds; null: none")
    x: str = param("frames", choices=("frames", "minutes"), doc="x axis of the plot")
    threads: int = param(2, lo=1, hi=1024, doc="torch CPU threads of the evaluations")

    def __post_init__(self) -> None:
        if isinstance(self.runs, str):  # one value for a list of one
            self.runs = (self.runs,)
        validate(self)
        if not self.runs:
            raise ConfigError("runs is required: runs=[RUN_DIR,...], a glob or a multirun dir")
        if not self.out or not self.out.lower().endswith(".json"):
            raise ConfigError(f"out = {self.out!r}: a JSON file to write (out=seeds.json)")
        if self.plot is not None and not self.plot.lower().endswith(".png"):
            raise ConfigError(f"plot = {self.plot!r} must end in .png")


# ------------------------------------------------------------------------------- finding runs
def is_run(path: Path) -> bool:
    """Whether ``path`` is a training run dir (it holds ``checkpoints/last.pt``)."""
    return (path / "checkpoints" / "last.pt").is_file()


def _natural(p: Path) -> list:
    """Sort key: ``2`` before ``10`` (Hydra numbers the jobs of a multirun)."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]


def find_runs(entries: tuple[str, ...]) -> list[Path]:
    """The run dirs named by ``entries`` (dirs, globs, multirun dirs), each once, in order.

    Raises:
        ConfigError: an entry that names nothing, or a folder without any run.
    """
    found: list[Path] = []
    for entry in entries:
        paths = (
            sorted(Path(p) for p in glob.glob(entry)) if glob.has_magic(entry) else [Path(entry)]
        )
        if not paths or not all(p.exists() for p in paths):
            raise ConfigError(f"runs: {entry!r} names no file or folder")
        for p in paths:
            if is_run(p):
                found.append(p)
                continue
            subs = sorted((d for d in p.iterdir() if d.is_dir() and is_run(d)), key=_natural)
            if not subs and not glob.has_magic(entry):
                raise ConfigError(
                    f"runs: {str(p)!r} is not a run dir (no checkpoints/last.pt) and holds none"
                )
            found += subs
    unique = list({p.resolve(): p for p in found}.values())
    if not unique:
        raise ConfigError(f"runs: {list(entries)} match no run dir (holding checkpoints/last.pt)")
    return unique


@dataclass
class Run:
    """What one run dir says about itself (before any evaluation)."""

    path: Path
    seed: int
    config: dict
    source: dict
    final_difficulty: float
    checkpoint: Path
    scalars: dict
    demos_s: float
    overrides: list[str] | None
    experiment: str | None


def read_run(path: Path, which: str) -> Run:
    """Read ``path``'s last.pt (config, seed, source, difficulty), its TensorBoard scalars, its
    ``demos.json`` and Hydra's record of its command line (``.hydra/``, where present).

    Raises:
        ConfigError, CheckpointError: a file that is missing or unreadable (one line).
    """
    import yaml

    from truckrl.rl.checkpoint import BEST_NAME, CHECKPOINT_DIR, load_training_state
    from truckrl.rl.policy import saved_config
    from truckrl.viz.curves import load_scalars

    state = load_training_state(path)
    config = saved_config(state)
    ckpt = path / CHECKPOINT_DIR / (BEST_NAME if which == "best" else "last.pt")
    if not ckpt.is_file():
        raise ConfigError(f"checkpoint = {which}: run {path} has no {CHECKPOINT_DIR}/{ckpt.name}")
    try:
        scalars = load_scalars(path)
    except (FileNotFoundError, ValueError) as e:
        raise ConfigError(f"runs: {path}: {e}") from None
    demos = path / "demos.json"
    demos_s = float(json.loads(demos.read_text()).get("seconds", 0.0)) if demos.is_file() else 0.0
    hydra_dir = path / ".hydra"
    overrides = experiment = None
    if (hydra_dir / "overrides.yaml").is_file():
        overrides = [str(o) for o in yaml.safe_load((hydra_dir / "overrides.yaml").read_text())]
    if (hydra_dir / "hydra.yaml").is_file():
        hydra = yaml.safe_load((hydra_dir / "hydra.yaml").read_text()) or {}
        experiment = hydra.get("hydra", {}).get("runtime", {}).get("choices", {}).get("experiment")
    return Run(
        path, int(config["seed"]), config, dict(state.get("source") or {}),
        float(state["curriculum"]["difficulty"]), ckpt, scalars, demos_s, overrides, experiment,
    )  # fmt: skip


def _differences(a: Any, b: Any, where: str = "") -> list[str]:
    """Dotted keys where the plain configs ``a`` and ``b`` differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            out += _differences(a.get(k), b.get(k), f"{where}.{k}" if where else str(k))
        return out
    return [] if a == b else [where]


def check_one_config(runs: list[Run]) -> None:
    """Refuse runs of different configs (beyond :data:`PER_RUN`) or with the same seed.

    Raises:
        ConfigError: naming the two runs and the first fields that differ, or the shared seed.
    """
    first = runs[0]
    mine = {k: v for k, v in first.config.items() if k not in PER_RUN}
    seen: dict[int, Path] = {}
    for r in runs:
        if r.seed in seen:
            raise ConfigError(
                f"runs: {seen[r.seed]} and {r.path} both have seed {r.seed}: one run per seed"
            )
        seen[r.seed] = r.path
        diff = _differences(mine, {k: v for k, v in r.config.items() if k not in PER_RUN})
        if diff:
            raise ConfigError(
                f"runs: {first.path} and {r.path} differ in {', '.join(diff[:4])}"
                f"{' ...' if len(diff) > 4 else ''}: aggregate the seeds of one config"
            )


def config_text(runs: list[Run]) -> str:
    """The runs' shared command line, ``truckrl train experiment=E OVERRIDE ...`` (the
    overrides all runs were given, ``seed`` and ``hydra.*`` left out), from their ``.hydra/``
    records; without them, the task and how the runs differ."""
    task = runs[0].config.get("env", {}).get("task", {}).get("name", "?")
    if any(r.overrides is None for r in runs):
        return f"task={task} (the run dirs hold no .hydra/ record of their command line)"
    shared = [o for o in runs[0].overrides if all(o in r.overrides for r in runs[1:])]
    keep = [o for o in shared if not o.lstrip("+~").startswith(("seed=", "hydra."))]
    experiments = {r.experiment for r in runs}
    head = ["truckrl train"]
    if len(experiments) == 1 and None not in experiments:
        head.append(f"experiment={experiments.pop()}")
    return " ".join(head + [o for o in keep if not o.startswith("experiment=")])


# ------------------------------------------------------------------------------- figures
def first_arrival(run: Run, level: float = TARGET_DIFFICULTY) -> tuple[float | None, int | None]:
    """``(minutes, frames)`` of the first logged ``curriculum/difficulty`` >= ``level``
    (minutes from the run's start, demonstrations included); ``(None, None)`` if never."""
    d = run.scalars.get("curriculum/difficulty")
    if d is None:
        return None, None
    for minutes, frames, value in d:
        if value >= level - 1e-9:
            return float(minutes) + run.demos_s / 60.0, int(frames)
    return None, None


def quality_minutes(run: Run) -> float | None:
    """Minutes from the run's start to its ``quality_reached`` (the ``quality/reached_minutes``
    scalar that training logs once, :class:`truckrl.rl.progress.Quality`); None if never."""
    q = run.scalars.get("quality/reached_minutes")
    return None if q is None or len(q) == 0 else float(q[0][2])


def per_seed_figures(run: Run, heldout: dict) -> dict[str, float | None]:
    """The metrics of one run (:data:`UNITS`)."""
    minutes, frames = first_arrival(run)
    return {
        "heldout_success": heldout["success"],
        "minutes_to_difficulty_6": minutes,
        "frames_to_difficulty_6": frames,
        "minutes_to_quality": quality_minutes(run),
        "final_difficulty": run.final_difficulty,
    }


def result(
    runs: list[Run], figures: list[dict], heldouts: list[dict], provenance: dict, config: str
) -> dict:
    """The JSON of the aggregate::

    {"provenance": {"command", "machine", "commit", "date", "threads"}, "kind": "seeds",
     "config": str, "seeds": [int],
     "metrics": {name: {"per_seed": {seed: float | null}, "iqm", "ci95", "unit"}},
     "bins": {"<dimension> <bin>": {"per_seed": {...}, "iqm", "ci95"}}}
    """
    from truckrl.tools.stats import summary

    seeds = [r.seed for r in runs]
    metrics = {}
    for name, unit in UNITS.items():
        values = [f[name] for f in figures]
        missing = math.inf if name in NEVER_IS_INFINITE else None
        per_seed = {str(s): v for s, v in zip(seeds, values, strict=True)}
        metrics[name] = {"per_seed": per_seed, **summary(values, missing), "unit": unit}
    names = list(dict.fromkeys(b for h in heldouts for b in h["bins"]))
    bins = {}
    for b in names:
        values = [h["bins"].get(b, {}).get("success") for h in heldouts]
        if all(v is None for v in values):
            continue  # no seed's scenes fell in this bin
        per_seed = {str(s): v for s, v in zip(seeds, values, strict=True)}
        bins[b] = {"per_seed": per_seed, **summary(values)}
    return {
        "provenance": provenance,
        "kind": "seeds",
        "config": config,
        "seeds": seeds,
        "metrics": metrics,
        "bins": bins,
    }


def _cell(value: float | None, name: str) -> str:
    if value is None:
        return "never" if name in NEVER_IS_INFINITE else "-"
    if name == "heldout_success" or "success" in name:
        return f"{100.0 * value:.1f} %"
    if name.startswith("frames"):
        return f"{value / 1e6:.2f} M" if value >= 1e6 else f"{value:,.0f}"
    return f"{value:.1f}" if name.startswith("minutes") else f"{value:g}"


def tables(data: dict) -> str:
    """Markdown tables: one row per seed, then IQM and 95 % interval per metric and bin."""
    names = list(data["metrics"])
    lines = ["| seed | " + " | ".join(names) + " |", "|---:|" + "---:|" * len(names)]
    for s in data["seeds"]:
        cells = [_cell(data["metrics"][n]["per_seed"][str(s)], n) for n in names]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += ["", "| metric | IQM | 95 % interval | unit |", "|---|---:|---:|---|"]
    rows = [(n, m, m["unit"]) for n, m in data["metrics"].items()]
    rows += [(f"success {b}", m, "fraction") for b, m in data["bins"].items()]
    for name, m, unit in rows:
        key = "heldout_success" if name.startswith("success ") else name
        ci = m["ci95"]
        shown = f"{_cell(ci[0], key)} – {_cell(ci[1], key)}" if ci else "-"
        iqm = _cell(m["iqm"], key) if m["iqm"] is not None else "-"
        lines.append(f"| {name} | {iqm} | {shown} | {unit} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------- plot
def _on_grid(series: Any, grid: Any, column: int) -> Any:
    """``series [K, 3]`` (minutes, frames, value) held at its last value up to each of ``grid``
    (x in ``column``: 0 minutes, 1 frames); NaN before its first point and after its last."""
    import numpy as np

    xs = series[:, column]
    i = np.searchsorted(xs, grid, side="right") - 1
    y = series[np.clip(i, 0, None), 2].astype(np.float64)
    y[(i < 0) | (grid > xs[-1])] = np.nan
    return y


def render_seeds(runs: list[Run], x: str, width: int = 900, panel_h: int = 240) -> Any:
    """:data:`CURVES` over the seeds, median line and interquartile band, up to where the
    shortest run ends, stacked: ``[len(CURVES) * panel_h, width, 3]`` uint8 RGB."""
    import cv2
    import numpy as np

    column = 1 if x == "frames" else 0
    shift = {id(r): (0.0 if x == "frames" else r.demos_s / 60.0) for r in runs}
    font, grey = cv2.FONT_HERSHEY_SIMPLEX, (60, 60, 60)
    left, right, top, bottom = 70, width - 20, 30, panel_h - 40
    panels = []
    for tag, (title, (lo, hi)) in CURVES.items():
        img = np.full((panel_h, width, 3), 255, np.uint8)
        series = [
            r.scalars[tag] + np.array([shift[id(r)], 0.0, 0.0])
            for r in runs
            if tag in r.scalars and len(r.scalars[tag])
        ]
        x_max = min((float(s[-1, column]) for s in series), default=1.0) or 1.0  # all seeds
        grid = np.linspace(0.0, x_max, 300)
        ys = np.stack([_on_grid(s, grid, column) for s in series]) if series else None
        y_hi = hi if hi is not None else max(1.0, float(np.nanmax(ys)) if ys is not None else 1.0)
        span = (y_hi - lo) or 1.0

        def px(t: Any, y: Any, lo: float = lo, span: float = span, x_max: float = x_max) -> Any:
            return np.stack(
                (left + (right - left) * t / x_max, bottom - (bottom - top) * (y - lo) / span), -1
            )

        for frac in (0.0, 0.5, 1.0):
            yy = int(bottom - (bottom - top) * frac)
            cv2.line(img, (left, yy), (right, yy), (225, 225, 225), 1)
            cv2.putText(img, f"{lo + frac * span:.3g}", (5, yy + 4), font, 0.4, grey, 1)
        if ys is not None:
            ok = ~np.all(np.isnan(ys), axis=0)
            q1, med, q3 = np.nanpercentile(ys[:, ok], [25, 50, 75], axis=0)
            band = np.concatenate((px(grid[ok], q3), px(grid[ok], q1)[::-1]))
            shade = img.copy()
            cv2.fillPoly(shade, [np.round(band).astype(np.int32)], (190, 210, 255))
            img = cv2.addWeighted(shade, 0.6, img, 0.4, 0.0)
            line = np.round(px(grid[ok], med)).astype(np.int32)
            cv2.polylines(img, [line], False, (40, 90, 220), 2, cv2.LINE_AA)
        cv2.rectangle(img, (left, top), (right, bottom), (120, 120, 120), 1)
        label = f"{title}: median and interquartile band of {len(series)} seeds"
        cv2.putText(img, label, (left, 20), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
            v = x_max * frac / (1e6 if x == "frames" else 1.0)
            xx = int(left + (right - left) * frac)
            cv2.putText(img, f"{v:.3g}", (xx - 10, bottom + 16), font, 0.4, grey, 1)
        unit = "frames [M]" if x == "frames" else "wall-clock minutes from the run's start"
        cv2.putText(img, unit, (right - 10 * len(unit), bottom + 32), font, 0.4, grey, 1)
        panels.append(img)
    return np.concatenate(panels, axis=0)


# ------------------------------------------------------------------------------- the command
def provenance(argv: list[str], runs: list[Run]) -> dict:
    """The command (``argv``: its arguments), machine, the runs' recorded commit(s), date and
    torch threads."""
    import torch

    from truckrl.tools.stats import commit_of, machine

    commits = sorted({commit_of(r.source) or "unknown" for r in runs})
    return {
        "command": shlex.join([*PROG.split(), *argv]),
        "machine": machine(),
        "commit": ", ".join(commits),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "threads": torch.get_num_threads(),
    }


def run(cfg: AggregateConfig, argv: list[str]) -> dict:
    """Read and check every run, evaluate each checkpoint, print, write ``out`` (and ``plot``);
    return the JSON written. ``argv``: the command's arguments, as given (the provenance)."""
    from truckrl.cli import check_writable

    out = Path(cfg.out)
    check_writable(out, "out")
    if cfg.plot:
        check_writable(Path(cfg.plot), "plot")
    runs = [read_run(p, cfg.checkpoint) for p in find_runs(cfg.runs)]
    check_one_config(runs)
    runs.sort(key=lambda r: r.seed)

    import torch

    from truckrl.tools.stats import heldout_by_bin

    torch.set_num_threads(cfg.threads)
    heldouts, figures = [], []
    for r in runs:
        print(f"seed {r.seed}: {r.checkpoint} on {cfg.episodes} scenes of seed {cfg.seed} at "
              f"difficulty {cfg.difficulty:g}", flush=True)  # fmt: skip
        h = heldout_by_bin(str(r.checkpoint), cfg.difficulty, cfg.episodes, cfg.seed)
        heldouts.append(h)
        figures.append(per_seed_figures(r, h))
    data = result(runs, figures, heldouts, provenance(argv, runs), config_text(runs))
    print(f"\n{data['config']}; {len(runs)} seeds; held-out: {cfg.episodes} scenes of seed "
          f"{cfg.seed} at difficulty {cfg.difficulty:g}, {cfg.checkpoint}.pt\n")  # fmt: skip
    print(tables(data))
    out.write_text(json.dumps(data, indent=2) + "\n")
    print(f"\nwrote {out}")
    if cfg.plot:
        import cv2

        image = render_seeds(runs, cfg.x)
        if not cv2.imwrite(cfg.plot, cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise ConfigError(f"plot = {cfg.plot!r}: could not be written")
        print(f"wrote {cfg.plot}")
    return data


def main(argv: list[str] | None = None) -> int:
    from truckrl.cli import key_value_config, run_or_fail

    argv = sys.argv[1:] if argv is None else list(argv)
    cfg = key_value_config(AggregateConfig, argv, PROG, ABOUT)
    return run_or_fail(lambda c: run(c, argv), cfg)


if __name__ == "__main__":
    sys.exit(main())
