"""The Curves tab: the /metrics of the runs this browser compares, like TensorBoard.

One metric group at a time (prefixes of one case: 'Loss/...' and 'loss/...' together),
the pinned metrics, or whatever matches the filter box, at most MAX_CHARTS charts; x as
iteration, samples or wall time; smoothing; log scale; a wide view; any chart enlarged in a
floating window. Only the charts on screen exist, and a chart is re-sent only when its own
arrays or axes changed, so a new iteration costs the charts in view, not all 70.
"""

from __future__ import annotations

import json
import math
import threading
from typing import Any, Callable

import numpy as np
import viser

from detach.runfolder.names import METRICS_TOPIC
from server.curves import X_AXES, Chart, chart, curve_groups, key_filter, legend_markdown, matching, \
    run_curves, uplot_options
from server.run_index import MetricSeries
from server.session import Panel, Session, chosen, is_quiet, quietly

MAX_CHARTS = 24
PINNED, ALL = "pinned", "all metrics"
DEFAULT_GROUPS = ("episode_success", "train", "episode_reward", "loss")
"""The group shown first, if the runs have it (rsl-rl's metric names: docs/METRICS.md)."""
CHART_HEIGHT = 250
"""Pixels: the same in both views, so the wide view shows longer time axes, not bigger charts."""
PINS_KEY = "detach-dashboard-pins"
"""Browser localStorage key of the pinned metrics (pins outlive a reload)."""


def _same(a: Chart | None, b: Chart) -> bool:
    return a is not None and a.title == b.title and a.labels == b.labels and \
        a.colors == b.colors and a.y_range == b.y_range and a.log == b.log and \
        a.x_axis == b.x_axis and len(a.data) == len(b.data) and \
        all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a.data, b.data))


def curves_panel(s: Session) -> Panel:
    gui = s.gui
    quiet = threading.local()
    legend = gui.add_markdown("")
    with gui.add_folder("View"):
        filter_box = gui.add_text("Metric filter", "", hint="regular expressions or words, e.g. "
                                  "'success' or 'Loss/(value|surrogate)'")
        view = gui.add_dropdown("Show", (ALL,), hint="one group of metrics, the pinned ones "
                                "or all (with the filter)")
        x_axis = gui.add_dropdown("X axis", X_AXES, initial_value="iteration")
        smoothing = gui.add_slider("Smoothing", min=0.0, max=0.99, step=0.01, initial_value=0.0)
        log_y = gui.add_checkbox("Log scale (y)", False)
        s.add_wide_toggle()
    note = gui.add_markdown("")
    holder = gui.add_folder("Charts")
    charts: dict[str, tuple[viser.GuiUplotHandle, viser.GuiButtonGroupHandle, Chart]] = {}
    state: dict[str, Any] = {"pins": [], "views": (), "enlarged": None, "versions": None,
                             "keys": [], "series": {}, "user_view": False, "filter": None}

    # --- data -------------------------------------------------------------------------------
    def load() -> dict[str, tuple[MetricSeries, int | None]]:
        out = {}
        for run in s.selected:
            reader, info = s.index.reader(run), s.infos.get(run)
            if reader is not None and info is not None and info.has_log:
                series = reader.series()
                if len(series.iterations):
                    out[run] = (series, info.samples_per_iteration)
        state["series"] = out
        return out

    def build(key: str) -> Chart:
        runs = [(s.labels.get(r, r), series, samples)
                for r, (series, samples) in state["series"].items()]
        axis = chosen(x_axis, X_AXES, "iteration")
        weight = float(smoothing.value) if math.isfinite(smoothing.value) else 0.0
        return chart(key, run_curves(key, runs, axis), axis, float(np.clip(weight, 0, 0.99)),
                     bool(log_y.value))

    def shown_keys() -> list[str]:
        keys = state["keys"]
        groups = curve_groups(keys)
        choice = chosen(view, state["views"], ALL)
        if choice == PINNED:
            picked = [k for k in state["pins"] if k in keys]
        elif choice == ALL:
            picked = keys
        else:
            picked = groups.get(choice.split(" (")[0], [])
        return matching(picked, current_filter())

    def current_filter() -> Callable[[str], bool]:
        """The filter box compiled once per text (RE2: linear in each key's length)."""
        text = filter_box.value if isinstance(filter_box.value, str) else ""
        cached = state["filter"]
        if cached is None or cached[0] != text:
            cached = state["filter"] = (text, key_filter(text))
        return cached[1]

    # --- layout -------------------------------------------------------------------------------
    def update_views() -> None:
        keys = sorted({k for series, _ in state["series"].values() for k in series.columns})
        state["keys"] = keys
        groups = curve_groups(keys)
        views = (PINNED, ALL, *(f"{g} ({len(k)})" for g, k in groups.items()))
        if views != state["views"]:
            state["views"] = views
            current = view.value
            quietly(quiet, view, options=views)
            names = [v.split(" (")[0] for v in views]
            same_group = [v for v in views if v.split(" (")[0] == current.split(" (")[0]]
            if state["user_view"] and same_group:
                quietly(quiet, view, value=same_group[0])  # its count may have changed
            else:
                first = next((g for g in DEFAULT_GROUPS if g in names), None)
                pinned = any(p in keys for p in state["pins"])
                quietly(quiet, view, value=PINNED if pinned else
                        views[names.index(first)] if first else ALL)

    def update_legend() -> None:
        runs = list(state["series"])
        if not s.selected:
            text = "Tick runs in the **Runs** tab to plot their curves."
        elif not runs:
            text = f"The selected runs have no {METRICS_TOPIC} messages yet."
        else:
            text = legend_markdown([s.labels.get(r, r) for r in runs])
        if legend.content != text:
            legend.content = text

    def redraw(data_changed: bool = True) -> None:
        """Create, update or remove charts so that exactly the shown keys are on screen."""
        if data_changed:
            load()
        update_views()
        update_legend()
        keys = shown_keys()
        hidden = max(0, len(keys) - MAX_CHARTS)
        keys = keys[:MAX_CHARTS]
        text = (f"{hidden} more metric(s) match: narrow the filter or pick a group." if hidden
                else "No metric matches the filter." if state["series"] and not keys
                and filter_box.value.strip() else
                "Nothing pinned yet: 'Pin' under a chart keeps it here." if
                chosen(view, state["views"]) == PINNED and not keys and state["series"] else "")
        if note.content != text:
            note.content = text
        for key in [k for k in charts if k not in keys]:
            plot, buttons, _c = charts.pop(key)
            plot.remove()
            buttons.remove()
        with holder:
            for order, key in enumerate(keys):
                c = build(key)
                if key in charts:
                    plot, buttons, old = charts[key]
                    if not _same(old, c):
                        update_plot(plot, c, old)
                        charts[key] = (plot, buttons, c)
                else:
                    charts[key] = add_chart(key, c, order)
        if state["enlarged"] is not None:
            update_enlarged()

    def add_chart(key: str, c: Chart, order: int) -> tuple:
        plot = gui.add_uplot(**uplot_options(c), height=CHART_HEIGHT, order=2 * order)
        buttons = gui.add_button_group(
            "", ("★ Unpin" if key in state["pins"] else "☆ Pin", "⤢ Enlarge"), order=2 * order + 1)
        buttons.on_click(lambda event, key=key: chart_button(key, event.target.value))
        return plot, buttons, c

    def update_plot(plot: viser.GuiUplotHandle, c: Chart, old: Chart | None) -> None:
        options = uplot_options(c)
        with s.client.atomic():
            if old is None or old.labels != c.labels or old.colors != c.colors or \
                    len(old.data) != len(c.data):
                plot.series = options["series"]
            if old is None or old.y_range != c.y_range or old.log != c.log:
                plot.scales = options["scales"]
            if old is None or old.x_axis != c.x_axis:
                plot.axes = options["axes"]
            if old is None or old.title != c.title:
                plot.title = options["title"]
            plot.data = options["data"]

    # --- pins and the enlarged chart ---------------------------------------------------------
    def chart_button(key: str, value: str) -> None:
        with s.lock:
            if "Pin" in value:
                pins = state["pins"]
                state["pins"] = [p for p in pins if p != key] if key in pins else [*pins, key]
                save_pins()
                if key in charts:
                    charts[key][1].options = ("★ Unpin" if key in state["pins"] else "☆ Pin",
                                              "⤢ Enlarge")
                redraw(data_changed=False)
            elif "Enlarge" in value:
                enlarge(key)

    def save_pins() -> None:
        try:
            s.client.local_storage.set_item(PINS_KEY, json.dumps(state["pins"]))
        except Exception:  # noqa: BLE001 - pins still work for this page
            pass

    def restore_pins() -> None:
        """Pins of this browser from an earlier visit (read off the GUI threads)."""
        try:
            stored = s.client.local_storage.get_item(PINS_KEY, timeout=5.0)
            pins = json.loads(stored) if stored else []
        except Exception:  # noqa: BLE001 - no storage, or garbage in it: no pins
            return
        if isinstance(pins, list):
            with s.lock:
                state["pins"] = [p for p in pins if isinstance(p, str)][:200]
                for key, (_plot, buttons, _c) in charts.items():
                    buttons.options = ("★ Unpin" if key in state["pins"] else "☆ Pin", "⤢ Enlarge")

    def enlarge(key: str) -> None:
        close_enlarged()
        c = build(key)
        panel = gui.add_panel()
        with panel.add_tab(key, viser.Icon.CHART_LINE):
            plot = gui.add_uplot(**uplot_options(c), height=480)
            close = gui.add_button("Close", icon=viser.Icon.X)
        close.on_click(lambda _event: close_enlarged())
        panel.float(x=30, y=30, width=880, height=600)
        state["enlarged"] = (key, panel, plot, c)

    def update_enlarged() -> None:
        key, panel, plot, old = state["enlarged"]
        c = build(key)
        if not _same(old, c):
            update_plot(plot, c, old)
            state["enlarged"] = (key, panel, plot, c)

    def close_enlarged() -> None:
        with s.lock:
            if state["enlarged"] is not None:
                state["enlarged"][1].remove()
                state["enlarged"] = None

    # --- controls ---------------------------------------------------------------------------
    def control_changed(_event: object) -> None:
        if not is_quiet(quiet):
            with s.lock:
                redraw(data_changed=False)

    for control in (view, x_axis, smoothing, log_y):
        control.on_update(control_changed)

    @filter_box.on_update
    def _(_event: object) -> None:
        if not is_quiet(quiet):
            current_filter()  # compiled before this browser's lock is taken
            with s.lock:
                redraw(data_changed=False)

    @view.on_update
    def _(_event: object) -> None:
        if not is_quiet(quiet):
            state["user_view"] = True

    def refresh(changed: set[str]) -> None:
        versions = tuple((r, s.infos[r].log_version) for r in s.selected if r in s.infos)
        if versions != state["versions"] or any(r in changed for r in s.selected):
            state["versions"] = versions
            redraw()

    def selection_changed() -> None:
        state["versions"] = None
        redraw()

    threading.Thread(target=restore_pins, name="pins", daemon=True).start()
    return Panel(refresh=refresh, selection_changed=selection_changed,
                 open_runs=lambda: set(s.selected))
