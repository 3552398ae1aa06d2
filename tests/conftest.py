"""Test-session set-up: the assets of every shipped task are built once, before any test.

Environments only read asset folders (`detach-scene build` or the runner builds them), so the
suite builds the procedural assets of configs/tasks/*.yaml into ./assets (cached by content
hash: a warm cache costs a few file reads) exactly as `detach-scene build` would.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from detach.config import load_task
from scene_builder.assets import ensure_assets

TASKS = Path(__file__).resolve().parents[1] / "configs" / "tasks"


@pytest.fixture(scope="session", autouse=True)
def built_assets() -> None:
    for task_file in sorted(TASKS.glob("*.yaml")):
        ensure_assets(load_task(task_file), jobs=1)
