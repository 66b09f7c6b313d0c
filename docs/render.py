"""Render the committed result and benchmark JSON under ``docs/data/`` into Markdown fragments.

    python docs/render.py [--data docs/data] [--out docs/_generated]

``make docs`` runs it before ``sphinx-build``; the pages pull the fragments in with MyST's
``{include}`` directive. Each JSON file ``<data>/<group>/<name>.json`` becomes one fragment per
table, ``<out>/<group>/<name><suffix>.md``: the table, then one provenance line (command,
machine, commit, date, and threads or device where the file records them). A figure on a page
is therefore always the one in a committed file, with the command that measured it.

Kinds of file, told apart by their keys:

* ``"kind": "seeds"`` (``truckrl tools aggregate``): one metric per row with its interquartile
  mean, 95 % confidence interval and per-seed values (suffix ``""``), and the same per bin
  (``-bins``). All of them are also joined, in file-name order, into ``<out>/seeds.md``, which
  says which command writes one when there is none.
* ``"benchmark": "env"`` (``truckrl bench env``): env-steps/s per layout, eager and compiled
  (``""``); with ``parts=true``, the milliseconds per step of each part of the step (``-parts``).
* ``"benchmark": "train"`` (``truckrl bench train``): the median training iteration and its parts.
* ``"benchmark": "lidar"`` (``truckrl bench lidar``): time per scan (``""``), scans/s (``-scans``).
* ``"benchmark": "trainers"`` (``truckrl bench trainers``): one row per trainer and seed, by
  trainer: frames in the budget, frames/s, difficulty reached, held-out success at the fixed
  difficulty and at the one reached.
* ``"kind": "quality"``: minutes to a good policy, one row per training run: minutes and frames
  to difficulty 6 (``null`` where the run stopped below it, with ``difficulty_reached``), the
  best held-out check there, when the check first met the target
  (``quality_reached``) or that it did not before the run stopped, and the final checkpoint's
  held-out success.
* an evaluation (``truckrl eval``: ``success_rate`` and ``categories``): outcome rates and final
  errors (``""``), the same per scene category (``-bins``).

Provenance comes from the file's ``provenance`` object ``{"command", "machine", "commit",
"date"}`` (plus ``threads`` / ``device``). A file written before its command recorded one is read
from what it has: a benchmark's ``time``, ``machine`` and ``args``, an evaluation's own fields;
a command rebuilt that way is marked "reconstructed", a missing field reads "not recorded".
The output folder is emptied first, so a removed JSON file leaves no fragment behind.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from truckrl.evaluation.interval import wilson_interval

DOCS = Path(__file__).resolve().parent
DATA = DOCS / "data"
OUT = DOCS / "_generated"

#: Written to ``seeds.md`` while ``data/seeds/`` holds no aggregate: the command that makes one.
NO_SEEDS = (
    "No aggregate over seeds is committed yet. `truckrl tools aggregate runs=[RUN_DIR,...] "
    "out=docs/data/seeds/NAME.json` writes one from the run dirs of one config trained on "
    "several seeds; `python docs/render.py` then shows it here.\n"
)
#: Units whose values are fractions in [0, 1], shown as percentages (and any unit that starts
#: with "fraction", such as ``tools aggregate``'s "fraction of held-out scenes").
FRACTION_UNITS = {"fraction", "rate", "1", ""}


def is_fraction(unit: str) -> bool:
    """Whether values in ``unit`` are fractions in [0, 1]."""
    return unit in FRACTION_UNITS or unit.startswith("fraction")


def unit_name(unit: str) -> str:
    """A unit without its explanation in brackets: ``"min (wall clock ...)"`` -> ``"min"``."""
    return unit.split(" (")[0].strip()


Table = tuple[list[str], list[list[str]]]


# ---------------------------------------------------------------------------------- formatting
def pct(x: float | None) -> str:
    """A fraction in [0, 1] as ``"97.7 %"`` (one decimal); ``None`` as an en dash."""
    return "–" if x is None else f"{100 * x:.1f} %"


def interval(rate: float | None, n: int) -> str:
    """The 95 % interval of a success ``rate`` over ``n`` episodes (Wilson's, as ``truckrl eval``
    reports it; computed from the rate, so files written before eval recorded it show it too) as
    ``"94.6–95.8 %"``; ``None`` as an en dash."""
    if rate is None:
        return "–"
    lo, hi = wilson_interval(rate * n, n)
    return f"{100 * lo:.1f}–{100 * hi:.1f} %"


def num(x: float | None) -> str:
    """A measured value: thousands separated above 1,000 (``"407,458"``), else 3 significant
    digits (``"0.617"``, ``"5.3"``); ``None`` as an en dash."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if abs(x) >= 1000:
        return f"{x:,.0f}"
    return f"{x:.3g}"


def value(x: float | None, unit: str) -> str:
    """``x`` in ``unit``: a fraction as a percentage, a percentage as given, else :func:`num`."""
    if is_fraction(unit):
        return pct(x)
    if unit == "%":
        return "–" if x is None else f"{x:.1f} %"
    return num(x)


def cell(text: Any) -> str:
    """A table cell: pipes escaped, line breaks removed."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def markdown_table(header: list[str], rows: list[list[str]], right: int = 1) -> str:
    """A pipe table; the columns from index ``right`` on are right-aligned (numbers)."""
    align = ["---" if i < right else "---:" for i in range(len(header))]
    lines = ["| " + " | ".join(cell(h) for h in header) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def label(key: str) -> str:
    """A quantity key as a column label: ``"pos_error_m"`` -> ``"pos error [m]"``."""
    m = re.fullmatch(r"(.+?)_(m|deg|s|rad)", key)
    name, unit = (m.group(1), m.group(2)) if m else (key, "")
    return name.replace("_", " ") + (f" [{unit}]" if unit else "")


# ---------------------------------------------------------------------------------- provenance
def short_commit(commit: str) -> str:
    """A full 40-digit hash cut to 10 digits (a dirty flag or other text kept as is)."""
    return re.sub(r"\b([0-9a-f]{10})[0-9a-f]{30}\b", r"\1", commit)


def provenance_line(prov: dict[str, Any]) -> str:
    """The one line under a table: command, machine, device, threads, commit and date."""
    command = prov.get("command") or "not recorded"
    parts = [f"`{command}`" + (" (reconstructed)" if prov.get("reconstructed") else "")]
    machine = prov.get("machine") or "not recorded"
    if prov.get("load_avg_1min") is not None:  # a loaded machine's figures are not an idle one's
        machine += f", load average {prov['load_avg_1min']:.1f}"
    parts.append(f"machine: {machine}")
    if prov.get("device"):
        parts.append(f"device: {prov['device']}")
    if prov.get("threads"):
        parts.append(f"torch threads: {prov['threads']}")
    commit = prov.get("commit")
    parts.append(f"commit `{short_commit(commit)}`" if commit else "commit: not recorded")
    parts.append(f"date: {prov.get('date') or 'not recorded'}")
    return "*Provenance:* " + " · ".join(parts)


def _stamp_date(stamp: str | None) -> str | None:
    """A benchmark's ``time`` stamp ``YYYYmmdd-HHMMSS`` as ``YYYY-mm-dd HH:MM``."""
    m = re.fullmatch(r"(\d{4})(\d{2})(\d{2})-(\d{2})(\d{2})\d{2}", stamp or "")
    return f"{m[1]}-{m[2]}-{m[3]} {m[4]}:{m[5]}" if m else stamp


def _machine_text(machine: dict[str, Any]) -> str:
    """A benchmark's ``machine`` record in words: accelerator, cores, torch, load average."""
    what = machine.get("cuda") or "CPU"
    text = f"{what}, {machine.get('cpu_count')} CPU cores, torch {machine.get('torch')}"
    load = machine.get("load_avg")
    return text + (f", load average {load[0]:.1f}" if load else "")


def _kv(key: str, v: Any) -> str:
    """One ``KEY=VALUE`` argument as the commands spell it (lists without spaces)."""
    if isinstance(v, list | tuple):
        return f"{key}=[{','.join(str(x) for x in v)}]"
    if isinstance(v, bool):
        return f"{key}={str(v).lower()}"
    if isinstance(v, float):
        return f"{key}={v:g}"
    return f"{key}={v}"


#: Per benchmark, the ``args`` keys worth repeating in a rebuilt command (the rest are defaults
#: that do not change what is measured, or paths).
BENCH_KEYS = {
    "env": (
        "tasks",
        "envs",
        "parallel_envs",
        "workers",
        "steps",
        "warmup",
        "compile",
        "collector",
        "device",
        "parts",
    ),
    "train": ("iterations", "warmup"),
    "lidar": ("quick", "beams", "segments", "envs", "device", "compile"),
    "trainers": ("minutes", "seeds", "trainers", "task", "control", "envs", "episodes"),
}


def bench_command(doc: dict[str, Any]) -> str:
    """``truckrl bench NAME KEY=VALUE ...`` rebuilt from a benchmark record's ``args``."""
    name, args = doc["benchmark"], doc.get("args", {})
    words = ["truckrl", "bench", name, *args.get("overrides", [])]
    words += [_kv(k, args[k]) for k in BENCH_KEYS.get(name, ()) if k in args]
    if args.get("no_paper") or args.get("paper") is False:
        words.append("paper=false")
    if args.get("threads"):
        words.append(_kv("threads", args["threads"]))
    return " ".join(words)


def eval_command(doc: dict[str, Any]) -> str:
    """``truckrl eval ...`` rebuilt from an evaluation record."""
    words = ["truckrl", "eval"]
    if doc.get("policy") == "planner":
        words.append("policy=planner")
    ckpt = doc.get("checkpoint")
    if ckpt:
        m = re.search(r"tasks/(\w+)/pretrained\.pt$", ckpt)
        words.append(f"checkpoint=pretrained:{m[1]}" if m else f"checkpoint={ckpt}")
    words += [_kv(k, doc[k]) for k in ("difficulty", "episodes", "seed") if k in doc]
    words += [_kv(k, v) for k, v in (doc.get("env_overrides") or {}).items()]
    return " ".join(words)


def provenance(doc: dict[str, Any]) -> dict[str, Any]:
    """The file's ``provenance`` object, or what its other fields say (see the module doc)."""
    if isinstance(doc.get("provenance"), dict):
        return doc["provenance"]
    if "benchmark" in doc:
        machine = doc.get("machine", {})
        return {
            "command": bench_command(doc),
            "reconstructed": True,
            "machine": _machine_text(machine) if machine else None,
            "threads": machine.get("torch_threads"),
            "date": _stamp_date(doc.get("time")),
        }
    if "success_rate" in doc:
        return {"command": eval_command(doc), "reconstructed": True}
    return {}


# ------------------------------------------------------------------------------------- tables
def seeds_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``truckrl tools aggregate``: metric, IQM, 95 % CI, per-seed values, n seeds; then bins."""
    header = ["metric", "IQM", "95 % CI", "per seed", "n seeds"]

    def row(name: str, m: dict[str, Any], unit: str) -> list[str]:
        lo, hi = m.get("ci95") or (None, None)
        per = m.get("per_seed", {})
        seeds = sorted(per, key=lambda s: int(s) if str(s).lstrip("-").isdigit() else str(s))
        return [
            name,
            value(m.get("iqm"), unit),
            f"[{value(lo, unit)}, {value(hi, unit)}]",
            ", ".join(f"{s}: {value(per[s], unit)}" for s in seeds),
            str(len(per)),
        ]

    metrics = doc.get("metrics", {})
    rows = []
    for name, m in metrics.items():
        unit = m.get("unit", "")
        shown = name if is_fraction(unit) or unit == "%" else f"{name} [{unit_name(unit)}]"
        rows.append(row(shown, m, unit))
    tables = {"": (header, rows)}
    if doc.get("bins"):
        unit = metrics.get("heldout_success", {}).get("unit", "fraction")
        bins = [row(name, b, b.get("unit", unit)) for name, b in doc["bins"].items()]
        tables["-bins"] = (["bin", *header[1:]], bins)
    return tables


#: Row labels of ``bench env`` layouts.
ENV_LAYOUTS = {
    "paper": "paper layout: single-truck worker processes",
    "batched": "one batched TruckEnv",
    "parallel": "ParallelEnv of batched TruckEnvs",
    "collector": "Collector with the policy (frames/s)",
}


def env_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``bench env``: one row per layout and size, eager and compiled env-steps/s side by side,
    and the ratio to the paper's layout where the run measured it; a run over several tasks
    (``tasks=[...]``) leads each row with its task and ends it with its compiled ratio to the
    intersection task's row of the same layout (``x intersection``, as the run reports it)."""
    cells: dict[tuple, dict[bool, float]] = {}
    ratios: dict[tuple, float] = {}
    tasks = len({r.get("task") for r in doc["rows"]}) > 1
    for r in doc["rows"]:
        key = (r.get("task") if tasks else None, r["layout"], r["workers"], r["envs/worker"])
        cells.setdefault(key, {})[bool(r["compile"])] = r["steps/s"]
        if tasks and r.get("x intersection") is not None:
            ratios[key] = r["x intersection"]
    paper = doc.get("summary", {}).get("paper_layout_steps_per_s")
    header = ["layout", "processes × trucks", "eager", "compiled"]
    if tasks:
        header = ["task", *header, "× intersection"]
    if paper:
        header.append("best × paper layout")
    rows = []
    for key, by_mode in cells.items():
        task, layout, workers, per = key
        row = [
            ENV_LAYOUTS.get(layout, layout),
            f"{workers} × {per:,}",
            num(by_mode.get(False)),
            num(by_mode.get(True)),
        ]
        if tasks:
            row = [task, *row, pct(ratios[key]) if key in ratios else "–"]
        if paper:
            row.append(f"{max(by_mode.values()) / paper:,.1f}")
        rows.append(row)
    tables = {"": (header, rows)}
    parts = env_parts_table(doc, tasks)
    if parts is not None:
        tables["-parts"] = parts
    return tables


#: ``bench env parts=true``'s parts of a step (truckrl.env.timing), in the order shown.
ENV_PARTS = ("draw", "prepare", "restart", "transition", "other", "total")


def env_parts_table(doc: dict[str, Any], tasks: bool) -> Table | None:
    """``bench env parts=true``: ms per step of each part of each row that has them, and over
    several tasks the ratio to the first task's steps/s with the episode draws left out of both
    (as the run reports it); ``None`` without parts."""
    rows = [r for r in doc["rows"] if r.get("parts_ms")]
    if not rows:
        return None
    ref = next((k for k in rows[0] if k.startswith("x ") and k.endswith(" without draws")), None)
    header = [
        "task" if tasks else "trucks",
        "episode draws",
        "their preparation",
        "restarts",
        "transition",
        "the rest",
        "total",
    ]
    if tasks and ref:
        header.append(f"× {ref[2 : -len(' without draws')]}, draws left out")
    body = []
    for r in rows:
        ms = r["parts_ms"]
        row = [r["task"] if tasks else f"{r['trucks']:,}", *(f"{ms[k]:.2f}" for k in ENV_PARTS)]
        if tasks and ref:
            row.append(pct(r.get(ref)))
        body.append(row)
    return header, body


#: ``bench train``'s per-iteration spans, in the order shown.
TRAIN_PARTS = ("collect_s", "gae_s", "loss_forward_s", "backward_s", "optimizer_s")


def train_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``bench train``: the median timed iteration: batch, frames/s and where its time goes."""
    cfg, med = doc.get("config", {}), doc["summary"]["median"]
    parts = {
        "collect_s": "collection",
        "gae_s": "GAE",
        "loss_forward_s": "loss forward",
        "backward_s": "backward",
        "optimizer_s": "optimizer",
    }
    header = ["trucks × steps", "epochs × minibatches", "frames/s", "iteration [s]"]
    header += [f"{parts[p]} [s]" for p in TRAIN_PARTS]
    timed = [r for r in doc.get("rows", []) if isinstance(r.get("iteration"), int)]
    row = [
        f"{cfg.get('workers', 1) * cfg.get('num_envs', 0):,} × {cfg.get('steps_per_env')}",
        f"{cfg.get('num_epochs')} × {cfg.get('num_minibatches')}",
        num(med["frames/s"]),
        num(med["total_s"]),
        *(num(med.get(p)) for p in TRAIN_PARTS),
    ]
    header.insert(0, "timed iterations")
    row.insert(0, str(len(timed)))
    return {"": (header, [row])}


def lidar_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``bench lidar``: ms per scan of one scene per implementation; batched scans/s over N."""
    per_scan = [
        [
            str(r["R"]),
            str(r["E"]),
            num(r.get("oracle_ms")),
            num(r.get("sweep_ms")),
            num(r.get("batched_ms")),
            f"{r['sweep_speedup']:.1f} ×" if r.get("sweep_speedup") else "–",
        ]
        for r in doc["per_scan"]
    ]
    scans = [
        [
            f"{r['N']:,}",
            num(r.get("batched_scans_per_s")),
            num(r.get("compiled_scans_per_s")),
            num(max(r.get("batched_vs_sweep", 0), r.get("compiled_vs_sweep", 0))) + " ×",
        ]
        for r in doc["throughput"]
    ]
    sweep = doc.get("sweep_scans_per_s_R16_E64")
    return {
        "": (
            [
                "beams R",
                "segments E",
                "oracle [ms]",
                "sweep [ms]",
                "batched [ms]",
                "sweep × oracle",
            ],
            per_scan,
        ),
        "-scans": (
            [
                "envs N",
                "batched scans/s",
                "compiled scans/s",
                f"best × sweep ({num(sweep)} scans/s)",
            ],
            scans,
        ),
    }


def eval_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``truckrl eval``: outcome rates and the mean / p95 of each final error; then per bin."""
    errors = [
        k.removesuffix("_mean") for k in doc if k.endswith("_mean") and f"{k[:-5]}_p95" in doc
    ]
    tol = f"{doc['tolerance_position_m']:.3g} m, {doc['tolerance_heading_deg']:.3g}°"
    header = ["difficulty (tolerance)", "episodes", "success", "95 % interval", "collision"]
    header += ["jack-knife", "timeout", *(f"{label(e)} mean / p95" for e in errors)]
    row = [
        f"{doc['difficulty']:g} ({tol})",
        f"{doc['episodes']:,}",
        pct(doc.get("success_rate")),
        interval(doc.get("success_rate"), doc["episodes"]),
        *(pct(doc.get(k)) for k in ("collision_rate", "jackknife_rate")),
        pct(doc.get("timeout_rate")),
        *(f"{num(doc[e + '_mean'])} / {num(doc[e + '_p95'])}" for e in errors),
    ]
    tables = {"": (header, [row])}
    cats = doc.get("categories") or []
    if cats:
        rows, last = [], None
        for c in cats:
            dim = c["dimension"] if c["dimension"] != last else ""
            last = c["dimension"]
            rates = ("collision_rate", "jackknife_rate", "timeout_rate")
            success = c.get("success_rate")
            rows.append([dim, c["bin"], f"{c['count']:,}", pct(success),
                         interval(success, c["count"]), *(pct(c.get(k)) for k in rates)])  # fmt: skip
        header = ["dimension", "bin", "episodes", "success", "95 % interval", "collision"]
        header += ["jack-knife", "timeout"]
        tables["-bins"] = (header, rows)
    sm = doc.get("smoothness")
    if sm:
        pcts = sorted({int(k.rsplit("_p", 1)[1]) for k in sm if "_p" in k})
        quantities = list(dict.fromkeys(k.rsplit("_p", 1)[0] for k in sm if "_p" in k))
        header = [f"magnitude over {sm['steps']:,} steps of successes", *(f"p{q}" for q in pcts)]
        rows = []
        for q in quantities:  # "<name>_<unit>", units hold no underscore
            name, unit = q.rsplit("_", 1)
            rows.append(
                [f"{name.replace('_', ' ')} [{unit}]", *(num(sm[f"{q}_p{p}"]) for p in pcts)]
            )
        tables["-smoothness"] = (header, rows)
    return tables


def quality_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """Minutes to a good policy: one row per run (see the module doc)."""
    target = doc["target"]
    goal = f"{pct(target['success'])} at {target['difficulty']:g}"
    header = ["seed", "device", "minutes (frames) to difficulty 6", "best held-out check at 6",
              f"held-out ≥ {goal}", "stopped", "final held-out success"]  # fmt: skip
    rows = []
    for r in doc["runs"]:
        checks = r.get("checks_at_6") or []
        best = max(checks, key=lambda c: c["success"], default=None)
        best_text = f"{pct(best['success'])} at {best['minutes']:.1f} min" if best else "none"
        q, stop = r.get("quality_reached"), r["stopped"]
        reached = (
            f"{q['minutes']:.1f} min ({q['frames'] / 1e6:.1f} M frames)"
            if q
            else f"not within {stop['minutes']:g} min"
        )
        final = r.get("final_heldout")
        if r.get("minutes_to_difficulty_6") is None:  # the run stopped below difficulty 6
            top = r.get("difficulty_reached")
            to_6 = "not reached" + (f" (stopped at {top:g})" if top is not None else "")
        else:
            to_6 = f"{r['minutes_to_difficulty_6']:.1f} ({r['frames_to_difficulty_6'] / 1e6:.1f} M)"
        rows.append([
            str(r["seed"]), r.get("device", ""),
            to_6, best_text, reached,
            f"{stop['minutes']:g} min, {stop['frames'] / 1e6:.1f} M frames ({stop['reason']})",
            f"{pct(final['success'])} of {final['episodes']:,} (seed {final['seed']})" if final else "",
        ])  # fmt: skip
    return {"": (header, rows)}


def trainers_tables(doc: dict[str, Any]) -> dict[str, Table]:
    """``bench trainers``: one row per run, grouped by trainer in the order the record names
    them, seeds ascending; a failed run reads "failed" with its exit status."""
    args = doc.get("args", {})
    fixed = args.get("eval_difficulty")
    header = ["trainer", "seed", "frames", "frames/s", "difficulty reached",
              f"held-out success at {fixed:g}" if fixed is not None else "held-out success",
              "held-out success at the difficulty reached"]  # fmt: skip
    order = {t: i for i, t in enumerate(args.get("trainers", ()))}
    runs = sorted(doc["rows"], key=lambda r: (order.get(r["trainer"], len(order)), r["seed"]))
    rows = []
    for r in runs:
        if "error" in r:
            rows.append([r["trainer"], str(r["seed"]), f"failed ({r['error']})", "", "", "", ""])
            continue
        rows.append([r["trainer"], str(r["seed"]), f"{r['frames']:,}", num(r["frames/s"]),
                     f"{r['difficulty']:g}", pct(r["success_fixed"]),
                     pct(r["success_reached"])])  # fmt: skip
    return {"": (header, rows)}


def kind_of(doc: dict[str, Any]) -> Callable[[dict[str, Any]], dict[str, Table]]:
    """The table maker for a JSON document, by its keys (see the module doc)."""
    if doc.get("kind") == "seeds":
        return seeds_tables
    if doc.get("kind") == "quality":
        return quality_tables
    makers = {"env": env_tables, "train": train_tables, "lidar": lidar_tables,
              "trainers": trainers_tables}  # fmt: skip
    if doc.get("benchmark") in makers:
        return makers[doc["benchmark"]]
    if "success_rate" in doc and "categories" in doc:
        return eval_tables
    raise ValueError(
        "not a seeds aggregate, a quality record, a bench env|train|lidar|trainers record or an "
        "evaluation"
    )


# ----------------------------------------------------------------------------------- rendering
def fragments(doc: dict[str, Any]) -> dict[str, str]:
    """Suffix -> Markdown fragment (one table and its provenance line) of one JSON document."""
    line = provenance_line(provenance(doc))
    out = {}
    for suffix, (header, rows) in kind_of(doc)(doc).items():
        right = 2 if header[:2] in (["dimension", "bin"], ["layout", "processes × trucks"]) else 1
        out[suffix] = markdown_table(header, rows, right) + "\n\n" + line + "\n"
    return out


def render(data: Path = DATA, out: Path = OUT) -> list[Path]:
    """Write every JSON file's fragments under ``out`` (emptied first) and ``seeds.md``; return
    the paths written. A file that cannot be read or rendered raises, naming it."""
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    written, seeds = [], []
    for path in sorted(data.rglob("*.json")):
        rel = path.relative_to(data).with_suffix("")
        try:
            doc = json.loads(path.read_text())
            frags = fragments(doc)
        except (ValueError, KeyError, TypeError) as err:
            raise SystemExit(f"{path}: {err}") from None
        for suffix, text in frags.items():
            target = out / rel.parent / f"{rel.name}{suffix}.md"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text)
            written.append(target)
        if doc.get("kind") == "seeds":
            title = f"### {doc.get('config') or rel.name}\n\n"
            seeds.append(title + "\n\n".join(frags.values()))
    index = out / "seeds.md"
    index.write_text("\n\n".join(seeds) if seeds else NO_SEEDS)
    written.append(index)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the JSON files")
    parser.add_argument("--out", type=Path, default=OUT, help="folder of the fragments")
    args = parser.parse_args(argv)
    written = render(args.data, args.out)
    print(f"wrote {len(written)} fragments to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
