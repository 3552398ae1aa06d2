"""A model is a plug-in: `linear`, defined in examples/linear_model.py alone (the module of
examples/07_add_model.py) plus a model YAML written here, trains, evaluates in a fresh process
through the public CLI (the kind recorded in config.yaml imports its module) and gets its row
label in the tables, without touching any other file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from detach import cli
from detach.eval.tables import skills_table
from detach.models import registered_models, unregister_model
from detach.runfolder.folder import find_runs

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


@pytest.fixture()
def linear_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))  # an importable module outside the package
    model = tmp_path / "linear.yaml"
    model.write_text(f"extends: {ROOT / 'configs' / 'models' / 'base' / 'ppo.yaml'}\n"
                     "model: {kind: 'linear_model:LinearCfg', width: 32, adapter_units: [64]}\n")
    yield model
    if any(e.kind == "linear" for e in registered_models()):
        unregister_model("linear")


def test_a_model_defined_outside_the_package_trains_and_evaluates(linear_model: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    code = cli.main(["train", "follow", "--model", str(linear_model), "--runs", str(runs), "--trials", "2",
                     "env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
                     "env.episode_length=60", "train.max_iterations=2"])
    assert code == 0
    run = find_runs(runs)[-1]
    assert "linear_model:LinearCfg" in (run.path / "config.yaml").read_text()
    assert any(e.kind == "linear" for e in registered_models())

    path = os.pathsep.join(p for p in (str(EXAMPLES), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": path}
    proc = subprocess.run([sys.executable, "-m", "detach.cli", "eval", str(run.path), "--trials", "2", "--replace"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = run.eval_result()
    assert result.model == "linear" and result.trials == 2
    assert skills_table([result], task="follow").rows[0][0] == "Linear"  # its register_model label
