"""Dashboard cost with 20 and with 200 run folders: refresh time and memory.

For each size N (one of the runs live, its log growing), measures what the dashboard does all
day: the run index's first (cold) refresh, an idle refresh (every poll, once a second), a
dashboard poll with one browser connected (a HeadlessClient: same websocket protocol as a
browser) when nothing changed and when the live run logged one more iteration, the bytes sent
to that browser per idle poll, the Python heap the index holds (tracemalloc), and the resident
memory of a real `detach-dashboard` process serving that folder to one browser. The goal
(issue 22): 200 runs within the same order of magnitude as 20 (ratio < 10).

With --mb, also the old large-log measurements: a live run whose log.mcap holds that many MB,
read by the incremental reader (detach.runfolder.log_tail) against the reference reader.

Run: .venv/bin/python benchmarks/bench_dashboard.py [--sizes 20 200] [--mb 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from detach import (  # noqa: E402
    BODY_NAMES, EpisodeFrame, LogTail, RunLogWriter, STATUS_FILE, read_episodes, read_metrics,
)
from server.episode import load_episode  # noqa: E402
from server.run_index import RunIndex  # noqa: E402
from tests.dashboard_fixtures import HeadlessClient, make_run, start_dashboard  # noqa: E402

MODELS = ("mlp", "detach", "tokenhsi", "cml", "ablation_a1")
SETTLED_PER_POLL = 20  # as server.app.SETTLED_PER_POLL


def timed(fn, repeat: int = 1) -> tuple[float, object]:
    """(median seconds, last result) of `repeat` calls."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def build_runs(folder: Path, n: int, templates: list[Path]) -> Path:
    """N run folders copied from the templates (finished runs of 200 iterations), the last
    one marked live; returns the live run."""
    folder.mkdir(parents=True)
    for k in range(n):
        src = templates[k % len(templates)]
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(1_700_000_000 + 60 * k))
        model = MODELS[k % len(MODELS)]
        shutil.copytree(src, folder / f"{stamp}-lh1-{model}-s{k}")
    live = sorted(folder.iterdir())[-1]
    text = (live / STATUS_FILE).read_text()
    (live / STATUS_FILE).write_text(re.sub(r'"state": "\w+"', '"state": "running"', text))
    return live


def rss_of(pid: int) -> float:
    """Resident memory of a process (MB), from /proc."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def served_memory(runs: Path) -> tuple[float, float]:
    """(MB resident, seconds to the panels) of a detach-dashboard process serving `runs` to one
    browser, after 10 polls."""
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(runs), "--port",
                             "0", "--poll", "0.5"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        url = None
        for line in proc.stdout:
            m = re.search(r"detach-dashboard: (http://\S+)", line)
            if m:
                url = m.group(1)
                break
        t0 = time.perf_counter()
        client = HeadlessClient(url)
        client.wait_for(lambda: len(client.elements) > 40, timeout=120, what="the panels")
        ready = time.perf_counter() - t0
        time.sleep(5.0)
        rss = rss_of(proc.pid)
        client.close()
        return rss, ready
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def measure(runs: Path, live: Path) -> dict[str, float]:
    out: dict[str, float] = {}
    index = RunIndex(runs, settled_per_refresh=SETTLED_PER_POLL)
    out["index first refresh, once at start-up (s)"], infos = timed(index.refresh)
    assert not any(i.unreadable for i in infos), [i.problems for i in infos if i.unreadable]
    out["index idle refresh, every poll (ms)"] = timed(index.refresh, 30)[0] * 1e3
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    held = RunIndex(runs, settled_per_refresh=SETTLED_PER_POLL)
    held.refresh()
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    out["Python heap held by the index (MB)"] = sum(
        s.size_diff for s in after.compare_to(before, "filename")) / 1e6
    del held

    server, dashboard, url = start_dashboard(runs, settled_per_poll=SETTLED_PER_POLL)
    client = HeadlessClient(url)
    try:
        client.wait_for(lambda: len(dashboard.sessions) == 1 and len(client.elements) > 40,
                        timeout=120, what="the panels")
        for _ in range(3):
            dashboard.poll()
        time.sleep(0.5)
        sent = client.bytes_received
        out["poll, 1 browser, idle (ms)"] = timed(dashboard.poll, 20)[0] * 1e3
        time.sleep(0.5)
        out["bytes sent per idle poll"] = (client.bytes_received - sent) / 20
        writer = RunLogWriter(live / "log.mcap", append=True)
        step = [10_000]

        def grow() -> None:
            writer.log_metrics(step[0], {"Train/mean_reward": 1.0, "Loss/value": 0.5})
            step[0] += 1
            writer.flush()
            dashboard.poll()

        out["poll after the live run logged 1 iteration (ms)"] = timed(grow, 10)[0] * 1e3
        writer.close()
    finally:
        client.close()
        server.stop()
    out["detach-dashboard resident memory, 1 browser (MB)"], out["panels shown after (s)"] = \
        served_memory(runs)
    return out


def big_log_rows(tmp: Path, megabytes: float) -> list[tuple[str, str]]:
    """The incremental reader on one live log of `megabytes` MB vs the reference reader."""
    from detach import build_character_model
    from tests.dashboard_fixtures import walk_frames

    run = make_run(tmp / "big", "detach", seed=0, shift=0.0, now=1_700_000_000,
                   assets=tmp / "assets", iterations=20)
    base_pos, base_quat = walk_frames(build_character_model(), 300, (9.5, 3.0), np.pi)
    rng = np.random.default_rng(0)
    episode, it = 0, 0
    with RunLogWriter(run.log_path, append=True) as log:
        while run.log_path.stat().st_size < megabytes * 1e6:
            noise = rng.normal(0, 0.01, base_pos.shape)
            for f in range(300):
                log.log_frame(EpisodeFrame(episode, f, f / 30, list(BODY_NAMES),
                                           (base_pos[f] + noise[f]).tolist(), base_quat[f].tolist()))
                if f % 30 == 0:
                    log.log_metrics(it, {"Train/mean_reward": it * 1e-3, "Perf/total_fps": 1000.0})
                    it += 1
            episode += 1
    path = run.log_path
    t_ref, ref = timed(lambda: read_metrics(path))
    t_tail, tail = timed(lambda: (lambda t: (t.refresh(), t)[1])(LogTail(path)))
    t_newest, ep = timed(lambda: load_episode(tail))
    t_ref_eps, _ = timed(lambda: read_episodes(path))
    size = path.stat().st_size / 1e6
    return [(f"metrics of a {size:.0f} MB log, LogTail first read", f"{t_tail * 1e3:.0f} ms"),
            ("same, mcap_reader.read_metrics (reference)", f"{t_ref * 1e3:.0f} ms"),
            ("newest episode, cold", f"{t_newest * 1e3:.1f} ms ({ep.num_frames} frames)"),
            ("all episodes, mcap_reader.read_episodes (reference)", f"{t_ref_eps:.2f} s")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 200])
    ap.add_argument("--mb", type=float, default=0.0, help="also read a live log of this size")
    ap.add_argument("--keep", type=Path, help="build the runs folders here and keep them")
    args = ap.parse_args()
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="bench_dashboard_"))
    load = os.getloadavg()[0]
    print(f"# bench_dashboard: Python {platform.python_version()}, {os.cpu_count()} cores, "
          f"load average {load:.1f}, {tmp}")
    t0 = time.perf_counter()
    templates = [make_run(tmp / "templates", m, seed=i, shift=0.3 * i, now=1_600_000_000 + 60 * i,
                          assets=tmp / "assets", iterations=200, frames=60).path
                 for i, m in enumerate(MODELS)]
    print(f"templates (5 runs of 200 iterations) in {time.perf_counter() - t0:.1f} s")
    results = {}
    for n in args.sizes:
        folder = tmp / f"runs{n}"
        live = build_runs(folder, n, templates)
        results[n] = measure(folder, live)
        print(f"measured {n} runs", flush=True)
    names = list(results[args.sizes[0]])
    head = " | ".join(f"{n} runs" for n in args.sizes)
    print(f"\n| measurement | {head} | ratio |\n| --- |" + " --: |" * (len(args.sizes) + 1))
    for name in names:
        values = [results[n][name] for n in args.sizes]
        ratio = values[-1] / values[0] if values[0] else float("nan")
        print(f"| {name} | " + " | ".join(f"{v:.3g}" for v in values) + f" | {ratio:.2f} |")
    if args.mb:
        print("\n| large log | time |\n| --- | --: |")
        for name, shown in big_log_rows(tmp, args.mb):
            print(f"| {name} | {shown} |")
    if args.keep is None:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
