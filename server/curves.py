"""Training curves as uPlot charts: which keys, their groups, and each chart's arrays and axes.

Pure functions (no viser server): tests check the arrays and axes a browser would get.

Why the server computes the y range and scales the values (uPlot would do both itself):
- uPlot's automatic range takes Math.min over the data, and one NaN (an iteration where a
  run has no value, e.g. every iteration before a success metric's first evaluation) makes
  the range NaN: no axis and no line. Charts therefore always carry an explicit range.
- uPlot labels ticks with Intl.NumberFormat (at most 3 decimals), so a learning rate of
  1e-3..1e-4 reads "0.001, 0, 0, 0". Values whose span is below 0.05 (or above 1e5) are
  sent as multiples of a power of ten named in the title ("learning_rate (x1e-4)").
- A constant series gets a range around its value (uPlot's default for 0 is 0..100).
- The iteration axis only ticks at whole iterations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import re2

from server.markup import md_text
from server.run_index import MetricSeries

X_AXES = ("iteration", "samples", "wall time (min)")
"""What the x axis of every chart can be: the training iteration, environment steps so far,
or minutes since the run's first logged iteration."""
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")
MAX_POINTS = 1500
"""Points per run and chart sent to the browser; longer runs are decimated (every k-th)."""
INTEGER_STEPS = tuple(float(m * 10 ** e) for e in range(10) for m in (1, 2, 5))
"""Tick increments of the iteration axis: whole iterations only."""


def metric_group(key: str) -> str:
    """'Loss/surrogate' -> 'loss'; 'Episode_Reward/follow/position' -> 'episode_reward' (one
    group whatever the case); keys without a prefix ('fps') form the group 'general'."""
    return key.split("/", 1)[0].lower() if "/" in key else "general"


def curve_groups(keys: Sequence[str]) -> dict[str, list[str]]:
    """Keys grouped by prefix (sorted, 'general' first; keys sorted case-insensitively)."""
    groups: dict[str, list[str]] = {}
    for k in sorted(set(keys), key=lambda k: (k.lower(), k)):
        groups.setdefault(metric_group(k), []).append(k)
    return dict(sorted(groups.items(), key=lambda kv: (kv[0] != "general", kv[0])))


MAX_FILTER = 200
"""Characters of the filter box that count."""


def key_filter(pattern: str) -> Callable[[str], bool]:
    """The filter box as a test of one key: every word of it (case-insensitive) must match,
    each word a regular expression ('loss/(value|surrogate)') or, if it is not a valid one,
    plain text.

    Expressions run in RE2 (google-re2), whose time is linear in the key's length whatever
    the pattern: the filter runs on the server, and Python's backtracking `re` took seconds
    per key on `(.|.)*Z` or `.*.*.*.*Z` while holding the GIL, which froze every browser. A
    pattern RE2 refuses (a backreference, a program over its memory bound) is plain text."""
    tests: list[Callable[[str], bool]] = []
    for word in pattern[:MAX_FILTER].split():
        try:
            tests.append(re2.compile(word, _RE2_OPTIONS).search)
        except re2.error:
            tests.append(lambda k, w=word.lower(): w in k.lower())
    return lambda key: all(t(key) for t in tests)


_RE2_OPTIONS = re2.Options()
_RE2_OPTIONS.case_sensitive = False
_RE2_OPTIONS.max_mem = 1 << 20  # bytes of a compiled word: the box is 200 characters
_RE2_OPTIONS.log_errors = False


def matching(keys: Sequence[str], pattern: str | Callable[[str], bool]) -> list[str]:
    """Keys matching the filter box (`key_filter`; a compiled filter may be passed)."""
    test = key_filter(pattern) if isinstance(pattern, str) else pattern
    return [k for k in keys if test(k)]


def legend_markdown(labels: Sequence[str]) -> str:
    """The Curves tab's legend: each run's label (escaped: it comes from its folder) in its
    line's colour."""
    return f"{len(labels)} run(s): " + ", ".join(
        f"<span style='color:{PALETTE[i % len(PALETTE)]}'>■ {md_text(label)}</span>"
        for i, label in enumerate(labels))


def smooth(y: np.ndarray, weight: float) -> np.ndarray:
    """TensorBoard's smoothing: an exponential moving average with debiasing (so the first
    points are not pulled towards 0), over the finite values only; NaN stays NaN."""
    out = np.array(y, dtype=np.float64)
    if weight <= 0.0:
        return out
    ok = np.isfinite(out)
    values = out[ok]
    ema, last = np.empty(len(values)), 0.0
    for i, v in enumerate(values.tolist()):
        last = last * weight + (1.0 - weight) * v
        ema[i] = last
    out[ok] = ema / (1.0 - weight ** np.arange(1, len(values) + 1))
    return out


def run_x(series: MetricSeries, axis: str, samples_per_iteration: int | None) -> np.ndarray | None:
    """One run's x values on the chosen axis; None if the run cannot be drawn on it."""
    if axis == "iteration":
        return series.iterations
    if axis == "samples":
        if not samples_per_iteration:
            return None
        return (series.iterations + 1.0) * samples_per_iteration
    if axis == X_AXES[2]:
        if len(series.times) != len(series.iterations) or not len(series.times):
            return None
        return (series.times - series.times.min()) / 60.0
    raise ValueError(f"unknown x axis {axis!r}; expected one of {', '.join(X_AXES)}")


@dataclass
class RunCurve:
    """One run's values of one key (its own x values, decimated)."""

    label: str
    color: str
    x: np.ndarray
    y: np.ndarray


@dataclass
class Chart:
    """Everything one uPlot chart needs; `data[0]` is x, then one array per series."""

    key: str
    title: str
    data: tuple[np.ndarray, ...]
    labels: list[str]
    colors: list[str]
    widths: list[float]
    y_range: tuple[float, float]
    exponent: int
    """Values are sent divided by 10**exponent (named in the title)."""
    log: bool
    x_axis: str
    notes: list[str] = field(default_factory=list)

    @property
    def drawn(self) -> bool:
        """At least one finite point (what the browser test checks as a visible line)."""
        return any(np.isfinite(y).any() for y in self.data[1:])


def run_curves(key: str, runs: Sequence[tuple[str, MetricSeries, int | None]], axis: str = "iteration",
               max_points: int = MAX_POINTS) -> list[RunCurve]:
    """(label, series, samples per iteration) of each run -> the runs that have `key`."""
    out = []
    for i, (label, series, samples) in enumerate(runs):
        col = series.columns.get(key)
        x = run_x(series, axis, samples)
        if col is None or x is None:
            continue
        ok = np.isfinite(col)
        x, y = x[ok], col[ok]
        if not len(x):
            continue
        if len(x) > max_points:
            step = int(math.ceil(len(x) / max_points))
            keep = np.unique(np.r_[np.arange(0, len(x), step), len(x) - 1])
            x, y = x[keep], y[keep]
        out.append(RunCurve(label, PALETTE[i % len(PALETTE)], x, y))
    return out


def chart(key: str, curves: Sequence[RunCurve], axis: str = "iteration", smoothing: float = 0.0,
          log: bool = False) -> Chart:
    """Align the runs on the union of their x values (NaN where a run has no point) and
    compute range and scale. With smoothing, each run's smoothed line is drawn over its raw
    values in a faint copy of its colour."""
    notes: list[str] = []
    x = np.unique(np.concatenate([c.x for c in curves])) if curves else np.zeros(0)
    if log and any((c.y <= 0).any() for c in curves):
        notes.append("values <= 0 are left out on the log scale")
    ys, raws = [], []
    for c in curves:
        y = c.y.astype(np.float64)
        if log:
            y = np.where(y > 0, y, np.nan)
        full = np.full(len(x), np.nan)
        full[np.searchsorted(x, c.x)] = y
        raws.append(full)
        if smoothing > 0:
            smoothed = np.full(len(x), np.nan)
            smoothed[np.searchsorted(x, c.x)] = smooth(y, smoothing)
            ys.append(smoothed)
    lines = ys if smoothing > 0 else raws
    values = np.concatenate([*lines, *(raws if smoothing > 0 else [])]) if curves else np.zeros(0)
    lo, hi = y_range(values, log)
    exponent = scale_exponent(lo, hi, log)
    factor = 10.0 ** -exponent
    labels = [c.label for c in curves]
    colors = [c.color for c in curves]
    widths = [1.5] * len(curves)
    data = [x, *(y * factor for y in lines)]
    if smoothing > 0:
        data += [y * factor for y in raws]
        labels += [f"{c.label} (raw)" for c in curves]
        colors += [c.color + "44" for c in curves]  # the same colour, faint
        widths += [1.0] * len(curves)
    title = key if exponent == 0 else f"{key} (x1e{exponent})"
    return Chart(key, title, tuple(np.asarray(d, dtype=np.float64) for d in data), labels,
                 colors, widths, (lo * factor, hi * factor), exponent, log, axis, notes)


def y_range(values: np.ndarray, log: bool = False) -> tuple[float, float]:
    """A y range that shows every finite value with 5 % margins; a constant series gets a
    range around its value; on a log scale, the positive values rounded out to decades."""
    finite = values[np.isfinite(values)]
    if log:
        finite = finite[finite > 0]
        if not len(finite):
            return 0.1, 10.0
        lo, hi = float(finite.min()), float(finite.max())
        return 10.0 ** math.floor(math.log10(lo)), 10.0 ** math.ceil(math.log10(hi) + 1e-12)
    if not len(finite):
        return -1.0, 1.0
    lo, hi = float(finite.min()), float(finite.max())
    if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
        pad = abs(lo) * 0.1 if lo != 0.0 else 1.0
        return lo - pad, hi + pad
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def scale_exponent(lo: float, hi: float, log: bool = False) -> int:
    """The power of ten the values are divided by so that 3-decimal tick labels still tell
    ticks apart: spans below 0.05 or above 1e5 (linear), values below 1 (log)."""
    if log:
        return min(0, math.floor(math.log10(lo))) if lo > 0 else 0
    span = hi - lo
    if span <= 0 or not math.isfinite(span):
        return 0
    if span < 0.05 or span >= 1e5:
        return math.floor(math.log10(span))
    return 0


def uplot_options(c: Chart) -> dict:
    """The keyword arguments of viser's add_uplot (and the props to update) for a chart."""
    from viser import uplot

    series = [uplot.Series(label=c.x_axis)] + [
        uplot.Series(label=label, stroke=color, width=width, spanGaps=True)
        for label, color, width in zip(c.labels, c.colors, c.widths)]
    y_scale = uplot.Scale(auto=False, range=c.y_range)
    if c.log:
        y_scale = uplot.Scale(auto=False, range=c.y_range, distr=3, log=10)
    x_axis = uplot.Axis(label=c.x_axis, labelSize=16)
    if c.x_axis == "iteration":
        x_axis = uplot.Axis(label=c.x_axis, labelSize=16, incrs=INTEGER_STEPS)
    return {"data": c.data, "series": tuple(series), "title": c.title,
            "scales": {"x": uplot.Scale(time=False), "y": y_scale},
            "axes": (x_axis, uplot.Axis())}
