"""Curves of named metrics from run folders' log.mcap, as one CSV and one PNG (matplotlib).

    python results/laptop/diagnosis/plot_runs.py --out carry_fix \
        --run "before=runs/A" --run "after=runs/B" \
        --metric carry/walk_to_box --metric carry/hands_on_box --metric carry/box_to_target

A metric matches the logged key that ends with it (runs before 2026-12-01 logged
`Reward/carry/...`, later ones `Episode_Reward/carry/...`). The CSV keeps every value read, so
the figure can be redrawn without the run folders (which are not in git).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from detach import read_metrics  # noqa: E402


def series(rows: list[dict], metric: str) -> list[tuple[int, float]]:
    out = []
    for row in rows:
        keys = [k for k in row if k == metric or k.endswith("/" + metric)]
        if keys and isinstance(row[keys[0]], (int, float)):
            out.append((int(row["iteration"]), float(row[keys[0]])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, metavar="LABEL=RUN_DIR")
    parser.add_argument("--metric", action="append", required=True)
    parser.add_argument("--out", required=True, help="file stem (writes STEM.csv and STEM.png beside this script)")
    parser.add_argument("--title", default="")
    args = parser.parse_args()
    runs = [(label, Path(path)) for label, path in (r.split("=", 1) for r in args.run)]
    logs = {run: read_metrics(run / "log.mcap") for _label, run in runs}  # each log read once
    stem = Path(__file__).parent / args.out
    fig, axes = plt.subplots(1, len(args.metric), figsize=(4.2 * len(args.metric), 3.4), squeeze=False)
    with open(stem.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["run", "run_dir", "metric", "iteration", "value"])
        for ax, metric in zip(axes[0], args.metric):
            for i, (label, run) in enumerate(runs):  # one colour per run on every axis
                points = series(logs[run], metric)
                writer.writerows([label, run.name, metric, it, f"{v:.6g}"] for it, v in points)
                if points:
                    ax.plot([p[0] for p in points], [p[1] for p in points], label=label, lw=1.2, color=f"C{i}")
            ax.set_title(metric, fontsize=9)
            ax.set_xlabel("PPO iteration")
            ax.grid(alpha=0.3)
        axes[0][0].legend(fontsize=8)
    if args.title:
        fig.suptitle(args.title, fontsize=10)
    fig.tight_layout()
    fig.savefig(stem.with_suffix(".png"), dpi=110)
    print(f"wrote {stem.with_suffix('.csv')} and {stem.with_suffix('.png')}")


if __name__ == "__main__":
    main()
