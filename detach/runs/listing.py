"""`detach-run list`: one line per run folder, robust to half-written and broken folders.

A run whose status.json says `running` but whose process is gone (`kill -9`, a crashed
machine) is listed as `dead`, with the command that resumes it; a malformed eval.json shows
as `invalid` with its reason, and never stops the listing of the other runs; a failed run
shows the reason it failed with. The summary, the shown state and the checks of eval.json
are `detach.runfolder`'s, the ones the dashboard shows.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from detach.runfolder.checkpoints import has_checkpoint
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.liveness import DEAD, shown_state, this_host


def run_row(run: RunFolder) -> dict[str, Any]:
    """Task, model, seed, state, iteration and LH success rate of one run (or why not)."""
    row: dict[str, Any] = {"run": run.path.name}
    try:
        status = run.status()
        summary = run.summary()
    except Exception as exc:  # noqa: BLE001 - a broken folder is listed, not fatal
        row.update(state="unreadable", error=f"{exc.__class__.__name__}: {exc}")
        return row
    row.update(task=summary.task, model=summary.model, seed=summary.seed,
               state=status.state, iteration=status.iteration, run_id=status.run_id)
    if shown_state(status) == DEAD:
        where = f" on {status.host}" if status.host and status.host != this_host() else ""
        row["state"] = DEAD
        started = (f"resume with: detach-run --resume {run.path}" if has_checkpoint(run.path) else
                   f"no checkpoint yet: detach-run --resume {run.path} restarts it from iteration 0")
        row.setdefault("notes", []).append(f"status says {status.state}, but its process {status.pid}{where} "
                                           f"is gone; {started}")
    if status.state == "failed" and status.error:  # why, where the run itself said it (e.g. a refused init_from)
        row.setdefault("notes", []).append(f"failed: {status.error.splitlines()[0][:300]}")
    try:
        result = run.eval_result()
    except Exception as exc:  # noqa: BLE001 - one bad eval.json must not hide the other runs
        row["lh_sr"] = "invalid"
        row.setdefault("notes", []).append(f"{run.eval_path.name} ignored: {exc}")
        return row
    row["lh_sr"] = result.lh_success.rate if result else None
    return row


def _rate(value: Any) -> str:
    if value is None:
        return "-"
    return value if isinstance(value, str) else f"{value:.2f}"


def format_runs(rows: list[dict[str, Any]]) -> str:
    header = ["run", "task", "model", "seed", "state", "iteration", "LH SR"]
    lines = [header]
    for r in rows:
        lines.append([r["run"], str(r.get("task", "-")), str(r.get("model", "-")),
                      str(r.get("seed", "-")), r["state"], str(r.get("iteration", "-")), _rate(r.get("lh_sr"))])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    out = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines]
    out += [f"  {r['run']}: {r['error']}" for r in rows if r["state"] == "unreadable"]
    out += [f"  {r['run']}: {note}" for r in rows for note in r.get("notes", ())]
    return "\n".join(out)


def print_runs(parent: Path) -> int:
    rows = [run_row(r) for r in find_runs(parent)]
    if not rows:
        print(f"no runs in {parent}/")
        return 0
    first: dict[str, str] = {}
    for row in rows:  # a copied folder shares its run id: tables count it once
        if row.get("run_id"):
            original = first.setdefault(row["run_id"], row["run"])
            if original != row["run"]:
                row.setdefault("notes", []).append(f"copy of {original} (same run id); tables count it once")
    print(format_runs(rows))
    return 0
