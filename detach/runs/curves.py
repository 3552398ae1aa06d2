"""Learning curves of a sweep's runs as PNG files, drawn from each run's log.mcap.

`detach-run table SWEEP --out DIR` writes one figure per stage of the protocol
(`curves_<sweep>_<stage>.png`, e.g. `curves_table1_follow.png`: named by sweep, since several
sweeps' tables share an --out folder and their stages with different models), a panel per
metric (mean reward, episode length and each success rate the environment logged), one line
per model and seed, so a table comes with the training that produced it. matplotlib draws
them (the `plots` extra); without it the tables are still written and a line says why the
plots are not.

A figure whose runs and their logs are unchanged since it was drawn is not drawn again: each
PNG carries a digest of its title, cell keys, run folders and their logs' sizes and times in
its metadata, compared before any log is read (a long study's logs are ~100 MB each, and a
sweep's table is often made several times while its cells train).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from detach.runfolder.atomic import atomic_writer
from detach.runfolder.checkpoints import selected_checkpoint
from detach.runfolder.messages import ContractError
from detach.runfolder.names import checkpoint_iteration
from detach.runfolder.folder import RunFolder
from detach.runfolder.mcap_reader import read_metrics

Report = Callable[[str], None]

PANELS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("mean reward", ("Train/mean_reward", "reward/mean")),
    ("episode length", ("Train/mean_episode_length", "Episode/length", "episode/length")),
)
"""(panel title, metric names in the order tried): the first name a log has is drawn."""
SUCCESS_PREFIXES = ("Episode_Success/", "Success/")
"""Success fractions of the episodes that ended in an iteration (the second: logs written before
the rsl-rl naming)."""
SOURCES_KEY = "detach:sources"
"""PNG text key of a figure's source digest (`sources_digest`)."""
SMOOTH = 10
"""Iterations in the trailing mean drawn over the raw (faint) values: success rates of the
episodes that ended in one iteration are noisy."""


@dataclass(frozen=True)
class Curve:
    label: str
    """`<model> s<seed>`."""
    iterations: list[int]
    values: dict[str, list[float]]
    """panel title -> one value per iteration (NaN where the iteration did not log it)."""
    selected: int | None = None
    """Iteration of the checkpoint the run chose as its policy (selection.json), if it chose."""


def run_curve(run: RunFolder, model: str, seed: int) -> Curve | None:
    """The panels' series of one run; None when its log has no metrics yet."""
    try:
        metrics = read_metrics(run.log_path)
    except (OSError, ValueError):
        return None
    if not metrics:
        return None
    names = {k for m in metrics for k in m}
    chosen = {title: next((n for n in candidates if n in names), None) for title, candidates in PANELS}
    for prefix in SUCCESS_PREFIXES:
        chosen.update({f"success: {n.removeprefix(prefix)}": n for n in sorted(names) if n.startswith(prefix)})
    values = {title: [float(m.get(name, float("nan"))) for m in metrics]
              for title, name in chosen.items() if name is not None}
    if not values:  # no episode ended yet
        return None
    return Curve(f"{model} s{seed}", [int(m["iteration"]) for m in metrics], values, _selected_iteration(run))


def _selected_iteration(run: RunFolder) -> int | None:
    try:
        chosen = selected_checkpoint(run.path)
    except ContractError:
        return None
    return checkpoint_iteration(chosen.name) if chosen is not None else None


def _trailing_mean(values: list[float], window: int) -> list[float]:
    out, kept = [], []
    for v in values:
        if v == v:  # not NaN
            kept.append(v)
        kept = kept[-window:]
        out.append(sum(kept) / len(kept) if kept else float("nan"))
    return out


def sources_digest(title: str, runs: list[tuple[str, RunFolder]]) -> str:
    """Digest of what a stage's figure is drawn from: the title, and per cell its key, run
    folder, and its log's and selection.json's sizes and modification times (a log being
    written changes both)."""
    h = hashlib.sha256(title.encode())
    for key, run in runs:
        h.update(f"\0{key}\0{run.path.resolve()}".encode())
        for path in (run.log_path, run.selection_path):
            try:
                st = path.stat()
                size, mtime = st.st_size, st.st_mtime_ns
            except OSError:
                size, mtime = -1, -1
            h.update(f"\0{size}\0{mtime}".encode())
    return h.hexdigest()


def drawn_from(path: Path) -> str | None:
    """The source digest stored in an existing figure, None if absent or unreadable."""
    try:
        from PIL import Image

        with Image.open(path) as image:
            return image.text.get(SOURCES_KEY)  # type: ignore[attr-defined]
    except (OSError, ImportError, AttributeError, ValueError):
        return None


def plot_stage(stage: str, curves: list[Curve], path: Path, title: str, sources: str | None = None) -> None:
    """One figure: a panel per metric any curve has, a line per curve; a dashed line at the
    iteration a run chose as its policy."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    panels = list(dict.fromkeys(t for c in curves for t in c.values))
    cols = min(3, len(panels))
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, panel in zip(axes.flat, panels):
        for i, curve in enumerate(curves):
            if panel not in curve.values:
                continue
            colour = colours[i % len(colours)]
            ax.plot(curve.iterations, curve.values[panel], ".", color=colour, alpha=0.3, markersize=2.5)
            label = curve.label if curve.selected is None else f"{curve.label} (policy: iteration {curve.selected})"
            ax.plot(curve.iterations, _trailing_mean(curve.values[panel], SMOOTH), color=colour,
                    linewidth=1.6, label=label)
            if curve.selected is not None:
                ax.axvline(curve.selected, color=colour, linestyle="--", linewidth=0.9, alpha=0.8)
        ax.set_title(panel, fontsize=10)
        ax.set_xlabel("PPO iteration", fontsize=8)
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3)
        if panel.startswith("success"):
            ax.set_ylim(-0.02, 1.02)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    chosen = "; dashed: the checkpoint chosen as the policy" if any(c.selected is not None for c in curves) else ""
    fig.suptitle(f"{title}: {stage} (dots: per iteration; line: mean of the last {SMOOTH} logged{chosen})",
                 fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_writer(path) as handle:
            fig.savefig(handle, dpi=110, format="png",
                        metadata={SOURCES_KEY: sources} if sources is not None else None)
    finally:
        plt.close(fig)


def write_sweep_curves(runs: dict[str, RunFolder], out: Path, name: str, title: str,
                       report: Report) -> list[Path]:
    """`runs`: sweep cell key (`<stage>/<model>/s<seed>/<digest>`) -> its run folder. Writes
    `out/curves_<name>_<stage>.png` for each stage with a logged run, unless the figure there
    was drawn from the same runs and logs (module docstring); returns the files written."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        report("learning curves not drawn: matplotlib is not installed (pip install 'detach[plots]')")
        return []
    by_stage: dict[str, list[tuple[str, RunFolder]]] = {}
    for key, run in sorted(runs.items()):
        by_stage.setdefault(key.split("/")[0], []).append((key, run))
    written = []
    for stage, cells in by_stage.items():
        path = out / f"curves_{name}_{stage}.png"
        sources = sources_digest(title, cells)
        if drawn_from(path) == sources:  # None when there is no figure yet
            report(f"{path.name}: up to date (its {len(cells)} runs' logs unchanged since it was drawn)")
            continue
        curves = []
        for key, run in cells:
            model, seed = key.split("/")[1:3]
            curve = run_curve(run, model, int(seed.removeprefix("s")))
            if curve is not None:
                curves.append(curve)
        if curves:
            plot_stage(stage, curves, path, title, sources)
            written.append(path)
    return written
