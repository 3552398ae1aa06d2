"""Print a run's learning curve from its log.mcap: iteration, wall-clock minutes, reward,
episode length, style reward and success rates, every N iterations.

    python benchmarks/learning_curve.py runs/<run> [--every 20]

Wall-clock time is the sum of the logged collection and learning times (the training loop
itself), so start-up and evaluation are excluded. Success rates are means over the episodes
that ended in each iteration (as logged by the env), smoothed over the printed window.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from detach import read_metrics


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--every", type=int, default=20)
    args = parser.parse_args()
    metrics = read_metrics(args.run / "log.mcap")
    if not metrics:
        raise SystemExit(f"{args.run}: no /metrics messages")
    success_keys = sorted({k for m in metrics for k in m if k.startswith("Episode_Success/")})
    columns = ["Train/mean_reward", "Train/mean_episode_length", "Train/step_reward_task", "Train/step_reward_style",
               *success_keys]
    print("| iter | minutes | " + " | ".join(columns) + " |")
    print("|" + "---|" * (len(columns) + 2))
    elapsed = 0.0
    window: list[dict] = []
    for m in metrics:
        elapsed += m.get("Perf/collection_time", 0.0) + m.get("Perf/learning_time", 0.0)
        window.append(m)
        if (m["iteration"] + 1) % args.every == 0 or m is metrics[-1]:
            cells = []
            for key in columns:
                values = [w[key] for w in window if key in w]
                cells.append(f"{statistics.fmean(values):.3f}" if values else "-")
            print(f"| {m['iteration'] + 1} | {elapsed / 60:.1f} | " + " | ".join(cells) + " |")
            window = []


if __name__ == "__main__":
    main()
