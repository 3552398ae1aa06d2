"""The dashboard: what all browsers share (the run index, its poll loop, the replay ticker,
the launcher) and one `Session` per connected browser (server.session).

Everything shown comes from run folders (server.run_index), so live runs, finished runs and
a copied runs/ folder look the same. The poll loop re-reads runs/ every `poll_s` seconds and
hands each browser only the runs that changed.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import viser

from server.curves_panel import curves_panel
from server.launch import Launcher, launch_panel
from server.replay import Ticker
from server.replay_panel import replay_panel
from server.run_index import RunIndex
from server.runs_panel import runs_panel
from server.session import NARROW, Panel, Session
from server.tables_panel import tables_panel

PANEL_WIDTH = NARROW
"""Pixels of the side column; each browser can widen it (curves' and tables' wide view)."""
SETTLED_PER_POLL = 20
"""Finished runs re-checked per poll (round-robin); new and live runs every poll."""


def layout(session: Session) -> list[Panel]:
    """One browser's tabs, one panel function each."""
    gui = session.gui
    panels = []
    tabs = gui.add_tab_group()
    with tabs.add_tab("Runs", viser.Icon.LIST):
        panels.append(runs_panel(session))
    with tabs.add_tab("Curves", viser.Icon.CHART_LINE):
        panels.append(curves_panel(session))
    with tabs.add_tab("Replay", viser.Icon.PLAYER_PLAY):
        panels.append(replay_panel(session))
    with tabs.add_tab("Tables", viser.Icon.TABLE):
        panels.append(tables_panel(session))
    if session.dashboard.allow_launch:
        with tabs.add_tab("Launch", viser.Icon.ROCKET):
            launch_panel(gui, session.dashboard.launcher)
    return panels


class Dashboard:
    """Shared state plus the poll loop; sessions are created as browsers connect."""

    def __init__(self, server: viser.ViserServer, runs_dir: Path, launcher: Launcher | None = None,
                 allow_launch: bool = False, poll_s: float = 1.0,
                 settled_per_poll: int | None = SETTLED_PER_POLL) -> None:
        self.server, self.runs_dir, self.poll_s = server, Path(runs_dir), poll_s
        self.allow_launch, self.launcher = allow_launch, launcher
        self.index = RunIndex(self.runs_dir, settled_per_refresh=settled_per_poll)
        self.ticker = Ticker()
        self.sessions: dict[int, Session] = {}
        self._lock = threading.RLock()
        self._poll_lock = threading.RLock()
        self._stop = threading.Event()
        server.gui.configure_theme(control_width="large", show_share_button=False)
        server.gui.main_panel.dock_right()  # a side column: the 3D view keeps the rest
        server.gui.main_panel.set_width(PANEL_WIDTH)
        server.scene.set_up_direction("+z")
        server.on_client_connect(self.connect)
        server.on_client_disconnect(self.disconnect)

    # --- browsers ---------------------------------------------------------------------------
    def connect(self, client: viser.ClientHandle) -> Session:
        """Build a browser's tabs; polls wait meanwhile, so it misses no change of runs/."""
        with self._poll_lock:
            session = Session(self, client, layout)
            with self._lock:
                self.sessions[client.client_id] = session
        return session

    def disconnect(self, client: viser.ClientHandle) -> None:
        with self._lock:
            session = self.sessions.pop(client.client_id, None)
        if session is not None:
            session.close()

    # --- the poll loop ----------------------------------------------------------------------
    def start(self) -> None:
        self.ticker.start()
        threading.Thread(target=self._poll_forever, name="poll", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()
        self.ticker.stop()

    def _poll_forever(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.poll()
            except Exception as exc:  # noqa: BLE001 - the dashboard must outlive a bad tick
                print(f"detach-dashboard: refresh failed: {exc!r}", flush=True)
            self._stop.wait(max(0.05, self.poll_s - (time.monotonic() - t0)))

    def poll(self) -> None:
        """One refresh: re-read what is due in runs/, then update every browser."""
        with self._poll_lock:
            self._poll()

    def _poll(self) -> None:
        self.index.refresh()
        changed = set(self.index.changed)
        infos = self.index.snapshot()
        with self._lock:
            sessions = list(self.sessions.values())
        for session in sessions:
            try:
                session.refresh(infos, changed)
            except Exception as exc:  # noqa: BLE001 - one browser's failure stays its own
                print(f"detach-dashboard: a browser's refresh failed: {exc!r}", flush=True)
        keep = set().union(*(s.open_runs() for s in sessions)) if sessions else set()
        self.index.close_logs_except(keep)
