"""Every script in examples/ runs (with small settings) and prints what it says it shows."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("[0-9][0-9]_*.py"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _args(name: str, tmp_path: Path) -> tuple[list[str], str]:
    """Small settings per example, and a line its output must contain."""
    return {
        "01_resolve_config.py": ([], "task lh1, model detach (detach), seed 3"),
        "02_step_env.py": (["--steps", "5"], "5 steps of"),
        "03_add_reward_term.py": ([], "follow/upright"),
        "04_add_skill.py": ([], "reach success with the scripted oracle: 1.00"),
        "05_train_tiny_run.py": (["--runs", str(tmp_path / "runs"), "--iterations", "1"], ": finished, follow success"),
        "06_open_dashboard.py": (["--runs", str(tmp_path), "--port", str(_free_port()), "--seconds", "1"],
                                 "dashboard: http://127.0.0.1:"),
        "07_add_model.py": (["--runs", str(tmp_path / "runs"), "--iterations", "1"], "model 'Linear', follow success"),
    }[name]


def test_examples_are_numbered_and_documented() -> None:
    assert [p.name[:2] for p in EXAMPLES] == [f"{i:02d}" for i in range(1, len(EXAMPLES) + 1)]
    for path in EXAMPLES:
        doc = path.read_text().split('"""')[1]
        assert doc.splitlines()[0].strip() and f"python examples/{path.name}" in doc, path.name


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_runs(path: Path, tmp_path: Path) -> None:
    args, expected = _args(path.name, tmp_path)
    proc = subprocess.run([sys.executable, str(path), *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert expected in proc.stdout, proc.stdout[-2000:]
