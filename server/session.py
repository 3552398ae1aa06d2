"""One browser's dashboard: its tabs, and the state of every control it has.

Each connection gets its own GUI and 3D scene (viser's `client.gui` / `client.scene`), so
what one browser selects, filters, pins or replays never changes another browser's view.
Panels are built by one function each (server.runs_panel, curves_panel, replay_panel,
tables_panel, launch; laid out as tabs by server.app.layout) and return a `Panel`: what to do
when runs change (the poll loop calls `refresh` with the runs whose info changed, so an idle
dashboard sends nothing), when this browser's selection of runs to compare changes, and which
runs' logs it has open.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

import viser

from server.replay import Replay, Ticker
from server.run_index import RunIndex, RunInfo
from server.run_views import run_labels


class Shared(Protocol):
    """What every browser shares (server.app.Dashboard)."""

    index: RunIndex
    ticker: Ticker
    allow_launch: bool
    launcher: Any


WIDE, NARROW = 1100, 560
"""Side panel widths (px) of the wide view and the normal one (server.app.PANEL_WIDTH)."""


def _nothing(*_args: object) -> None:
    return None


@dataclass
class Panel:
    refresh: Callable[[set[str]], None] = _nothing
    """Called with the ids of runs whose info changed (or that appeared or disappeared)."""
    selection_changed: Callable[[], None] = _nothing
    """This browser's runs to compare changed."""
    filter_changed: Callable[[], None] = _nothing
    """This browser's filter of the Runs tab changed (`Session.filtered`)."""
    open_runs: Callable[[], set[str]] = field(default=lambda: set())
    """Runs whose logs this panel reads (the others' logs may be closed)."""
    close: Callable[[], None] = _nothing


def quietly(flag: threading.local, handle: object, **attrs: object) -> None:
    """Set GUI values from code without running the handlers meant for the user's changes
    (viser calls update callbacks synchronously on assignment)."""
    flag.on = True
    try:
        for name, value in attrs.items():
            if getattr(handle, name) != value:
                setattr(handle, name, value)
    finally:
        flag.on = False


def is_quiet(flag: threading.local) -> bool:
    return bool(getattr(flag, "on", False))


def chosen(handle: Any, options: Sequence[str], fallback: str | None = None) -> str | None:
    """The value of a dropdown if it is one of `options` (the server's own list, not the
    handle's, which a client can overwrite); otherwise `fallback`."""
    value = handle.value
    return value if isinstance(value, str) and value in options else fallback


class Session:
    """The state of one connected browser."""

    def __init__(self, dashboard: Shared, client: viser.ClientHandle,
                 layout: Callable[["Session"], list[Panel]]) -> None:
        self.dashboard, self.client, self.gui = dashboard, client, client.gui
        self.index: RunIndex = dashboard.index
        self.lock = threading.RLock()
        self.infos: dict[str, RunInfo] = self.index.snapshot()
        self.labels: dict[str, str] = run_labels(list(self.infos.values()))
        self.selected: list[str] = []
        self.filtered: list[str] = list(self.infos)
        """Runs matching this browser's filter box on the Runs tab."""
        self.replay: Replay | None = None
        """This browser's replay (set by the replay panel)."""
        self._wide_toggles: list[viser.GuiCheckboxHandle] = []
        self._wide_quiet = threading.local()
        self.panels: list[Panel] = []
        self._defaulted = False
        with self.lock:
            self.panels = layout(self)
            self.select(default_selection(list(self.infos.values())))
            self._refresh(set(self.infos))

    def refresh(self, infos: dict[str, RunInfo], changed: set[str]) -> None:
        """New run infos from the poll loop; panels redraw what depends on `changed`."""
        with self.lock:
            self.infos = infos
            if changed:
                self.labels = run_labels(list(infos.values()))
            gone = [r for r in self.selected if r not in infos]
            if gone:
                self.select([r for r in self.selected if r in infos])
            if not self._defaulted and infos:
                self.select(default_selection(list(infos.values())))
            self._refresh(changed)

    def _refresh(self, changed: set[str]) -> None:
        for panel in self.panels:
            panel.refresh(changed)

    def select(self, run_ids: Sequence[str]) -> None:
        """This browser's runs to compare (curves and tables)."""
        with self.lock:
            ids = [r for r in dict.fromkeys(run_ids) if r in self.infos]
            self._defaulted = self._defaulted or bool(self.infos)
            if ids != self.selected:
                self.selected = ids
                for panel in self.panels:
                    panel.selection_changed()

    def set_filtered(self, run_ids: Sequence[str]) -> None:
        """The runs matching this browser's filter box (the Tables tab can pool them)."""
        with self.lock:
            ids = list(run_ids)
            if ids != self.filtered:
                self.filtered = ids
                for panel in self.panels:
                    panel.filter_changed()

    def add_wide_toggle(self) -> viser.GuiCheckboxHandle:
        """A 'Wide view' checkbox (curves and tables have one each, kept in step): a wider
        side panel for this browser only."""
        box = self.gui.add_checkbox("Wide view", bool(self._wide_toggles and
                                                      self._wide_toggles[0].value),
                                    hint="a wider side panel (this browser only)")

        @box.on_update
        def _(_event: object) -> None:
            if is_quiet(self._wide_quiet):
                return
            self.gui.main_panel.set_width(WIDE if box.value else NARROW)
            for other in self._wide_toggles:
                quietly(self._wide_quiet, other, value=box.value)

        self._wide_toggles.append(box)
        return box

    def open_runs(self) -> set[str]:
        with self.lock:
            return set().union(*(p.open_runs() for p in self.panels))

    def close(self) -> None:
        with self.lock:
            for panel in self.panels:
                panel.close()


def default_selection(infos: Sequence[RunInfo]) -> list[str]:
    """The newest run that has a log (else the newest run): something to show at once."""
    if not infos:
        return []
    with_log = [i.run_id for i in infos if i.has_log]
    return [(with_log or [infos[-1].run_id])[-1]]
