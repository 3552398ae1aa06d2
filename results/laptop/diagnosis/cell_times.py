"""Wall-clock of sweep cells: training minutes (the sum of the logged collection and update
times), the run's whole span (status.json: start to the last update, which is after its
evaluation) and iterations, as a Markdown table.

    python results/laptop/diagnosis/cell_times.py RUN_DIR [RUN_DIR ...]
"""
import json
import sys
from pathlib import Path

from detach import read_metrics

print("| run | cell | iterations | training min | s per iteration | whole run min |")
print("| --- | --- | --- | --- | --- | --- |")
for name in sys.argv[1:]:
    run = Path(name)
    status = json.loads((run / "status.json").read_text())
    rows = read_metrics(run / "log.mcap")
    train_s = sum(r.get("Perf/collection_time", 0.0) + r.get("Perf/learning_time", 0.0) for r in rows)
    span_min = (status["updated"] - status["started"]) / 60
    print(f"| `{run.name}` | `{status.get('cell')}` | {len(rows)} | {train_s / 60:.1f} | "
          f"{train_s / max(len(rows), 1):.1f} | {span_min:.1f} |")
