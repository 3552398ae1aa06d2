"""The Tables tab's content: the paper's tables (detach.eval.tables, the same functions as
`detach-run table`) over the runs the user pools, optionally one row per run under each pooled
row and the paper's own numbers as reference rows; rendered as HTML that does not wrap.

Which runs a pooled row holds is found by building the same table from each run's files
alone: a run belongs to the pooled rows its own rows are named like.
"""

from __future__ import annotations

import dataclasses
import html
from dataclasses import dataclass, field
from typing import Sequence

from detach import Cell, TABLES, Table
from detach.runfolder.eval_result import EvalResult
from server.paper_reference import SWAP_NOTE, reference_rows

LABEL_KEYS = ("experiment", "method")
"""Columns that name a row rather than hold a number."""


@dataclass
class ShownTable:
    """One table as displayed: its rows and what each row is."""

    name: str
    table: Table | None
    kinds: list[str] = field(default_factory=list)
    """Per row: 'pooled', 'run' (one run's own row) or 'paper'."""
    runs: dict[int, list[str]] = field(default_factory=dict)
    """Row index of a pooled row -> ids of the runs pooled into it."""
    error: str | None = None


def table_keys(table: Table) -> list[str]:
    """Column keys (`Table.keys`; the lower-case headers for a table without them)."""
    keys = getattr(table, "keys", None)
    return list(keys) if keys else [h.lower() for h in table.header]


def row_name(row: Sequence[str | Cell]) -> tuple[str, ...]:
    """The cells before the first number: what names a row (experiment, method)."""
    name = []
    for c in row:
        if isinstance(c, Cell):
            break
        name.append(c)
    return tuple(name)


def _reference(table: Table, name: str) -> list[list[str | Cell]]:
    keys = table_keys(table)
    rows = []
    for labels, numbers in reference_rows(name):
        row: list[str | Cell] = []
        for k in keys:
            if k in LABEL_KEYS:
                row.append(labels.get(k, ""))
            elif k in numbers:
                row.append(Cell(numbers[k], digits=1 if k == "time_s" else 2))
            else:
                row.append(Cell(None))
        rows.append(row)
    return rows


def one_trial_set(evals: Sequence[tuple[str, EvalResult]]) -> list[tuple[str, EvalResult]]:
    """The evaluations of one trial set (`detach.eval.trial_sets`), so that a run evaluated on
    both counts once: the held-out test trials where any run has them, else the development
    trials (as `detach-run table` reads a sweep)."""
    wanted = "test" if any(e.trial_set == "test" for _r, e in evals) else "development"
    return [(r, e) for r, e in evals if e.trial_set == wanted]


def build_tables(evals: Sequence[tuple[str, EvalResult]], labels: dict[str, str] | None = None,
                 per_run: bool = False, paper: bool = False) -> dict[str, ShownTable]:
    """Every table of `TABLES` over (run id, eval result) pairs. A table that cannot be
    built from these files carries the error instead (a malformed file must not crash)."""
    labels = labels or {}
    evals = one_trial_set(evals)
    run_ids = list(dict.fromkeys(r for r, _e in evals))
    out = {}
    for name, build in TABLES.items():
        try:
            pooled = build([e for _r, e in evals])
            own = {r: build([e for rr, e in evals if rr == r]).rows for r in run_ids}
        except Exception as exc:  # noqa: BLE001 - a malformed eval file is reported
            out[name] = ShownTable(name, None, error=f"{exc.__class__.__name__}: {exc}")
            continue
        shown = ShownTable(name, dataclasses.replace(pooled, rows=[]))
        for row in pooled.rows:
            members = [r for r in run_ids if any(row_name(o) == row_name(row) for o in own[r])]
            shown.runs[len(shown.table.rows)] = members
            shown.table.rows.append(row)
            shown.kinds.append("pooled")
            if per_run:
                for r in members:
                    for o in own[r]:
                        if row_name(o) == row_name(row):
                            prefix = len(row_name(o))
                            o = [*o[: prefix - 1], f"↳ {labels.get(r, r)}", *o[prefix:]]
                            shown.table.rows.append(o)
                            shown.kinds.append("run")
        if paper:
            for row in _reference(pooled, name):
                shown.table.rows.append(row)
                shown.kinds.append("paper")
        out[name] = shown
    return out


def _cell_html(c: str | Cell) -> str:
    if not isinstance(c, Cell):
        return html.escape(str(c))
    if c.value is None:
        return "-"
    d = c.digits
    main = f"{c.value:.{d}f}"
    extra = []
    spread = getattr(c, "spread", None)
    if spread is not None:
        extra.append(f"±{spread:.{d}f}")
    if c.low is not None and c.high is not None:
        extra.append(f"[{c.low:.{d}f}, {c.high:.{d}f}]")
    if not extra:
        return main
    return f"{main} <span style='color:#888;font-size:0.85em'>{' '.join(extra)}</span>"


ROW_STYLE = {"pooled": "", "run": "color:#666;font-size:0.9em",
             "paper": "font-style:italic;background:#f3f0e6"}


def table_html(shown: ShownTable, labels: dict[str, str] | None = None) -> str:
    """One table as HTML: cells never wrap (the panel scrolls sideways instead), intervals
    in small grey type, paper rows in italics, then which runs each pooled row holds."""
    labels = labels or {}
    if shown.table is None:
        return f"<p><b>{html.escape(shown.name)}</b>: could not be built ({html.escape(shown.error or '')})</p>"
    t = shown.table
    cell = "padding:2px 6px;white-space:nowrap;border-bottom:1px solid #e4e4e4"
    parts = [f"<p style='margin:6px 0 2px'><b>{html.escape(t.title)}</b></p>",
             "<div style='overflow-x:auto'><table style='border-collapse:collapse;font-size:0.8em'>",
             "<tr>" + "".join(f"<th style='{cell};text-align:left'>{html.escape(h)}</th>"
                              for h in t.header) + "</tr>"]
    for row, kind in zip(t.rows, shown.kinds):
        parts.append(f"<tr style='{ROW_STYLE[kind]}'>" + "".join(
            f"<td style='{cell}'>{_cell_html(c)}</td>" for c in row) + "</tr>")
    parts.append("</table></div>")
    if "pooled" not in shown.kinds:  # the paper's rows alone must not look like results
        parts.append("<p><i>(no evaluations for this table among these runs)</i></p>")
    pooled = [(i, runs) for i, runs in sorted(shown.runs.items())]
    if pooled:
        items = []
        for i, runs in pooled:
            names = ", ".join(html.escape(labels.get(r, r)) for r in runs)
            items.append(f"<li>{html.escape(' '.join(row_name(t.rows[i])))}: {len(runs)} run"
                         f"{'s' if len(runs) != 1 else ''} ({names})</li>")
        parts.append("<p style='font-size:0.75em;margin:2px 0'>Pooled runs:</p>"
                     f"<ul style='font-size:0.75em;margin:0'>{''.join(items)}</ul>")
    notes = list(getattr(t, "notes", []) or [])
    if "paper" in shown.kinds and shown.name == "generalization":
        notes.append(SWAP_NOTE)
    if notes:
        parts.append("".join(f"<p style='font-size:0.75em;color:#555;margin:2px 0'>"
                             f"{html.escape(n)}</p>" for n in notes))
    return "\n".join(parts)


def table_csv(shown: ShownTable) -> str:
    """The displayed rows as CSV (Table.to_csv: one column per key, rounded numbers)."""
    return shown.table.to_csv() if shown.table is not None else ""
