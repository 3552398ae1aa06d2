"""`detach-run list`: one line per run folder, robust to half-written folders."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from detach.runs.folder import RunFolder, find_runs


def run_row(run: RunFolder) -> dict[str, Any]:
    """Task, model, seed, state, iteration and LH success rate of one run (or why not)."""
    row: dict[str, Any] = {"run": run.path.name}
    try:
        status = run.status()
        cfg = run.config()
    except Exception as exc:  # noqa: BLE001 - a broken folder is listed, not fatal
        row.update(state="unreadable", error=f"{exc.__class__.__name__}: {exc}")
        return row
    row.update(task=cfg.task_name, model=cfg.model_name, seed=cfg.seed,
               state=status.state, iteration=status.iteration)
    try:
        result = run.eval_result()
    except (OSError, ValueError):
        result = None
    row["lh_sr"] = result.lh_success.rate if result else None
    return row


def format_runs(rows: list[dict[str, Any]]) -> str:
    header = ["run", "task", "model", "seed", "state", "iteration", "LH SR"]
    lines = [header]
    for r in rows:
        sr = "-" if r.get("lh_sr") is None else f"{r['lh_sr']:.2f}"
        lines.append([r["run"], str(r.get("task", "-")), str(r.get("model", "-")),
                      str(r.get("seed", "-")), r["state"], str(r.get("iteration", "-")), sr])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    out = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines]
    out += [f"  {r['run']}: {r['error']}" for r in rows if r["state"] == "unreadable"]
    return "\n".join(out)


def print_runs(parent: Path) -> int:
    rows = [run_row(r) for r in find_runs(parent)]
    if not rows:
        print(f"no runs in {parent}/")
        return 0
    print(format_runs(rows))
    return 0
