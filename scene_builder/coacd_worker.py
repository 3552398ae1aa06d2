"""One CoACD run in a child process: `python -m scene_builder.coacd_worker JOB_DIR`.

CoACD's C++ core cannot be interrupted from Python, so `scene_builder.hulls` runs it here and
kills this process when the asset's time budget is spent. Reads `JOB_DIR/input.npz`
(`vertices` [V, 3] float64, `faces` [F, 3] int32, `params` JSON of CoACD keyword arguments) and
writes `JOB_DIR/output.npz` (`v<i>`, `f<i>` per hull, `count`, `peak_rss_mb`) through a
temporary name, or `JOB_DIR/error.txt` with one line. Imports only numpy and coacd, so it
starts in ~0.3 s.
"""

from __future__ import annotations

import json
import os
import resource
import sys
from pathlib import Path

import numpy as np


def _peak_rss_mb() -> float:
    """This program's peak resident memory in MiB: VmHWM from /proc (ru_maxrss would include
    the parent's memory at the fork that started us: 1.7 GB for a 20k-face job)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run(job: Path) -> int:
    """Run the job in `job`; 0 on success, 1 when CoACD raised (error.txt says why)."""
    import coacd

    data = np.load(job / "input.npz")
    params = json.loads(str(data["params"]))
    coacd.set_log_level("error")
    try:
        parts = coacd.run_coacd(coacd.Mesh(data["vertices"], data["faces"]), **params)
    except Exception as e:  # CoACD reports failures as assorted exceptions from its C++ core
        (job / "error.txt").write_text(f"{type(e).__name__}: {e}".splitlines()[0] + "\n")
        return 1
    arrays: dict[str, np.ndarray] = {"count": np.int64(len(parts)), "peak_rss_mb": np.float64(_peak_rss_mb())}
    for i, (v, f) in enumerate(parts):
        arrays[f"v{i}"], arrays[f"f{i}"] = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
    tmp = job / "output.tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, job / "output.npz")
    return 0


if __name__ == "__main__":
    sys.exit(run(Path(sys.argv[1])))
