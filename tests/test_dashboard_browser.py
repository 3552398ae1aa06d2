"""The dashboard in a real browser: headless Chromium (Debian package) driven by Playwright.

Starts `python -m server.cli` on a fixture runs folder (tests/dashboard_fixtures.py: two
finished runs, one broken folder, one run that recorded no episode) and checks what issue 22
found broken: a metric that starts late has a drawn line (defect 1), two pages keep separate
selections (defect 3), switching to a run without episodes clears the replay (defect 4), the
tables show n and the pooled runs (defect 6), plus the runs table and that switching runs
changes the 3D view. Screenshots are saved in the test's tmp dir. WebGL renders in software
(SwiftShader), so every wait is generous: on a loaded 2-core machine a click took up to 9 s.
"""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.dashboard_fixtures import make_run, make_runs

CHROMIUM = Path("/usr/bin/chromium")
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]
ROOT = Path(__file__).resolve().parents[1]
WAIT_MS = 90_000
"""Playwright waits (ms): the panels appear after the server imported its modules."""
STARTUP_S = 8.0
"""Process start -> URL printed. Measured 1.3-2.2 s with load average 8-10 on 2 cores (the URL
is printed as soon as the server accepts connections); the margin is for a slower CI box."""
LINE_RGB = (31, 119, 180)
"""PALETTE[0] of server.curves: the colour of the first compared run's line."""

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian's chromium at /usr/bin/chromium "
                              "(apt-get install -y chromium)"),
]


@pytest.fixture()
def dashboard(tmp_path: Path):
    """(url, fixture runs, the run without episodes) of a dashboard subprocess."""
    runs = make_runs(tmp_path / "runs")
    empty = make_run(tmp_path / "runs", "tokenhsi", seed=4, shift=0.5, now=1_700_000_500,
                     assets=tmp_path / "assets", iterations=8, frames=0)
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(tmp_path / "runs"),
                             "--port", "0", "--poll", "0.5"], cwd=ROOT, stdout=subprocess.PIPE,
                            env={**os.environ, "DETACH_ASSETS": str(tmp_path / "assets")},
                            stderr=subprocess.STDOUT, text=True)
    t0, url, seen = time.monotonic(), None, []
    assert proc.stdout is not None
    for line in proc.stdout:
        seen.append(line)
        m = re.search(r"detach-dashboard: (http://\S+)", line)
        if m:
            url = m.group(1)
            break
    startup = time.monotonic() - t0
    try:
        assert url, "".join(seen)
        assert startup < STARTUP_S, f"startup took {startup:.2f} s"
        yield url, runs, empty
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _scene_shot(page, path: Path) -> np.ndarray:
    """Screenshot of the 3D view left of the control panel (the panel text changes with
    the selected run, so it must not count as a scene change)."""
    from PIL import Image

    panel = page.get_by_role("tablist").first.bounding_box()
    view = page.viewport_size
    clip = {"x": 0, "y": 0, "width": max(100, panel["x"] - 20), "height": view["height"]}
    png = page.screenshot(path=str(path), clip=clip)
    return np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float64)


def _line_pixels(page, chart, path: Path) -> int:
    """Pixels of a chart's plot area drawn in the first run's colour (the legend's colour
    marker is outside the canvas)."""
    from PIL import Image

    canvas = chart.locator("canvas").first
    canvas.scroll_into_view_if_needed(timeout=WAIT_MS)
    box = canvas.bounding_box(timeout=WAIT_MS)
    png = page.screenshot(path=str(path), clip=box)
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)
    return int((np.abs(rgb - np.array(LINE_RGB)).sum(axis=-1) < 60).sum())


def _select(page, label: str, option: str) -> None:
    """Pick `option` in the viser dropdown labelled `label` (a Mantine Select)."""
    page.get_by_role("combobox", name=label).click(force=True, timeout=WAIT_MS)
    page.get_by_role("option", name=option, exact=True).click(force=True, timeout=WAIT_MS)


def _tab(page, name: str) -> None:
    page.get_by_role("tab", name=name).first.click(force=True, timeout=WAIT_MS)


def _open(browser, url: str, width: int = 1400, height: int = 900):
    from playwright.sync_api import Error

    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(WAIT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(url)
    page.get_by_role("tab", name="Curves").first.wait_for(timeout=WAIT_MS)
    for close in page.locator(".mantine-Notification-closeButton").all():
        try:  # the "software WebGL" notice covers the canvas; best effort
            close.click(force=True, timeout=10_000)
        except Error:
            pass
    return page, errors


def test_dashboard_in_chromium(dashboard, tmp_path: Path) -> None:
    from playwright.sync_api import expect, sync_playwright

    url, runs, empty = dashboard
    ids = [r.path.name for r in runs]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
        try:
            a, errors_a = _open(browser, url)

            # Runs tab: the fixture runs, the broken one with its reason.
            expect(a.get_by_text("status.json unreadable").first).to_be_visible(timeout=WAIT_MS)
            expect(a.get_by_text("unreadable", exact=True).first).to_be_visible()
            a.screenshot(path=str(tmp_path / "runs_panel.png"))

            # Defect 1: Success/late starts at iteration 10 of 20 and has a drawn line.
            _tab(a, "Curves")
            late = a.locator(".uplot").filter(has_text="Episode_Success/late")
            expect(late).to_be_visible(timeout=WAIT_MS)
            box = late.bounding_box()
            assert box and box["width"] > 50 and box["height"] > 50, box
            deadline, pixels = time.monotonic() + 30, 0
            while time.monotonic() < deadline and pixels <= 40:
                pixels = _line_pixels(a, late, tmp_path / "late_metric.png")
                time.sleep(0.5)
            assert pixels > 40, f"no line drawn for the late metric ({pixels} pixels)"

            # Defect 3: page A compares a second run; page B keeps its own selection.
            b, errors_b = _open(browser, url, 900, 700)
            _tab(a, "Runs")
            a.get_by_label("mlp lh1 s0", exact=True).check(force=True, timeout=WAIT_MS)
            _tab(a, "Curves")
            expect(a.get_by_text("2 run(s):")).to_be_visible(timeout=WAIT_MS)
            a.screenshot(path=str(tmp_path / "curves_a.png"))
            _tab(b, "Curves")
            expect(b.get_by_text("1 run(s):")).to_be_visible(timeout=WAIT_MS)
            _tab(b, "Runs")
            expect(b.get_by_label("mlp lh1 s0", exact=True)).not_to_be_checked(timeout=WAIT_MS)
            b.close()

            # 3D view: pause, show run 0, then run 1; the scene must differ.
            _tab(a, "Replay")
            a.get_by_role("button", name="Pause").click(force=True, timeout=WAIT_MS)
            expect(a.get_by_role("button", name="Play")).to_be_visible(timeout=WAIT_MS)
            _select(a, "Run", ids[0])
            expect(a.get_by_text(f"{ids[0]} (finished)")).to_be_visible(timeout=WAIT_MS)
            expect(a.get_by_text("current subtask").first).to_be_visible(timeout=WAIT_MS)
            time.sleep(1.5)
            first = _scene_shot(a, tmp_path / "scene_run0.png")
            assert first.std() > 8.0, f"3D view looks blank (pixel std {first.std():.1f})"
            _select(a, "Run", ids[1])
            expect(a.get_by_text(f"{ids[1]} (finished)")).to_be_visible(timeout=WAIT_MS)
            deadline, diff = time.monotonic() + 30, 0.0
            while time.monotonic() < deadline:
                time.sleep(0.5)
                second = _scene_shot(a, tmp_path / "scene_run1.png")
                diff = np.abs(first - second).mean()
                if diff > 2.0:
                    break
            assert diff > 2.0, f"switching runs did not change the 3D view (diff {diff:.2f})"

            # Defect 4: a run without episodes clears the episode, frame and subtask.
            _select(a, "Run", empty.path.name)
            expect(a.get_by_text("no episode recorded in this run's log")).to_be_visible(
                timeout=WAIT_MS)
            expect(a.get_by_text("no episode to replay")).to_be_visible(timeout=WAIT_MS)
            expect(a.get_by_text("current subtask")).to_have_count(0, timeout=WAIT_MS)
            expect(a.get_by_text(re.compile(r"frame \d+/\d+"))).to_have_count(0)
            a.screenshot(path=str(tmp_path / "replay_empty.png"))

            # Defect 6: the tables show n and which runs were pooled.
            _tab(a, "Tables")
            expect(a.get_by_text("Pooled runs:").first).to_be_visible(timeout=WAIT_MS)
            expect(a.get_by_role("columnheader", name="n", exact=True).first).to_be_visible()
            expect(a.get_by_text("40 (1 seed: s0)").first).to_be_visible()
            expect(a.get_by_text("paper: DETACH").first).to_be_visible()
            a.screenshot(path=str(tmp_path / "tables.png"))
            assert not errors_a and not errors_b, errors_a + errors_b
        finally:
            browser.close()
