"""`benchmarks/gpu_check.py` keeps what it measured when a section fails: on a lent GPU machine
a crash in one section must not cost the figures of the others (the lease is short)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _gpu_check():
    spec = importlib.util.spec_from_file_location("gpu_check", ROOT / "benchmarks" / "gpu_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_failed_section_is_reported_and_the_figures_so_far_are_written(tmp_path: Path) -> None:
    g = _gpu_check()
    report = {"date": "today", "device": "cpu", "device_name": "CPU", "versions": "v", "wall_s": 60.0}
    g._section(report, "env", tmp_path, lambda: {"n": 8, "env_steps_per_s": 123.0})
    g._section(report, "raw", tmp_path, lambda: 1 / 0)
    written = json.loads((tmp_path / "gpu_check.json").read_text())
    assert written["env"]["env_steps_per_s"] == 123.0 and "raw" not in written
    assert written["errors"] == {"raw": "ZeroDivisionError: division by zero"}
    text = g.markdown(report)
    assert "| env control steps/s, random actions | 8 | 123 |" in text
    assert "Section raw failed: ZeroDivisionError: division by zero" in text
