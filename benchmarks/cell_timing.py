"""Sweep cells trained side by side, before and after a change: their time and their figures.

    python benchmarks/cell_timing.py BEFORE_RUNS AFTER_RUNS [--labels before after]

BEFORE_RUNS and AFTER_RUNS are the `--runs` folders of two sweeps of the same cells that
differ in one setting and ran at the same time on the same machine (one core each, e.g.
benchmarks/sweeps/laptop_reuse_timing.yaml), so the load each saw was the same. For each
task found in both (follow, carry, ...), prints the training loop's seconds per iteration by
stage (median of collection + learning, as logged), the cell's wall time from start to finish (training,
checkpoint choice and evaluation; `status.json`), the after/before ratios, and each cell's
evaluation (the success rate of eval.test.json, or eval.json, with its Wilson interval), so
that a speed-up is read beside the figures it must leave unchanged.
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections import defaultdict
from pathlib import Path

from detach import read_metrics


def cell_folders(runs: Path) -> dict[str, Path]:
    """{task: run folder} of the finished cells under a sweep's --runs folder."""
    out = {}
    for status in sorted(runs.glob("*/status.json")):
        info = json.loads(status.read_text())
        if info.get("state") == "finished":
            out[info["cell"].split("/")[0]] = status.parent
    return out


def stage_seconds(run: Path) -> dict[str, tuple[int, float]]:
    """{stage: (iterations, median seconds per iteration)} of the training loop (the median,
    so that a stretch of other load on the machine moves it less than a mean)."""
    per: dict[str, list[float]] = defaultdict(list)
    for m in read_metrics(run / "log.mcap"):
        if "Perf/collection_time" in m:
            per[str(m.get("stage", "ppo"))].append(m["Perf/collection_time"] + m.get("Perf/learning_time", 0.0))
    return {stage: (len(t), statistics.median(t)) for stage, t in per.items()}


def evaluation(run: Path) -> str:
    for name in ("eval.test.json", "eval.json"):
        if (run / name).exists():
            e = json.loads((run / name).read_text())
            lo, hi = e["lh_mean"]["ci"]
            return f"{e['lh_mean']['rate']:.2f} [{lo:.2f}, {hi:.2f}] ({name}, n={e['lh_mean']['n']})"
    return "no evaluation"


def wall_seconds(run: Path) -> float:
    info = json.loads((run / "status.json").read_text())
    return info["updated"] - info["started"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--labels", nargs=2, default=["before", "after"])
    args = parser.parse_args()
    before, after = cell_folders(args.before), cell_folders(args.after)
    tasks = [t for t in before if t in after]
    if not tasks:
        raise SystemExit(f"no finished cell of the same task in both {args.before} and {args.after}")
    a, b = args.labels
    print(f"| cell | stage | iterations | s/iteration {a} | s/iteration {b} | {b} / {a} |")
    print("|---|---|---|---|---|---|")
    for task in tasks:
        sa, sb = stage_seconds(before[task]), stage_seconds(after[task])
        for stage in sa:
            if stage in sb:
                (n, ta), (_, tb) = sa[stage], sb[stage]
                print(f"| {task} | {stage} | {n} | {ta:.2f} | {tb:.2f} | {tb / ta:.3f} |")
        wa, wb = wall_seconds(before[task]), wall_seconds(after[task])
        print(f"| {task} | whole cell (wall, min) | | {wa / 60:.1f} | {wb / 60:.1f} | {wb / wa:.3f} |")
    print()
    for task in tasks:
        print(f"{task}: {a} {evaluation(before[task])}; {b} {evaluation(after[task])}")


if __name__ == "__main__":
    main()
