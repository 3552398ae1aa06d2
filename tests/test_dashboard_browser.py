"""The dashboard in a real browser: headless Chromium (Debian package) driven by Playwright.

Starts `python -m server.cli` on a fixture runs folder (tests/dashboard_fixtures.py) and
checks the runs table, the curves, the 3D canvas and that switching runs changes the scene.
Screenshots are saved in the test's tmp dir. WebGL renders in software (SwiftShader).
"""

from __future__ import annotations

import io
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.dashboard_fixtures import make_runs

CHROMIUM = Path("/usr/bin/chromium")
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]
ROOT = Path(__file__).resolve().parents[1]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="needs Debian's chromium at /usr/bin/chromium "
                              "(apt-get install -y chromium)"),
]


@pytest.fixture()
def dashboard(tmp_path: Path):
    """(url, fixture runs) of a dashboard subprocess on a free port."""
    runs = make_runs(tmp_path / "runs")
    proc = subprocess.Popen([sys.executable, "-m", "server.cli", "--runs", str(tmp_path / "runs"),
                             "--port", "0", "--poll", "0.5"], cwd=ROOT, stdout=subprocess.PIPE,
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
        assert startup < 3.0, f"startup took {startup:.2f} s"
        yield url, runs
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


def _select(page, label: str, option: str) -> None:
    """Pick `option` in the viser dropdown labelled `label` (a Mantine Select)."""
    page.get_by_role("combobox", name=label).click(force=True)
    page.get_by_role("option", name=option, exact=True).click(force=True)


def test_dashboard_in_chromium(dashboard, tmp_path: Path) -> None:
    from playwright.sync_api import expect, sync_playwright

    url, runs = dashboard
    ids = [r.path.name for r in runs]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(url)
            # Runs panel: the fixture runs (table rows + compare checkboxes) and the broken one.
            for run_id in ids:
                expect(page.get_by_text(run_id, exact=True).first).to_be_visible(timeout=20000)
            expect(page.get_by_text("unreadable", exact=True).first).to_be_visible()
            expect(page.get_by_text("status.json unreadable").first).to_be_visible()
            for close in page.locator(".mantine-Notification-closeButton").all():
                close.click(force=True)  # the "software WebGL" notice covers the canvas
            page.get_by_label(ids[0], exact=True).check(force=True)  # compare both runs
            page.screenshot(path=str(tmp_path / "runs_panel.png"))

            # Curves: uPlot charts with a non-zero size, both runs in the legend.
            page.get_by_role("tab", name="Curves").click(force=True)
            chart = page.locator(".uplot canvas").first
            expect(chart).to_be_visible(timeout=15000)
            box = chart.bounding_box()
            assert box and box["width"] > 50 and box["height"] > 50, box
            expect(page.get_by_text("mlp lh1 s0").first).to_be_visible()
            expect(page.get_by_text("detach lh1 s1").first).to_be_visible()
            assert page.locator(".uplot").count() >= 8  # one chart per numeric key
            page.screenshot(path=str(tmp_path / "curves.png"))

            # 3D view: pause, show run 0, then run 1; the scene must differ.
            page.get_by_role("tab", name="Replay").click(force=True)
            page.get_by_role("button", name="Pause").click(force=True)
            expect(page.get_by_role("button", name="Play")).to_be_visible()
            _select(page, "Run", ids[0])
            expect(page.get_by_text(f"{ids[0]} (finished)")).to_be_visible(timeout=10000)
            time.sleep(1.5)
            first = _scene_shot(page, tmp_path / "scene_run0.png")
            assert first.std() > 8.0, f"3D view looks blank (pixel std {first.std():.1f})"
            time.sleep(0.5)
            again = _scene_shot(page, tmp_path / "scene_run0_again.png")
            assert np.abs(first - again).mean() < 1.0, "paused view should stay still"
            _select(page, "Run", ids[1])
            expect(page.get_by_text(f"{ids[1]} (finished)")).to_be_visible(timeout=10000)
            deadline, diff = time.monotonic() + 10, 0.0
            while time.monotonic() < deadline:
                time.sleep(0.5)
                second = _scene_shot(page, tmp_path / "scene_run1.png")
                diff = np.abs(first - second).mean()
                if diff > 2.0:
                    break
            assert diff > 2.0, f"switching runs did not change the 3D view (diff {diff:.2f})"
            expect(page.get_by_text("current subtask").first).to_be_visible()
            page.get_by_role("button", name="Play").click(force=True)
            time.sleep(0.7)
            page.screenshot(path=str(tmp_path / "replay.png"))

            # Tables: the paper's tables over both runs' eval*.json files.
            page.get_by_role("tab", name="Tables").click(force=True)
            expect(page.get_by_text("DETACH (ours)").first).to_be_visible(timeout=10000)
            expect(page.get_by_text("Ablation on LH3").first).to_be_visible()
            page.screenshot(path=str(tmp_path / "tables.png"))
        finally:
            browser.close()
