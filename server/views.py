"""Pure functions from run data to what the panels show (Markdown, plot arrays, tables).

Kept apart from the viser code so that tests check the content without a browser.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from detach.eval.tables import TABLES, Table
from detach.run_contract import EvalResult
from server.run_index import MetricSeries, RunInfo

PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")
MAX_POINTS = 1500
"""Points per curve sent to the browser; longer runs are decimated (every k-th iteration)."""


def _md(text: str) -> str:
    """Escape what would break a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def runs_table(infos: Sequence[RunInfo], now: float | None = None) -> str:
    """The runs panel: one row per run folder, newest last (folder names sort by time)."""
    if not infos:
        return "*No run folders yet.* New runs appear here as soon as they are created."
    now = time.time() if now is None else now
    lines = ["| # | run | task | model | seed | state | iter | LH SR | updated |",
             "| --: | --- | --- | --- | --: | --- | --: | --: | --: |"]
    for i, r in enumerate(infos, 1):
        state = f"**{r.shown_state}**" if r.unreadable or r.state == "failed" else r.state
        lines.append(" | ".join([
            f"| {i}", f"`{_md(short_id(r))}`", _md(r.task), _md(r.model),
            "-" if r.seed is None else str(r.seed), state,
            "-" if r.iteration is None else str(r.iteration),
            "-" if r.lh_sr is None else f"{r.lh_sr:.2f}",
            _age(r.updated, now)]) + " |")
    notes = [f"- `{_md(r.run_id)}` ({r.state}): " + "; ".join(_md(p) for p in r.problems)
             for r in infos if r.unreadable]
    notes += [f"- `{_md(r.run_id)}` {r.state}: {_md(r.error)}" for r in infos
              if r.error and not r.unreadable]
    if notes:
        lines += ["", "**Problems**", "", *notes]
    return "\n".join(lines) + "\n"


def short_id(info: RunInfo) -> str:
    """The run id without the '-<task>-<model>-s<seed>' that the table's columns repeat."""
    tail = f"-{info.task}-{info.model}-s{info.seed}"
    stamp, found, suffix = info.run_id.partition(tail)
    return stamp + suffix if found and stamp else info.run_id


def _age(t: float | None, now: float) -> str:
    if not isinstance(t, (int, float)):
        return "-"
    s = max(0.0, now - t)
    if s < 90:
        return f"{s:.0f} s ago"
    if s < 5400:
        return f"{s / 60:.0f} min ago"
    if s < 48 * 3600:
        return f"{s / 3600:.0f} h ago"
    return time.strftime("%Y-%m-%d", time.localtime(t))


def run_label(info: RunInfo | None, run_id: str) -> str:
    """Short legend label: model/task/seed, which is what runs are compared by."""
    if info is None or info.task == "?":
        return run_id
    return f"{info.model} {info.task} s{info.seed}"


def metric_group(key: str) -> str:
    """'loss/surrogate' -> 'loss'; keys without a prefix ('fps') form the group 'general'."""
    return key.split("/", 1)[0] if "/" in key else "general"


def curve_groups(series: dict[str, MetricSeries]) -> dict[str, list[str]]:
    """Numeric /metrics keys of the given runs, grouped by prefix (sorted, 'general' first)."""
    keys = sorted({k for s in series.values() for k in s.columns})
    groups: dict[str, list[str]] = {}
    for k in keys:
        groups.setdefault(metric_group(k), []).append(k)
    return dict(sorted(groups.items(), key=lambda kv: (kv[0] != "general", kv[0])))


@dataclass
class Curve:
    """One overlaid plot: x = union of the runs' iterations, one y array per run
    (NaN where a run has no value at that iteration, which uPlot leaves out)."""

    key: str
    x: np.ndarray
    ys: list[np.ndarray]
    labels: list[str]


def overlay(key: str, series: dict[str, MetricSeries], labels: dict[str, str],
            max_points: int = MAX_POINTS) -> Curve:
    """Align every run's `key` column on the union of iterations (decimated)."""
    runs = list(series)
    xs = [series[r].iterations for r in runs]
    x = np.unique(np.concatenate(xs)) if xs else np.zeros(0)
    if len(x) > max_points:
        step = int(np.ceil(len(x) / max_points))
        x = np.unique(np.concatenate([x[::step], x[-1:]]))
    ys = []
    for r in runs:
        s = series[r]
        y = np.full(len(x), np.nan)
        col = s.columns.get(key)
        if col is not None and len(s.iterations):
            idx = np.minimum(np.searchsorted(s.iterations, x), len(s.iterations) - 1)
            ok = s.iterations[idx] == x
            y[ok] = col[idx[ok]]
        ys.append(y)
    return Curve(key, x, ys, [labels.get(r, r) for r in runs])


def comparison_tables(evals: Sequence[EvalResult]) -> tuple[dict[str, Table], dict[str, str]]:
    """The tables `detach-run table` prints (detach.eval.tables.TABLES, same functions);
    a table that cannot be built from these files gives an error text instead."""
    tables, errors = {}, {}
    for name, build in TABLES.items():
        try:
            tables[name] = build(evals)
        except Exception as exc:  # noqa: BLE001 - a malformed eval file must not crash
            errors[name] = f"{exc.__class__.__name__}: {exc}"
    return tables, errors


def tables_markdown(tables: dict[str, Table], errors: dict[str, str] | None = None) -> str:
    parts = []
    for name, table in tables.items():
        md = table.to_markdown()
        if not table.rows:
            md += "\n*(no evaluations for this table among these runs)*\n"
        parts.append(md)
    for name, err in (errors or {}).items():
        parts.append(f"**{name}**: could not be built ({err})\n")
    return "\n".join(parts)
