"""Evaluation results per scene category: summarise each bin of episodes, print the table.

A policy can look fine on average and still fail one kind of scene (right turns, sharp left turns
at a crossing). Each task says how its episodes split (``Task.category_bins``, :func:`task_bins`);
:func:`summarize_by_category` gives the outcome rates and p95 final errors of every non-empty
bin, and :func:`format_category_table` prints them. Pure torch: no TorchRL needed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from truckrl.config.fields import ConfigError
from truckrl.evaluation.interval import wilson_interval
from truckrl.tasks import Quantity, task_class
from truckrl.tasks.goals import POSE_ERRORS

#: Outcome flags of ``results`` (bool) and the name of their rate (``truncated`` = timeout).
OUTCOMES = {
    "success": "success",
    "collision": "collision",
    "jackknife": "jackknife",
    "truncated": "timeout",
}
#: Final errors of ``results`` and their units; rows report their p95.
ERRORS = {q.key: q.shown_unit for q in POSE_ERRORS}


def task_bins(task: str, info: Mapping[str, Tensor]) -> dict[str, dict[str, Tensor]] | None:
    """The category bins of task ``task``'s episodes (``Task.category_bins``), or None where it
    declares none."""
    return task_class(task).category_bins(info)


def category_mask(
    bins: Mapping[str, Mapping[str, Tensor]] | None,
    categories: tuple[str, ...],
    task: str,
    keep: Tensor,
) -> Tensor:
    """``keep`` (bool ``[E]``) and the masks of ``categories``, each ``"DIMENSION BIN"`` as the
    category table prints it, out of ``bins`` (``{dimension: {bin: bool [E]}}``).

    Raises:
        ConfigError: a category the task does not have (the message lists those it has).
    """
    named = {f"{dim} {b}": m for dim, group in (bins or {}).items() for b, m in group.items()}
    for c in categories:
        if c not in named:
            known = ", ".join(repr(n) for n in named) or "none"
            raise ConfigError(f"category = {c!r}: task {task!r} has the categories {known}")
        keep = keep & named[c].to(keep.device)
    return keep


def summarize_by_category(
    results: Mapping[str, Tensor],
    bins: Mapping[str, Mapping[str, Tensor]],
    errors: Sequence[Quantity] | None = None,
) -> list[dict]:
    """Outcome rates and p95 final errors of every bin with at least one episode.

    Args:
        results: per-episode ``[E]`` tensors: bool "success", "collision", "jackknife",
            "truncated" (timeout); float "pos_error" [m], "tractor_heading_error" and
            "trailer_heading_error" [deg] at the episode's last step.
        bins: ``{dimension: {bin: bool [E]}}``, e.g. from :func:`task_bins`.
        errors: the task's error quantities (``results`` holds them in their shown units);
            default the three pose errors (:data:`ERRORS`).

    Returns:
        One dict per non-empty bin, in the order of ``bins``: "dimension", "bin", "count" (int),
        "success_rate", "collision_rate", "jackknife_rate", "timeout_rate" (fractions in [0, 1]),
        "success_ci95" (``[lo, hi]``, the success rate's 95 % interval:
        :func:`~truckrl.evaluation.interval.wilson_interval`),
        "pos_error_m_p95", "tractor_heading_error_deg_p95", "trailer_heading_error_deg_p95"
        (linear-interpolated 95th percentile, as :func:`torch.quantile`); with ``errors``,
        ``"<key>_<shown unit>_p95"`` for each.
    """
    units = ERRORS if errors is None else {q.key: q.shown_unit for q in errors}
    missing = [k for k in (*OUTCOMES, *units) if k not in results]
    if missing:
        raise KeyError(f"summarize_by_category: results lack {', '.join(missing)}")
    n = results["success"].shape
    dev = results["success"].device
    rows = []
    for dim, named in bins.items():
        for name, mask in named.items():
            if mask.shape != n:
                raise ValueError(
                    f"summarize_by_category: bin {dim!r}/{name!r} has shape {tuple(mask.shape)}, "
                    f"results {tuple(n)}"
                )
            mask = mask.to(dev, torch.bool)
            count = int(mask.sum())
            if count == 0:
                continue
            row: dict = {"dimension": dim, "bin": name, "count": count}
            for key, rate in OUTCOMES.items():
                row[f"{rate}_rate"] = results[key][mask].to(torch.float64).mean().item()
            row["success_ci95"] = list(wilson_interval(int(results["success"][mask].sum()), count))
            for key, unit in units.items():
                v = results[key][mask].to(torch.float64)
                row[f"{key}_{unit}_p95"] = torch.quantile(v, 0.95).item()
            rows.append(row)
    return rows


#: Rate columns of :func:`format_category_table`: header, row key, width, format.
_COLUMNS = (
    ("n", "count", 6, "d"),
    ("success %", "success_rate", 10, "pct"),
    ("95 % interval", "success_ci95", 15, "ci"),
    ("collision %", "collision_rate", 12, "pct"),
    ("jack-knife %", "jackknife_rate", 13, "pct"),
    ("timeout %", "timeout_rate", 10, "pct"),
)


def _error_columns(rows: Sequence[Mapping]) -> list[tuple[str, str, int, str]]:
    """One column per ``<key>_<unit>_p95`` entry of the rows: ``"p95 pos m"``, ..."""
    cols = []
    for key in rows[0] if rows else ():
        if key.endswith("_p95"):
            name, _, unit = key[: -len("_p95")].rpartition("_")
            title = f"p95 {name.removesuffix('_error').replace('_', ' ')} {unit}"
            cols.append((title, key, len(title) + 2, ".2f" if unit == "m" else ".1f"))
    return cols


def format_category_table(rows: Sequence[Mapping]) -> str:
    """Fixed-width text table of :func:`summarize_by_category` rows (rates in %, then the p95
    of every error; the dimension named on the first row of its group)."""
    columns = (*_COLUMNS, *_error_columns(rows))
    w_dim = max([len("dimension"), *(len(str(r["dimension"])) for r in rows)])
    w_bin = max([len("bin"), *(len(str(r["bin"])) for r in rows)])
    header = f"{'dimension':<{w_dim}}  {'bin':<{w_bin}}" + "".join(
        f"{title:>{width}}" for title, _, width, _ in columns
    )
    lines = [header, "-" * len(header)]
    previous = None
    for r in rows:
        dim = str(r["dimension"])
        line = f"{dim if dim != previous else '':<{w_dim}}  {r['bin']!s:<{w_bin}}"
        previous = dim
        for _, key, width, fmt in columns:
            v = r.get(key) if fmt == "ci" else r[key]
            if fmt == "pct":
                line += f"{100.0 * v:>{width}.1f}"
            elif fmt == "ci":  # rows written before the interval was: from count and rate
                lo, hi = v or wilson_interval(r["success_rate"] * r["count"], r["count"])
                line += f"{f'{100.0 * lo:.1f}-{100.0 * hi:.1f}':>{width}}"
            else:
                line += f"{v:>{width}{fmt}}"
        lines.append(line)
    if not rows:
        lines.append("(no episodes)")
    return "\n".join(lines)
