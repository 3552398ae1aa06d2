"""Screenshots of every dashboard tab (docs/dashboard/*.png) from real runs.

Trains two tiny runs on LH1 (DETACH and TokenHSI; puppet character, 3 iterations, evaluated
on LH1 and LH3 with 2 trials each), or takes an existing runs folder, starts
`detach-dashboard` on it with the launch form, and drives headless Chromium through the tabs:
Runs (with one run's details and a config diff), Replay (a second run beside the first, the
walked path), Curves (the runs compared, wide view), Tables (one row per run and the paper's
numbers) and Launch.

    python docs/dashboard/make_screenshots.py [--runs DIR] [--out docs/dashboard] [--only replay,runs]

`--runs DIR` names a runs folder to use, or where to train the tiny runs when it does not exist
yet; `--only` keeps the named screenshots and leaves the other files as they are.

Needs Debian's chromium (/usr/bin/chromium) and playwright (the test extra). Training and
evaluating the runs takes 5-20 minutes on a 2-core machine (LH3 episodes are long).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--no-first-run"]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.max_iterations=3",
        "train.num_steps_per_env=8", "eval.num_envs=2", "env.episode_length=150"]
RUNS = (("detach", 0), ("tokenhsi", 0))
WAIT_MS = 120_000


def train_runs(out: Path) -> None:
    """The tiny runs the tests use, evaluated on their task (LH1) and on LH3."""
    for model, seed in RUNS:
        cmd = [sys.executable, "-m", "detach.cli", "configs/tasks/lh1.yaml", "--model", model,
               "--seed", str(seed), *TINY, "--trials", "2", "--eval-on",
               "configs/tasks/lh3.yaml", "--out", str(out)]
        print("+", " ".join(cmd[2:]), flush=True)
        subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)


def start_dashboard(runs: Path) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(runs), "--port",
                             "0", "--allow-launch"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:
        m = re.search(r"detach-dashboard: (http://\S+)", line)
        if m:
            return proc, m.group(1)
    raise RuntimeError("detach-dashboard did not print its URL")


def select(page, label: str, option: str) -> None:
    page.get_by_role("combobox", name=label).click(force=True)
    page.get_by_role("option", name=option, exact=True).click(force=True)


SHOTS = ("runs", "replay", "curves", "tables", "launch")


def shoot(url: str, runs: list[str], out: Path, only: tuple[str, ...] = SHOTS) -> None:
    from playwright.sync_api import Error, sync_playwright

    def save(page, name: str) -> None:
        if name in only:
            page.screenshot(path=str(out / f"{name}.png"))

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.set_default_timeout(WAIT_MS)
        page.goto(url)
        page.get_by_role("tab", name="Curves").first.wait_for()
        time.sleep(2)
        for close in page.locator(".mantine-Notification-closeButton").all():
            try:  # the "software WebGL" notice
                close.click(force=True, timeout=10_000)
            except Error:
                pass

        page.get_by_role("button", name="Shown", exact=True).click(force=True)  # compare all
        select(page, "Diff with", runs[0])
        page.mouse.move(5, 5)
        time.sleep(3)
        save(page, "runs")

        page.get_by_role("tab", name="Replay").first.click(force=True)
        select(page, "Run", runs[-1])
        select(page, "Beside it", runs[0])
        page.mouse.move(5, 5)
        time.sleep(6)
        page.get_by_role("button", name="Pause").first.click(force=True)
        frame = page.get_by_role("slider").nth(1)  # Speed, then Frame
        frame.focus()
        frame.press("End")  # the closing frame: the walked path, the task markers and the verdict
        page.mouse.move(5, 5)
        time.sleep(3)
        save(page, "replay")

        page.get_by_role("tab", name="Curves").first.click(force=True)
        page.get_by_label("Wide view").filter(visible=True).check(force=True)
        page.mouse.move(5, 5)
        time.sleep(4)
        save(page, "curves")

        page.get_by_role("tab", name="Tables").first.click(force=True)  # still wide
        page.get_by_label("One row per run").check(force=True)
        page.mouse.move(5, 5)
        time.sleep(4)
        save(page, "tables")
        page.get_by_label("Wide view").filter(visible=True).uncheck(force=True)

        page.get_by_role("tab", name="Launch").first.click(force=True)
        time.sleep(2)
        save(page, "launch")
        browser.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, help="a runs folder, trained into when it does not exist "
                    "(default: a temporary one)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    ap.add_argument("--only", default=",".join(SHOTS), help=f"screenshots to write (default: {','.join(SHOTS)})")
    args = ap.parse_args()
    only = tuple(s for s in args.only.split(",") if s)
    if not set(only) <= set(SHOTS):
        ap.error(f"--only: choose among {', '.join(SHOTS)}")
    runs_dir = args.runs
    if runs_dir is None or not runs_dir.exists():
        runs_dir = runs_dir or Path(tempfile.mkdtemp(prefix="dashboard_shots_")) / "runs"
        train_runs(runs_dir)
    names = sorted(p.name for p in runs_dir.iterdir() if (p / "config.yaml").exists())
    proc, url = start_dashboard(runs_dir)
    try:
        shoot(url, names, args.out, only)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    print(f"screenshots of {len(names)} runs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
