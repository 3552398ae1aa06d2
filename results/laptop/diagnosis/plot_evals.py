"""Mean-action evaluations of a run's checkpoints against iteration, as one CSV and one PNG.

Training curves are sampled-action figures; what a run reports is its mean-action evaluation,
which moved by 0.3 between checkpoints 25 iterations apart in LH1's whole-plan runs. This
draws every subtask's success, the LH mean and the chain of each series of evaluation JSONs
(`detach-run eval` output), with their 95% intervals as bars.

    python results/laptop/diagnosis/plot_evals.py --out lh1_teachers3 \
        --series "K6=diagnosis/teachers3_evals/k6_*_model*.json" --series "K7=..."

A file's checkpoint iteration is read from its `iteration` field.
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).resolve().parent


def rows_of(label: str, pattern: str) -> list[dict]:
    """One row per (checkpoint, figure) of the evaluation files matching pattern."""
    rows = []
    for path in sorted(glob.glob(pattern)):
        data = json.loads(Path(path).read_text())
        figures = [(f"{s['index']}_{s['skill']}", s) for s in data["subtasks"]]
        figures += [("lh_mean", data["lh_mean"]), ("lh_chain", data["lh_chain"])]
        for name, fig in figures:
            rows.append({"series": label, "iteration": int(data["iteration"]), "figure": name,
                         "rate": fig["rate"], "low": fig["ci"][0] if "ci" in fig else None,
                         "high": fig["ci"][1] if "ci" in fig else None, "n": fig["n"], "file": Path(path).name})
    if not rows:
        raise SystemExit(f"{label}: no file matches {pattern}")
    return sorted(rows, key=lambda r: (r["figure"], r["iteration"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="file stem under results/laptop/diagnosis/")
    parser.add_argument("--series", action="append", required=True, help='"label=glob of eval JSON files"')
    args = parser.parse_args()
    rows = []
    for spec in args.series:
        label, _, pattern = spec.partition("=")
        rows += rows_of(label, pattern)
    with open(HERE / f"{args.out}.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    figures = list(dict.fromkeys(r["figure"] for r in rows))
    fig, axes = plt.subplots(1, len(figures), figsize=(3.2 * len(figures), 3.0), sharey=True)
    for ax, name in zip(axes, figures):
        for label in dict.fromkeys(r["series"] for r in rows):
            pts = [r for r in rows if r["series"] == label and r["figure"] == name]
            x = [r["iteration"] for r in pts]
            y = [r["rate"] for r in pts]
            err = [[r["rate"] - r["low"] for r in pts], [r["high"] - r["rate"] for r in pts]]
            ax.errorbar(x, y, yerr=err, marker="o", capsize=2, label=label)
        ax.set_title(name)
        ax.set_xlabel("iteration")
        ax.set_ylim(-0.02, 1.02)
    axes[0].set_ylabel("success (100 trials, mean actions)")
    axes[-1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(HERE / f"{args.out}.png", dpi=110)
    print(f"wrote {HERE / args.out}.csv and .png ({len(rows)} rows)")


if __name__ == "__main__":
    main()
