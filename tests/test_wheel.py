"""The wheel works without the source tree: built here, installed into a fresh venv (no
network: --no-deps, the dependencies seen through a .pth line to this environment's
site-packages), run from another directory."""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd: list, cwd: Path, **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the wheel's detach, not a source tree's
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=900, env=env, **kw)
    assert proc.returncode == 0, f"{cmd}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


def _source_copy(dest: Path) -> Path:
    """The checkout's files that git knows or would add (no runs/, assets/, build/): the build
    leaves nothing in the checkout and no earlier build/ folder leaks into the wheel. A source
    tree without git (an unpacked archive) is copied without what the build makes or reads."""
    git = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, capture_output=True)
    if git.returncode != 0:
        def skip(folder: str, names: list[str]) -> set[str]:
            top = {"runs", "assets", "build", "dist", ".venv"} if Path(folder) == ROOT else set()
            return {n for n in names if n in top or n == "__pycache__" or n.endswith(".egg-info")}

        shutil.copytree(ROOT, dest, symlinks=True, ignore=skip)
        return dest
    listed = git.stdout.decode().split("\0")
    for name in filter(None, listed):
        src, dst = ROOT / name, dest / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.is_symlink():
            dst.symlink_to(src.readlink())
        elif src.is_file():
            shutil.copy2(src, dst)
    return dest


@pytest.mark.slow
def test_wheel_installs_and_runs_from_another_directory(tmp_path: Path) -> None:
    dist = tmp_path / "dist"
    source = _source_copy(tmp_path / "src")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", dist, source], cwd=tmp_path)
    (wheel,) = dist.glob("detach-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for shipped in ("detach/configs/tasks/lh1.yaml", "detach/configs/tasks/base/lh.yaml",
                    "detach/configs/models/detach.yaml", "detach/configs/sweeps/table1.yaml",
                    "detach/motion/maps/cmu.yaml", "detach/py.typed", "server/py.typed"):
        assert shipped in names, shipped
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    metadata = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "Requires-Dist: embreex==4.4.0.post1; platform_machine != \"aarch64\"" in metadata
    assert "Requires-Dist: lz4==" in metadata and "Requires-Dist: zstandard==" in metadata

    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=tmp_path)
    python = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", python, "install", "--no-deps", "--no-index", "-q", wheel],
         cwd=tmp_path)
    purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                        cwd=tmp_path).stdout.strip())
    ours = {sysconfig.get_paths()["purelib"], *site.getsitepackages()}
    (purelib / "zz_dependencies.pth").write_text("".join(f"{p}\n" for p in sorted(ours)))

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run([python, "-c", "import detach.config as c; print(c.__file__); print(c.builtin_configs())"],
                 cwd=elsewhere).stdout.split()
    assert all(Path(w).is_relative_to(venv) for w in where), where  # the wheel's, not the checkout's
    out = _run([venv / "bin" / "detach-run", "train", "lh1", "--model", "mlp", "--dry-run", "--runs", "out"],
               cwd=elsewhere).stdout
    assert out.splitlines()[-1].startswith("# run folder: out/") and out.splitlines()[-1].endswith("-lh1-mlp-s0")
    user = _run([venv / "bin" / "detach-run", "train", ROOT / "configs/tasks/follow.yaml", "--model",
                 ROOT / "configs/models/mlp.yaml", "--dry-run"], cwd=elsewhere).stdout  # user configs by path
    assert user.splitlines()[-1].endswith("-follow-mlp-s0")
    keys = _run([venv / "bin" / "detach-run", "keys", "sim"], cwd=elsewhere).stdout
    assert "sim.num_envs: int" in keys
