"""Plot humanoid learning curves from run folders: Follow success, style reward, episode length
and fall share against samples and against minutes of training, one line per run.

    python results/humanoid/curve.py RUN [RUN ...] --out results/humanoid/curve.png [--csv FILE]
        [--labels "recipe A" "recipe B" ...] [--baseline OLD.csv --baseline-runs "C: ..."]
        [--continues K=J:538]

`--continues CHILD=PARENT:ITER` draws run CHILD (a label) after run PARENT's iteration ITER,
the checkpoint it started from (`train.init_from`): its samples and minutes are offset by
PARENT's there. `--baseline` draws runs of an earlier `--csv` output (already smoothed;
dashed), so a new run is compared with one whose folder is gone.

Samples are iterations x sim.num_envs x train.num_steps_per_env (from the run's config.yaml);
minutes are the logged collection + learning times (the training loop, not start-up or
evaluation). Training success is the share of episodes that ended in an iteration with Follow
done, smoothed over `--window` iterations: it reads the policy with exploration noise, so the
test figure (mean actions, 100 trials) is in results/humanoid/README.md, not here.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from detach import read_metrics  # noqa: E402

PANELS = (
    ("Episode_Success/0_follow", "Follow success (training episodes)"),
    ("Train/step_reward_style", "style reward per step"),
    ("Train/mean_episode_length", "episode length (steps)"),
    ("Episode_Termination/fell", "share of episodes ended by a fall"),
    ("Episode_Reward/follow/velocity", "Follow velocity reward (episodes)"),
    ("Train/balance_assist", "balance assist strength"),
)


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    if window <= 1 or len(values) < window:
        return values
    kernel = np.ones(window) / window
    head = np.array([values[: i + 1].mean() for i in range(window - 1)])
    return np.concatenate([head, np.convolve(values, kernel, mode="valid")])


def run_curve(run: Path, pause_over: float | None = None) -> dict[str, np.ndarray]:
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    per_iteration = cfg["sim"]["num_envs"] * cfg["train"]["num_steps_per_env"]
    metrics = read_metrics(run / "log.mcap")
    if not metrics:
        raise SystemExit(f"{run}: no /metrics messages in log.mcap")
    out = {"iteration": np.array([m["iteration"] + 1 for m in metrics], dtype=float)}
    out["samples"] = out["iteration"] * per_iteration
    seconds = np.array([m.get("Perf/collection_time", 0.0) + m.get("Perf/learning_time", 0.0) for m in metrics])
    if pause_over is not None:  # an iteration the process was stopped in counts as a typical one
        seconds = np.where(seconds > pause_over, np.median(seconds), seconds)
    out["minutes"] = np.cumsum(seconds) / 60.0
    for key, _ in PANELS:
        out[key] = np.array([m.get(key, np.nan) for m in metrics], dtype=float)
    return out


def csv_curves(path: Path, names: list[str]) -> dict[str, dict[str, np.ndarray]]:
    """Runs `names` of an earlier `--csv` file (smoothed values; a panel it lacks is NaN)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for name in names:
        mine = [r for r in rows if r["run"] == name]
        if not mine:
            raise SystemExit(f"{path}: no run {name!r} (it has {sorted({r['run'] for r in rows})})")
        c = {k: np.array([float(r[k]) for r in mine]) for k in ("iteration", "samples", "minutes")}
        for key, _ in PANELS:
            c[key] = np.array([float(r[key]) if r.get(key) not in (None, "") else np.nan for r in mine])
        out[name] = c
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--csv", type=Path, help="also write every run's smoothed curve here")
    parser.add_argument("--window", type=int, default=20)
    parser.add_argument("--labels", nargs="+", help="one legend label per run (default: the folder names)")
    parser.add_argument("--pause-over", type=float, metavar="S",
                        help="an iteration longer than S seconds (a stopped process) counts as the median one")
    parser.add_argument("--baseline", type=Path, help="an earlier --csv file to draw runs from (dashed)")
    parser.add_argument("--baseline-runs", nargs="+", default=[], help="which of its runs (their 'run' column)")
    parser.add_argument("--continues", nargs="+", default=[], metavar="CHILD=PARENT:ITER",
                        help="draw run CHILD after run PARENT's iteration ITER (labels)")
    args = parser.parse_args()
    labels = args.labels or [run.name for run in args.runs]
    if len(labels) != len(args.runs):
        parser.error(f"--labels: {len(labels)} labels for {len(args.runs)} runs")
    if bool(args.baseline) != bool(args.baseline_runs):
        parser.error("--baseline and --baseline-runs go together")
    curves = {label: run_curve(run, args.pause_over) for label, run in zip(labels, args.runs)}
    for spec in args.continues:
        child, _, rest = spec.partition("=")
        parent, _, at = rest.rpartition(":")
        if child not in curves or parent not in curves or not at.isdigit():
            parser.error(f"--continues {spec!r}: CHILD=PARENT:ITER with labels among {list(curves)}")
        p = curves[parent]
        i = int(np.searchsorted(p["iteration"], int(at)))
        i = min(i, len(p["iteration"]) - 1)
        curves[child]["samples"] = curves[child]["samples"] + p["samples"][i]
        curves[child]["minutes"] = curves[child]["minutes"] + p["minutes"][i]
    old = csv_curves(args.baseline, args.baseline_runs) if args.baseline else {}
    fig, axes = plt.subplots(len(PANELS), 2, figsize=(11, 3.0 * len(PANELS)), squeeze=False)
    for name, c in [*old.items(), *curves.items()]:
        style = "--" if name in old else "-"
        for row, (key, label) in enumerate(PANELS):
            y = c[key] if name in old else smooth(np.nan_to_num(c[key]), args.window)
            axes[row, 0].plot(c["samples"] / 1e6, y, style, label=name)
            axes[row, 1].plot(c["minutes"], y, style, label=name)
            axes[row, 0].set_ylabel(label)
    axes[-1, 0].set_xlabel("samples (millions)")
    axes[-1, 1].set_xlabel("minutes of training")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"humanoid Follow, smoothed over {args.window} iterations")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")
    if args.csv:
        with args.csv.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["run", "iteration", "samples", "minutes", *[k for k, _ in PANELS]])
            for name, c in curves.items():
                smoothed = [smooth(np.nan_to_num(c[k]), args.window) for k, _ in PANELS]
                for i in range(len(c["iteration"])):
                    w.writerow([name, int(c["iteration"][i]), int(c["samples"][i]), f"{c['minutes'][i]:.2f}",
                                *[f"{s[i]:.4f}" for s in smoothed]])
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
