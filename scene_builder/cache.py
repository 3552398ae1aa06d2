"""Build cache and atomic folders: a warm `detach-scene build` reads a few JSON files and stops.

An asset folder is current when its config.json carries the cache key of the request, a hash
of (source sha256, PIPELINE_VERSION, options) and every file the contract promises exists.
Folders are written next to their target under a temporary name and renamed at the end, so
an interrupted or failed build never leaves a half-written asset that looks current.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

PIPELINE_VERSION = "1"
"""Bump when the processing changes the output, so every cached asset is rebuilt."""

REQUIRED_FILES = ("mesh.obj", "config.json", "height_map/map2d.npy", "height_map/map2d.png", "vis/mesh.glb")


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def cache_key(source_sha256: str, options: dict[str, Any]) -> str:
    """Hash of everything that determines the output (JSON with sorted keys)."""
    payload = json.dumps({"source": source_sha256, "pipeline": PIPELINE_VERSION, "options": options}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()


def read_config(folder: Path) -> dict[str, Any] | None:
    """config.json of an asset folder, or None when missing or unreadable."""
    try:
        return json.loads((folder / "config.json").read_text())
    except (OSError, ValueError):
        return None


def is_current(folder: Path, key: str) -> bool:
    """True when `folder` is a complete asset built with this exact cache key."""
    config = read_config(folder)
    if config is None or config.get("cache_key") != key:
        return False
    hulls = config.get("collision", {}).get("files", [])
    return bool(hulls) and all((folder / name).is_file() for name in (*REQUIRED_FILES, *hulls))


@contextmanager
def atomic_folder(target: Path) -> Iterator[Path]:
    """Yield an empty temporary folder beside `target`; on success it replaces `target`.

    On an exception the temporary folder is removed and `target` is left as it was.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.parent / f".{target.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        yield tmp
        if target.exists():
            old = target.parent / f".{target.name}.old-{uuid.uuid4().hex[:8]}"
            target.rename(old)
            tmp.rename(target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(target)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
