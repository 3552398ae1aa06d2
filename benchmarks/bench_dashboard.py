"""Dashboard reader on a large runs folder: 20 runs, one of them with a ~100 MB log.mcap.

Measures what the dashboard does every poll (refresh of the run index: stat every file,
re-parse changed ones, tail logs) and what it does when a run is opened in the 3D view (find
and load the newest episode), against the reference reader of detach.runs.mcap_log (which
parses the whole file), plus the startup time of `detach-dashboard` and the server-side
cost of one humanoid frame.

Run: /work/venv/bin/python benchmarks/bench_dashboard.py [--mb 100] [--keep DIR]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from detach.character import build_character_model  # noqa: E402
from detach.character.body import BODY_NAMES  # noqa: E402
from detach.run_contract import EpisodeFrame  # noqa: E402
from detach.runs.folder import RunFolder  # noqa: E402
from detach.runs.mcap_log import RunLogWriter, read_episodes, read_metrics  # noqa: E402
from server.log_tail import LogTail  # noqa: E402
from server.run_index import RunIndex  # noqa: E402
from tests.dashboard_fixtures import make_run, walk_frames  # noqa: E402


def timed(fn, repeat: int = 1) -> tuple[float, object]:
    """(median seconds, last result) of `repeat` calls."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def big_log(run: RunFolder, megabytes: float, frames_per_episode: int = 300) -> tuple[int, int]:
    """Rewrite `run`'s log with metrics and preview episodes until it reaches the size.

    Poses are a walk with per-frame noise (so they compress like real motion, not like
    repeated frames); one /metrics message per 30 frames, as a training run that previews
    often would write. Returns (episodes, frames). The writer is left open (a live run)."""
    from detach.runs.mcap_log import read_scene

    scene = read_scene(run.log_path)
    model = build_character_model()
    base_pos, base_quat = walk_frames(model, frames_per_episode, (9.5, 3.0), math.pi)
    rng = np.random.default_rng(0)
    log = RunLogWriter(run.log_path)
    log.log_scene(scene)
    episode, frames, it = 0, 0, 0
    while run.log_path.stat().st_size < megabytes * 1e6:
        noise = rng.normal(0, 0.01, base_pos.shape)
        for f in range(frames_per_episode):
            log.log_frame(EpisodeFrame(episode, f, f / 30, list(BODY_NAMES), (base_pos[f] + noise[f]).tolist(),
                                       base_quat[f].tolist(), objects=[{"name": "box", "pos": [4.5, -4.0, 0.35],
                                                                        "quat": [1, 0, 0, 0]}],
                                       subtask=f * 4 // frames_per_episode, skill="follow"))
            frames += 1
            if f % 30 == 0:
                log.log_metrics(it, {"reward/mean": it * 1e-3, "loss/value": 1 / (1 + it),
                                     "fps": 1000.0})
                it += 1
        episode += 1
    log.flush()
    return episode, frames, log


def startup(runs: Path) -> tuple[float, float]:
    """(seconds to the printed URL, seconds to the first HTTP 200) of a fresh process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(runs), "--port",
                             "0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        url = None
        for line in proc.stdout:
            m = re.search(r"detach-dashboard: (http://\S+)", line)
            if m:
                url = m.group(1)
                break
        t_url = time.perf_counter() - t0
        while True:
            try:
                urllib.request.urlopen(url, timeout=1).read()
                break
            except OSError:
                time.sleep(0.02)
        return t_url, time.perf_counter() - t0
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def frame_cost(runs: Path, run_id: str) -> tuple[float, float]:
    """(median, p95) seconds of one humanoid frame update on a server without clients."""
    import viser

    from server.app import Dashboard

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        d = Dashboard(server, runs)
        d.poll()
        ep = d.index.reader(run_id).log.load_episode()
        d.view.show(d.index.reader(run_id).log.scene, runs / run_id)
        costs = []
        for i in range(ep.num_frames):
            t0 = time.perf_counter()
            d._draw_frame(ep, i)
            costs.append(time.perf_counter() - t0)
        t_poll, _ = timed(d.poll, 5)
        return statistics.median(costs), float(np.percentile(costs, 95)), t_poll
    finally:
        server.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="size of the big log (MB)")
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--keep", type=Path, help="build the runs folder here and keep it")
    args = ap.parse_args()
    tmp = args.keep or Path(tempfile.mkdtemp(prefix="bench_dashboard_"))
    runs_dir = tmp / "runs"
    print(f"# bench_dashboard: {platform.python_version()}, {os.cpu_count()} cores, {tmp}")

    t0 = time.perf_counter()
    models = ["mlp", "detach", "tokenhsi", "cml", "ablation_a1"]
    runs = [make_run(runs_dir, models[i % len(models)], seed=i, shift=0.1 * i,
                     now=1_700_000_000 + 60 * i, assets=tmp / "assets", iterations=200)
            for i in range(args.runs)]
    big = runs[-1]
    big.set_state("running")
    episodes, frames, writer = big_log(big, args.mb)
    size = big.log_path.stat().st_size
    print(f"generated {args.runs} runs in {time.perf_counter() - t0:.1f} s; big log "
          f"{size / 1e6:.1f} MB, {episodes} episodes, {frames} frames")

    rows: list[tuple[str, float, str]] = []
    index = RunIndex(runs_dir)
    t_cold, infos = timed(index.refresh)
    assert len(infos) == args.runs and not any(i.unreadable for i in infos), infos
    rows.append((f"run index, first refresh ({args.runs} runs, incl. the {size / 1e6:.0f} MB log)",
                 t_cold, ""))
    t_warm, _ = timed(index.refresh, 20)
    rows.append(("run index, refresh with nothing changed", t_warm, ""))

    appended = [0]

    def grow() -> list:
        """The live run writes one more iteration and 30 frames of its newest episode."""
        writer.log_metrics(10**6 + appended[0], {"reward/mean": 1.0})
        for f in range(appended[0] * 30, appended[0] * 30 + 30):
            writer.log_frame(EpisodeFrame(episodes, f, f / 30, list(BODY_NAMES), np.zeros((15, 3)).tolist(),
                                          np.tile([1.0, 0, 0, 0], (15, 1)).tolist()))
        appended[0] += 1
        writer.flush()
        return index.refresh()

    t_grow, _ = timed(grow, 10)
    rows.append(("run index, refresh after the live run appended 1 iteration + 30 frames",
                 t_grow, ""))

    path = big.log_path
    t_ref_metrics, ref_metrics = timed(lambda: read_metrics(path))
    t_tail_metrics, tail = timed(lambda: (lambda t: (t.refresh(), t)[1])(LogTail(path)))
    assert len(tail.metrics) == len(ref_metrics)
    rows.append((f"metrics of the {size / 1e6:.0f} MB log, LogTail first read (cold)",
                 t_tail_metrics,
                 f"{t_ref_metrics / t_tail_metrics:.0f}x faster"))
    rows.append(("same, mcap_log.read_metrics (parses everything)", t_ref_metrics, ""))
    t_newest, ep = timed(tail.load_episode)
    rows.append(("newest episode (cold: find it from the end, decode its chunks)", t_newest,
                 f"{ep.num_frames} frames"))
    t_newest_warm, _ = timed(tail.load_episode, 5)
    rows.append(("newest episode again (chunks cached)", t_newest_warm, ""))
    t_all, numbers = timed(tail.episode_numbers)
    rows.append(("episode list (first time: decode every frame chunk once)", t_all,
                 f"{len(numbers)} episodes"))
    t_all_warm, _ = timed(tail.episode_numbers, 5)
    rows.append(("episode list again", t_all_warm, ""))
    t_mid, mid = timed(lambda: tail.load_episode(numbers[len(numbers) // 2]))
    rows.append(("a middle episode by number (index built)", t_mid, ""))
    t_ref_eps, ref = timed(lambda: read_episodes(path))
    rows.append(("all episodes, mcap_log.read_episodes (reference)", t_ref_eps,
                 f"{t_ref_eps / t_newest:.0f}x the cold newest-episode load"))
    assert len(ref[numbers[-1]]) == ep.num_frames and len(ref) == len(numbers)
    writer.close()

    t_url, t_http = startup(runs_dir)
    rows.append(("detach-dashboard startup: process start -> URL printed", t_url, "goal < 3 s"))
    rows.append(("detach-dashboard startup: process start -> first HTTP 200", t_http, ""))
    med, p95, t_poll = frame_cost(runs_dir, big.path.name)
    rows.append(("humanoid frame update, server side (median)", med,
                 f"p95 {p95 * 1e3:.2f} ms; 30 fps budget 33 ms"))
    rows.append((f"dashboard poll, {args.runs} runs, nothing changed (all panels)", t_poll, ""))

    print("\n| measurement | time | note |\n| --- | --- | --- |")
    for name, t, note in rows:
        shown = f"{t * 1e3:.2f} ms" if t < 1 else f"{t:.2f} s"
        print(f"| {name} | {shown} | {note} |")
    if args.keep is None:
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
