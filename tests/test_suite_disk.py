"""The test suite keeps its temporary run folders only for failed tests.

A full run writes ~5 GB of run folders (a paper-sized network's checkpoint is 66 MB even with
4 envs); pytest's default keeps every one of them for the last three sessions, and a CI on a
shared disk once failed its last tests with "No space left on device". The project's pytest
settings (pyproject.toml) must remove a passing test's folder.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

INNER = '''
import pytest

@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    d = tmp_path_factory.mktemp("shared_run")
    (d / "model_0.pt").write_bytes(b"x" * 100_000)
    return d

def test_passes(tmp_path, shared):
    (tmp_path / "model_1.pt").write_bytes(b"x" * 100_000)

def test_fails(tmp_path):
    (tmp_path / "kept.txt").write_text("look at me")
    assert False
'''


def _session(tmp_path: Path, tests: str) -> tuple[int, list[Path]]:
    """Run the tests in `tests` under the project's pytest settings; (exit code, files left)."""
    (tmp_path / "test_inner.py").write_text(tests)
    temproot = tmp_path / "temproot"
    temproot.mkdir()
    env = {**os.environ, "PYTEST_DEBUG_TEMPROOT": str(temproot)}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-c", str(ROOT / "pyproject.toml"), "--rootdir", str(tmp_path),
                           str(tmp_path / "test_inner.py")], env=env, capture_output=True, text=True, timeout=120)
    return proc.returncode, [p for p in temproot.rglob("*") if p.is_file()]


def test_a_passing_tests_folder_is_removed_a_failing_ones_kept(tmp_path: Path) -> None:
    code, left = _session(tmp_path, INNER)
    assert code == 1
    names = {p.name for p in left}
    assert "kept.txt" in names  # a failure's folder stays to be looked at
    assert "model_1.pt" not in names


def test_a_green_session_leaves_nothing(tmp_path: Path) -> None:
    code, left = _session(tmp_path, INNER.replace("assert False", "pass"))
    assert code == 0
    assert left == []
