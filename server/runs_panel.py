"""The Runs tab: filter and group the runs, pick the ones to compare, and look at one run in
detail (status with its failure reason, config, a diff against another run, stdout tail)."""

from __future__ import annotations

import threading

import viser

from detach.runfolder.names import CONFIG_FILE, STDOUT_FILE
from server.run_views import (
    GROUP_BY, config_diff, diff_markdown, filter_runs, runs_table, status_markdown,
)
from server.session import Panel, Session, chosen, is_quiet, quietly

MAX_BOXES = 40
"""Compare checkboxes shown at most (the newest runs matching the filter)."""
NO_RUN = "(no runs)"
NOTHING = "(nothing)"


def _small(markdown: str) -> str:
    """Markdown in a smaller font that scrolls sideways instead of wrapping."""
    return ("<div style='font-size:0.8em; overflow-x:auto; white-space:nowrap'>\n\n" + markdown
            + "\n\n</div>")


def _code(text: str) -> str:
    return "```\n" + (text.replace("```", "'''") or "(empty)") + "\n```"


def runs_panel(s: Session) -> Panel:
    gui = s.gui
    quiet = threading.local()
    filter_box = gui.add_text("Filter", "", hint="words the run id, task, model, s<seed>, "
                              "sweep cell or state must contain, e.g. 'lh1 detach'")
    group = gui.add_dropdown("Group by", GROUP_BY, initial_value="nothing")
    pick = gui.add_button_group("Compare", ("Shown", "Add shown", "None", "Newest"),
                                hint="Shown: the runs matching the filter")
    table = gui.add_markdown("*Reading the runs folder...*")
    boxes_folder = gui.add_folder("Runs to compare (curves and tables)")
    with boxes_folder:
        boxes_note = gui.add_markdown("")
    boxes: dict[str, viser.GuiCheckboxHandle] = {}
    with gui.add_folder("Run details"):
        run_dd = gui.add_dropdown("Details of", (NO_RUN,))
        status = gui.add_markdown("")
        diff_dd = gui.add_dropdown("Diff with", (NOTHING,))
        diff = gui.add_markdown("")
        with gui.add_folder(f"{CONFIG_FILE}", expand_by_default=False):
            config = gui.add_markdown("")
        with gui.add_folder(f"{STDOUT_FILE} (last lines)", expand_by_default=False):
            stdout = gui.add_markdown("")
    shown: dict[str, object] = {"table": None, "ids": (), "details": None, "diff": None,
                                "stdout": None}

    def visible() -> list:
        return filter_runs(list(s.infos.values()), filter_box.value)

    def redraw() -> None:
        infos = visible()
        s.set_filtered([i.run_id for i in infos])
        by = chosen(group, GROUP_BY, "nothing")
        text = _small(runs_table(infos, s.selected, by, total=len(s.infos)))
        if text != shown["table"]:
            table.content = shown["table"] = text
        update_boxes(infos)

    def update_boxes(infos: list) -> None:
        wanted = [i.run_id for i in infos][-MAX_BOXES:]
        for run_id in [r for r in boxes if r not in wanted]:
            boxes.pop(run_id).remove()
        with boxes_folder:
            for run_id in wanted:
                if run_id not in boxes:
                    box = gui.add_checkbox(s.labels.get(run_id, run_id),
                                           initial_value=run_id in s.selected, hint=run_id)
                    box.on_update(box_changed)
                    boxes[run_id] = box
        hidden = len(infos) - len(wanted)
        note = (f"{hidden} older matching run(s) have no box here: narrow the filter or use "
                f"'Shown'." if hidden > 0 else "")
        if boxes_note.content != note:
            boxes_note.content = note

    def box_changed(_event: object) -> None:
        if is_quiet(quiet):
            return
        with s.lock:
            ticked = {r for r, b in boxes.items() if b.value}
            keep = [r for r in s.selected if r not in boxes or r in ticked]
            s.select(keep + [r for r in boxes if r in ticked and r not in keep])

    @pick.on_click
    def _(event: viser.GuiEvent) -> None:
        with s.lock:
            choice = event.target.value
            if choice == "Shown":
                s.select(s.filtered)
            elif choice == "Add shown":
                s.select([*s.selected, *s.filtered])
            elif choice == "None":
                s.select([])
            elif choice == "Newest" and s.infos:
                s.select([list(s.infos)[-1]])

    @filter_box.on_update
    def _(_event: object) -> None:
        with s.lock:
            redraw()

    @group.on_update
    def _(_event: object) -> None:
        with s.lock:
            redraw()

    def details(force: bool = False) -> None:
        """Status, config, diff and stdout tail of the run picked in 'Run'."""
        run = chosen(run_dd, list(s.infos))
        info = s.infos.get(run) if run else None
        reader = s.index.reader(run) if run else None
        if info is None or reader is None:
            for handle in (status, config, diff, stdout):
                handle.content = ""
            shown["details"] = None
            return
        text = status_markdown(info)
        if text != status.content:
            status.content = text
        if force or shown["details"] != run:
            try:
                config.content = _code(reader.config_text())
            except OSError as exc:
                config.content = f"*{CONFIG_FILE} unreadable ({exc.strerror})*"
            except ValueError as exc:  # refused: a FIFO, a link out of the run, too large
                config.content = _code(f"{CONFIG_FILE} {getattr(exc, 'why', exc)}")
        tail = reader.stdout_tail()
        if force or tail != shown["stdout"]:
            stdout.content = _code(tail)
            shown["stdout"] = tail
        other = chosen(diff_dd, list(s.infos))
        if force or shown["details"] != run or shown["diff"] != other:
            diff.content = compare(run, other)
            shown["diff"] = other
        shown["details"] = run

    def compare(run: str, other: str | None) -> str:
        if other is None:
            return ""
        a, b = s.index.reader(run), s.index.reader(other)
        if a is None or b is None:
            return ""
        try:
            return diff_markdown(run, other, config_diff(a.config_text(), b.config_text()))
        except Exception as exc:  # noqa: BLE001 - an unreadable config is said, not raised
            return f"*cannot compare the configs ({exc.__class__.__name__}: {exc})*"

    @run_dd.on_update
    def _(_event: object) -> None:
        if not is_quiet(quiet):
            with s.lock:
                details(force=True)

    @diff_dd.on_update
    def _(_event: object) -> None:
        if not is_quiet(quiet):
            with s.lock:
                details()

    def refresh(changed: set[str]) -> None:
        ids = tuple(s.infos)
        if ids != shown["ids"]:
            shown["ids"] = ids
            keep = run_dd.value if run_dd.value in s.infos else (ids[-1] if ids else NO_RUN)
            quietly(quiet, run_dd, options=ids or (NO_RUN,), value=keep)
            other = diff_dd.value if diff_dd.value in s.infos else NOTHING
            quietly(quiet, diff_dd, options=(NOTHING, *ids), value=other)
        if changed or shown["table"] is None:
            redraw()
        run = chosen(run_dd, list(s.infos))
        if run is not None and (run in changed or shown["details"] != run):
            details()

    def selection_changed() -> None:
        for run_id, box in boxes.items():
            quietly(quiet, box, value=run_id in s.selected)
        redraw()

    return Panel(refresh=refresh, selection_changed=selection_changed)
