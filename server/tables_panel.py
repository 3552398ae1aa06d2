"""The Tables tab: the paper's tables over the runs this browser pools (all runs, the runs it
compares, or those matching its filter), optionally a row per run and the paper's numbers,
each table with its pooled runs listed and a CSV download."""

from __future__ import annotations

import threading
from typing import Any

import viser

from detach import TABLES
from detach.runfolder.names import EVAL_GLOB
from server.session import Panel, Session, chosen, is_quiet
from server.table_views import build_tables, table_csv, table_html

SCOPES = ("all runs", "runs to compare", "runs matching the filter")


def tables_panel(s: Session) -> Panel:
    gui = s.gui
    quiet = threading.local()
    scope = gui.add_dropdown("Pool", SCOPES, initial_value=SCOPES[0],
                             hint=f"which runs' {EVAL_GLOB} files the tables pool")
    per_run = gui.add_checkbox("One row per run", False,
                               hint="each pooled run's own row under its pooled row")
    paper = gui.add_checkbox("Paper's numbers", True, hint="the paper's Tables I-III as "
                             "reference rows")
    s.add_wide_toggle()
    head = gui.add_markdown("")
    bodies = {name: gui.add_html("") for name in TABLES}
    download = gui.add_button_group("Download CSV", tuple(TABLES))
    state: dict[str, Any] = {"key": None, "tables": {}}

    def pooled_ids() -> list[str]:
        which = chosen(scope, SCOPES, SCOPES[0])
        if which == SCOPES[1]:
            return [r for r in s.selected if r in s.infos]
        if which == SCOPES[2]:
            return [r for r in s.filtered if r in s.infos]
        return list(s.infos)

    def update(force: bool = False) -> None:
        ids = pooled_ids()
        key = (tuple((r, s.infos[r].eval_version) for r in ids), bool(per_run.value),
               bool(paper.value), tuple(s.labels.get(r, r) for r in ids))
        if key == state["key"] and not force:
            return
        state["key"] = key
        evals = s.index.evals_by_run(ids)
        tables = build_tables(evals, s.labels, per_run=bool(per_run.value),
                              paper=bool(paper.value))
        state["tables"] = tables
        files = len(evals)
        text = (f"{files} evaluation file(s) (`{EVAL_GLOB}`) of {len({r for r, _e in evals})} "
                f"run(s) out of {len(ids)} pooled: a rate is over all their trials, with its "
                f"confidence interval; `n` counts trials and seeds." if evals else
                f"*No `{EVAL_GLOB}` files among these runs yet.*")
        if head.content != text:
            head.content = text
        for name, html in bodies.items():
            content = table_html(tables[name], s.labels)
            if html.content != content:
                html.content = content

    def control_changed(_event: object) -> None:
        if not is_quiet(quiet):
            with s.lock:
                update()

    for control in (scope, per_run, paper):
        control.on_update(control_changed)

    @download.on_click
    def _(event: viser.GuiEvent) -> None:
        name = event.target.value
        shown = state["tables"].get(name) if name in TABLES else None
        if shown is not None and event.client is not None:
            event.client.send_file_download(f"{name}.csv", table_csv(shown).encode("utf-8"),
                                            save_immediately=True)

    def refresh(changed: set[str]) -> None:
        if changed or state["key"] is None:
            update()

    def selection_changed() -> None:
        if chosen(scope, SCOPES) == SCOPES[1]:
            update()

    def filter_changed() -> None:
        if chosen(scope, SCOPES) == SCOPES[2]:
            update()

    return Panel(refresh=refresh, selection_changed=selection_changed,
                 filter_changed=filter_changed)
