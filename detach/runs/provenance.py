"""provenance.json: what code on what machine produced a run.

One record per start of training (the first, then one per resume): UTC time, the command
line and working directory, Python, the platform and host, the versions of detach and of
every installed package it depends on, the torch device (GPU name and CUDA version on a GPU,
torch threads on the CPU), and the git state of the source tree detach was imported from:
commit, branch, whether it is dirty, the diff against the commit (`git diff HEAD`, cut at
`MAX_DIFF` characters) and the untracked files (names only). An installed wheel outside a
git work tree records `git: null`.
"""

from __future__ import annotations

import datetime
import os
import platform
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import torch

from detach.runfolder.atomic import atomic_write_json
from detach.runfolder.folder import RunFolder, read_json

CODE_PATHS = ("detach", "scene_builder", "configs", "pyproject.toml")
"""What decides a run's behaviour besides its config.yaml (docs and results do not)."""
MAX_DIFF = 500_000
"""Characters of `git diff HEAD` kept (a larger diff is cut and says so)."""
KEY_PACKAGES = ("detach", "torch", "mujoco", "rsl-rl-lib", "tensordict", "numpy")


def _git(args: list[str], cwd: Path) -> str | None:
    try:
        proc = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return proc.stdout if proc.returncode == 0 else None


def git_state(source: Path | None = None) -> dict[str, Any] | None:
    """Commit, branch, dirty flag, diff and untracked files of the work tree holding `source`
    (default: detach's own source); None outside a git work tree."""
    source = source or Path(__file__).resolve().parents[1]  # the detach package's folder
    top = _git(["rev-parse", "--show-toplevel"], source)
    if top is None:
        return None
    root = Path(top.strip())
    commit = (_git(["rev-parse", "HEAD"], root) or "").strip() or None
    branch = (_git(["rev-parse", "--abbrev-ref", "HEAD"], root) or "").strip() or None
    diff = _git(["diff", "HEAD", "--no-ext-diff", "--no-color"], root) or ""
    untracked = [line for line in (_git(["ls-files", "--others", "--exclude-standard"], root) or "").splitlines()
                 if line]
    truncated = len(diff) > MAX_DIFF
    return {"root": str(root), "commit": commit, "branch": branch, "dirty": bool(diff or untracked),
            "diff": diff[:MAX_DIFF] + (f"\n... cut at {MAX_DIFF} of {len(diff)} characters\n" if truncated else ""),
            "untracked": untracked}


def package_versions() -> dict[str, str]:
    """detach and every package it requires (its extras too) that is installed, by name."""
    names = list(KEY_PACKAGES)
    try:
        for req in metadata.requires("detach") or []:
            name = re.split(r"[\s;<>=!~\[(]", req, maxsplit=1)[0]
            if name and name not in names:
                names.append(name)
    except metadata.PackageNotFoundError:
        pass
    versions = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return dict(sorted(versions.items(), key=lambda kv: kv[0].lower()))


def device_info(device: str) -> dict[str, Any]:
    info: dict[str, Any] = {"device": device, "torch_threads": torch.get_num_threads(),
                            "cpu_count": os.cpu_count()}
    if device.startswith("cuda") and torch.cuda.is_available():
        index = torch.device(device).index or 0
        info.update(gpu=torch.cuda.get_device_name(index), cuda=torch.version.cuda,
                    gpu_count=torch.cuda.device_count())
    return info


def provenance_record(device: str, resumed: bool = False) -> dict[str, Any]:
    return {"time": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "resumed": resumed, "command": list(sys.argv), "cwd": os.getcwd(),
            "python": sys.version.split()[0], "python_executable": sys.executable,
            "platform": platform.platform(), "host": platform.node(),
            "packages": package_versions(), "device": device_info(device), "git": git_state()}


def write_provenance(run: RunFolder, device: str, resumed: bool = False) -> Path:
    """Add this start's record to the run's provenance.json: `{"runs": [first, resume, ...]}`."""
    path = run.provenance_path
    records: list[dict[str, Any]] = []
    if resumed and path.exists():
        try:
            old = read_json(path)
            records = list(old.get("runs", [])) if isinstance(old, dict) else []
        except (OSError, ValueError):
            records = []
    records.append(provenance_record(device, resumed))
    atomic_write_json(path, {"runs": records})
    return path


def last_git(run: RunFolder) -> dict[str, Any] | None:
    """The git state of the run's last start or resume (provenance.json), None where unknown."""
    path = run.provenance_path
    try:
        records = read_json(path).get("runs", []) if path.exists() else []
    except (OSError, ValueError, AttributeError):
        return None
    git = records[-1].get("git") if records and isinstance(records[-1], dict) else None
    return git if isinstance(git, dict) else None


def code_change_since(run: RunFolder, current: dict[str, Any] | None = None) -> str | None:
    """A warning when the code about to resume `run` differs from the code that trained its last
    stretch, else None. A sweep's cell key digests the config, not the code, so a cell
    interrupted before a reward or physics change resumes under the new code without this.
    Says nothing when either side is not a git work tree (the versions cannot be compared)."""
    before = last_git(run)
    now = current if current is not None else git_state()
    if not before or not now or not before.get("commit") or not now.get("commit"):
        return None
    same_commit, same_diff = before["commit"] == now["commit"], before.get("diff", "") == now.get("diff", "")
    if same_commit and same_diff:
        return None
    changed = _git(["diff", "--name-only", before["commit"], "--", *CODE_PATHS], Path(now["root"]))
    if changed is not None and not changed.strip() and not before.get("diff") and not now.get("diff"):
        return None  # commits differ only outside the code (docs, results)
    files = sorted(set((changed or "").split())) if changed is not None else []
    what = (f"{len(files)} code file(s) differ: {', '.join(files[:8])}{' ...' if len(files) > 8 else ''}"
            if files else "the code cannot be compared file by file" if changed is None
            else "uncommitted changes differ")
    return (f"warning: {run.path.name} last trained with code at commit {before['commit'][:10]}"
            f"{' (uncommitted changes)' if before.get('diff') else ''}; it resumes with "
            f"{now['commit'][:10]}{' (uncommitted changes)' if now.get('diff') else ''}: {what}. "
            f"The iterations from here run under the new code.")
