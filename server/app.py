"""The dashboard's GUI: one function per panel, laid out as tabs; a poller keeps them current.

Everything shown comes from run folders (server.run_index), so live runs, finished runs and
a copied runs/ folder look the same. The GUI is shared by all connected browsers (one
selection, one replay), which suits a lab dashboard.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Callable

import viser
from viser import uplot

from detach.eval.tables import TABLES
from server.episode import Episode
from server.launch import launch_panel
from server.replay import ReplayThread
from server.run_index import RunIndex, RunInfo
from server.scene_view import SceneView
from server.views import (PALETTE, comparison_tables, curve_groups, overlay, run_label,
                          runs_table, tables_markdown)

NEWEST = "newest"
PANEL_WIDTH = 540
"""Pixels; wide enough for the tables with their confidence intervals."""


def _small(markdown: str) -> str:
    """Markdown in a smaller font that scrolls sideways instead of spilling over."""
    return ("<div style='font-size:0.8em; overflow-x:auto'>\n\n" + markdown
            + "\n\n</div>")


class Dashboard:
    """Shared state of the panels plus the poll loop (runs/ is re-read every `poll_s`)."""

    def __init__(self, server: viser.ViserServer, runs_dir: Path, allow_launch: bool = False,
                 poll_s: float = 1.0) -> None:
        self.server, self.runs_dir, self.poll_s = server, Path(runs_dir), poll_s
        self.index = RunIndex(self.runs_dir)
        self.infos: dict[str, RunInfo] = {}
        self.selected: list[str] = []
        self.lock = threading.RLock()
        self.view = SceneView(server)
        self.replay = ReplayThread(self._draw_frame)
        self.on_frame: Callable[[Episode, int], None] = lambda ep, i: None
        """Called after each drawn frame (the replay controls show time and subtask)."""
        self._stop = threading.Event()

        server.gui.configure_theme(control_width="large", show_share_button=False)
        server.gui.main_panel.dock_right()  # a side column: the 3D view keeps the rest
        server.gui.main_panel.set_width(PANEL_WIDTH)
        server.scene.set_up_direction("+z")
        tabs = server.gui.add_tab_group()
        with tabs.add_tab("Runs", viser.Icon.LIST):
            self.update_runs = runs_panel(self)
        with tabs.add_tab("Curves", viser.Icon.CHART_LINE):
            self.update_curves = curves_panel(self)
        with tabs.add_tab("Replay", viser.Icon.PLAYER_PLAY):
            self.update_scene = scene_panel(self)
            replay_controls(self)
        with tabs.add_tab("Tables", viser.Icon.TABLE):
            self.update_tables = tables_panel(self)
        if allow_launch:
            with tabs.add_tab("Launch", viser.Icon.ROCKET):
                launch_panel(server.gui, self.runs_dir)

    # --- loop ---------------------------------------------------------------------------
    def start(self) -> None:
        self.replay.start()
        threading.Thread(target=self._poll_forever, name="poll", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()
        self.replay.stop()

    def _poll_forever(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                self.poll()
            except Exception as exc:  # noqa: BLE001 - the dashboard must outlive a bad tick
                print(f"detach-dashboard: refresh failed: {exc!r}", flush=True)
            self._stop.wait(max(0.05, self.poll_s - (time.monotonic() - t0)))

    def poll(self) -> None:
        """One refresh of every panel from the run folders."""
        infos = self.index.refresh()
        with self.lock:
            self.infos = {i.run_id: i for i in infos}
            self.update_runs(infos)
            self.update_curves()
            self.update_tables()
            self.update_scene(infos)

    def set_selection(self, run_ids: list[str]) -> None:
        with self.lock:
            if run_ids != self.selected:
                self.selected = run_ids
                self.update_curves()
                self.update_tables()

    def _draw_frame(self, episode: Episode, i: int) -> None:
        skill = episode.skill[i]
        text = f"subtask {episode.subtask[i]}: {skill}" if skill else ""
        self.view.set_frame(episode, i, text)
        self.on_frame(episode, i)


def runs_panel(d: Dashboard) -> Callable[[list[RunInfo]], None]:
    """All runs as a Markdown table, plus one checkbox per run to pick runs to compare."""
    gui = d.server.gui
    table = gui.add_markdown("*Reading the runs folder...*")
    folder = gui.add_folder("Compare (curves and tables)")
    with folder:
        pick = gui.add_button_group("Select", ("All", "None", "Newest"))
    boxes: dict[str, viser.GuiCheckboxHandle] = {}
    first = [True]
    quiet = threading.local()

    def selection_changed(_event: object = None) -> None:
        if not getattr(quiet, "on", False):
            d.set_selection([r for r, b in boxes.items() if b.value])

    @pick.on_click
    def _(event: viser.GuiEvent) -> None:
        choice = event.target.value
        newest = max(boxes, default=None)
        for run_id, box in boxes.items():  # one selection change, not one per box
            _quietly(quiet, box, value=choice == "All" or (choice == "Newest"
                                                           and run_id == newest))
        selection_changed()

    def update(infos: list[RunInfo]) -> None:
        text = _small(runs_table(infos))
        if table.content != text:
            table.content = text
        ids = {i.run_id for i in infos}
        for gone in [r for r in boxes if r not in ids]:
            boxes.pop(gone).remove()
        if first[0] and infos:  # start with the newest run that has something to show
            with_log = [i.run_id for i in infos if i.log_version] or [infos[-1].run_id]
            default = with_log[-1]
        with folder:
            for info in infos:
                if info.run_id not in boxes:
                    initial = first[0] and info.run_id == default
                    box = gui.add_checkbox(info.run_id, initial_value=initial,
                                           hint=f"{info.model} on {info.task}, seed {info.seed}")
                    box.on_update(selection_changed)
                    boxes[info.run_id] = box
        if infos and first[0]:
            first[0] = False
            selection_changed()
        elif any(r not in ids for r in d.selected):
            selection_changed()

    return update


def curves_panel(d: Dashboard) -> Callable[[], None]:
    """Every numeric /metrics key of the selected runs, one uPlot per key, runs overlaid,
    grouped in folders by prefix (loss/, reward/, success/, ...); x = iteration."""
    gui = d.server.gui
    hint = gui.add_markdown("")
    holder = gui.add_folder("Training curves")
    state: dict[str, object] = {"layout": None, "versions": None}
    plots: dict[str, viser.GuiUplotHandle] = {}
    folders: list[viser.GuiFolderHandle] = []

    def update() -> None:
        readers = {r: d.index.reader(r) for r in d.selected}
        series = {r: rd.series() for r, rd in readers.items() if rd is not None}
        series = {r: s for r, s in series.items() if len(s.iterations)}
        labels = {r: run_label(d.infos.get(r), r) for r in series}
        groups = curve_groups(series)
        layout = (tuple(labels.items()), tuple((g, tuple(k)) for g, k in groups.items()))
        versions = tuple(d.infos[r].log_version if r in d.infos else 0 for r in series)
        text = ("Tick runs in the **Runs** tab to plot their curves." if not d.selected else
                "The selected runs have no /metrics messages yet." if not series else
                f"{len(series)} run(s), x = iteration: "
                + ", ".join(f"<span style='color:{PALETTE[i % len(PALETTE)]}'>{labels[r]}</span>"
                            for i, r in enumerate(series)))
        if hint.content != text:
            hint.content = text
        if layout != state["layout"]:
            for f in folders:
                f.remove()
            folders.clear()
            plots.clear()
            with holder:
                for n, (group, keys) in enumerate(groups.items()):
                    with gui.add_folder(group, expand_by_default=n < 3) as f:
                        folders.append(f)
                        for key in keys:
                            plots[key] = _add_plot(gui, overlay(key, series, labels))
            state["layout"], state["versions"] = layout, versions
        elif versions != state["versions"]:
            for key, plot in plots.items():
                c = overlay(key, series, labels)
                plot.data = (c.x, *c.ys)
            state["versions"] = versions

    return update


def _add_plot(gui: viser.GuiApi, c) -> viser.GuiUplotHandle:
    series = [uplot.Series(label="iteration")] + [
        uplot.Series(label=lbl, stroke=PALETTE[i % len(PALETTE)], width=1.5, spanGaps=True)
        for i, lbl in enumerate(c.labels)]
    return gui.add_uplot(data=(c.x, *c.ys), series=tuple(series), title=c.key,
                         scales={"x": uplot.Scale(time=False)}, aspect=2.0)


def scene_panel(d: Dashboard) -> Callable[[list[RunInfo]], None]:
    """Which run (and episode) the 3D view shows; the scene is redrawn when it changes and
    the newest episode of a live run is streamed as its log grows."""
    gui = d.server.gui
    run_dd = gui.add_dropdown("Run", ("(no runs)",))
    episode_dd = gui.add_dropdown("Episode", (NEWEST,),
                                  hint="'newest' follows a live run's newest episode")
    info = gui.add_markdown("")
    shown: dict[str, object] = {"run": None, "log": -1, "episode": None, "frames": 0,
                                "scene": None}
    quiet = threading.local()

    def open_episode(keep_time: bool = False) -> None:
        reader = d.index.reader(str(shown["run"]))
        choice = episode_dd.value
        ep, shown["problem"] = None, None
        try:
            if reader is not None:
                ep = reader.log.load_episode(None if choice == NEWEST else int(choice))
            if ep is not None:
                d.view.check_episode(ep)
        except Exception as exc:  # noqa: BLE001 - malformed frames: say so, keep serving
            ep, shown["problem"] = None, f"episode frames unreadable ({exc!r:.160})"
        live = bool(d.infos.get(str(shown["run"])) and d.infos[str(shown["run"])].live)
        d.replay.player.hold_at_end = live and choice == NEWEST
        shown["episode"] = None if ep is None else ep.number
        shown["frames"] = 0 if ep is None else ep.num_frames
        d.replay.set_episode(ep, keep_time)
        describe(ep)

    def describe(ep: Episode | None) -> None:
        run = str(shown["run"])
        r = d.infos.get(run)
        lines = [f"**{run}**" + (f" ({r.state})" if r else "")]
        lines.append("no /episode/bodies frames in this log" if ep is None else
                     f"episode {ep.number}: {ep.num_frames} frames, "
                     f"{ep.times[-1] - ep.times[0]:.1f} s")
        lines += [f"- {n}" for n in [*d.view.notes, shown.get("problem")] if n]
        info.content = "\n\n".join(lines[:2]) + ("\n\n" + "\n".join(lines[2:]) if
                                                 lines[2:] else "")

    def open_run(run_id: str) -> None:
        with d.lock, d.replay.lock:
            reader = d.index.reader(run_id)
            shown.update(run=run_id, log=-1 if reader is None else reader.log.version,
                         scene=None if reader is None else reader.log.scene,
                         chunks=None if reader is None else len(reader.log.chunks))
            d.view.show(None if reader is None else reader.log.scene,
                        d.runs_dir / run_id)
            numbers = [] if reader is None else reader.log.episode_numbers()
            _quietly(quiet, episode_dd, options=(NEWEST, *map(str, numbers)))
            open_episode()

    @run_dd.on_update
    def _(_event: object) -> None:
        if not getattr(quiet, "on", False) and run_dd.value in d.infos \
                and run_dd.value != shown["run"]:
            open_run(run_dd.value)

    @episode_dd.on_update
    def _(_event: object) -> None:
        if not getattr(quiet, "on", False) and shown["run"] is not None:
            with d.lock, d.replay.lock:
                open_episode()

    def update(infos: list[RunInfo]) -> None:
        ids = tuple(i.run_id for i in infos) or ("(no runs)",)
        if shown["run"] not in d.infos and infos:  # first run, or the shown one was deleted
            with_log = [i.run_id for i in infos if i.log_version] or [infos[-1].run_id]
            _quietly(quiet, run_dd, options=ids, value=with_log[-1])
            open_run(with_log[-1])
            return
        if tuple(run_dd.options) != ids:
            _quietly(quiet, run_dd, options=ids)
        r = d.infos.get(str(shown["run"]))
        if r is None or r.log_version == shown["log"]:
            return
        reader = d.index.reader(r.run_id)
        if reader is None or reader.log.scene != shown["scene"]:
            open_run(r.run_id)  # the scene arrived (or an evaluation logged another one)
            return
        shown["log"] = r.log_version
        if len(reader.log.chunks) == shown.get("chunks"):
            return  # only metrics arrived
        shown["chunks"] = len(reader.log.chunks)
        options = (NEWEST, *map(str, reader.log.episode_numbers()))
        if tuple(episode_dd.options) != options:
            _quietly(quiet, episode_dd, options=options)
        if episode_dd.value == NEWEST:  # stream the newest episode of a growing log
            with d.replay.lock:  # same episode: keep playing from where it was
                open_episode(keep_time=reader.log.newest_episode() == shown["episode"])

    return update


def _quietly(flag: threading.local, handle: object, **attrs: object) -> None:
    """Set GUI values from code without running the handlers meant for the user's changes
    (viser calls update callbacks synchronously on assignment)."""
    flag.on = True
    try:
        for name, value in attrs.items():
            setattr(handle, name, value)
    finally:
        flag.on = False


def replay_controls(d: Dashboard) -> None:
    """Play/pause, speed and a time scrubber for the humanoid replay, plus the subtask."""
    gui = d.server.gui
    play = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE)
    speed = gui.add_slider("Speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
    scrub = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0)
    status = gui.add_markdown("")
    setting = threading.local()

    @play.on_click
    def _(_event: object) -> None:
        with d.replay.lock:
            player = d.replay.player
            player.playing = not player.playing
            play.label = "Pause" if player.playing else "Play"
            play.icon = viser.Icon.PLAYER_PAUSE if player.playing else viser.Icon.PLAYER_PLAY

    @speed.on_update
    def _(_event: object) -> None:
        d.replay.player.speed = float(speed.value)

    @scrub.on_update
    def _(_event: object) -> None:
        if getattr(setting, "busy", False):
            return  # our own update from the replay thread
        with d.replay.lock:
            d.replay.player.seek(int(scrub.value))
            d.replay.redraw()

    def frame_text(ep: Episode, i: int) -> None:
        setting.busy = True
        try:
            if scrub.max != max(ep.num_frames - 1, 1):
                scrub.max = max(ep.num_frames - 1, 1)
            scrub.value = i
        finally:
            setting.busy = False
        skill = ep.skill[i]
        status.content = (f"**t = {ep.times[i] - ep.times[0]:.2f} s** of "
                          f"{ep.times[-1] - ep.times[0]:.2f} s, frame {i + 1}/{ep.num_frames}"
                          + (f"  \ncurrent subtask **{ep.subtask[i]}: {skill}**" if skill
                             else ""))

    d.on_frame = frame_text


def tables_panel(d: Dashboard) -> Callable[[], None]:
    """The paper's tables (detach.eval.tables, as `detach-run table` prints them) over the
    eval*.json files of all or of the selected runs, with CSV downloads."""
    gui = d.server.gui
    scope = gui.add_dropdown("Runs", ("all runs", "selected runs"), initial_value="all runs")
    body = gui.add_markdown("")
    download = gui.add_button_group("Download CSV", tuple(TABLES))
    state: dict[str, object] = {"key": None, "tables": {}}

    @download.on_click
    def _(event: viser.GuiEvent) -> None:
        table = state["tables"].get(event.target.value)  # type: ignore[union-attr]
        if table is not None and event.client is not None:
            event.client.send_file_download(f"{event.target.value}.csv",
                                            table.to_csv().encode("utf-8"),
                                            save_immediately=True)

    @scope.on_update
    def _(_event: object) -> None:
        with d.lock:
            update()

    def update() -> None:
        ids = sorted(d.infos) if scope.value == "all runs" else list(d.selected)
        key = (scope.value, tuple((r, d.infos[r].eval_version) for r in ids if r in d.infos))
        if key == state["key"]:
            return
        evals = d.index.evals(ids)
        tables, errors = comparison_tables(evals)
        head = (f"{len(evals)} evaluation file(s) (`eval*.json`) of {len(ids)} run(s); "
                f"rates [confidence interval], seeds of a method pooled.\n\n" if evals else
                "*No `eval*.json` files among these runs yet.*\n\n")
        body.content = head + _small(tables_markdown(tables, errors))
        state["key"], state["tables"] = key, tables

    return update
