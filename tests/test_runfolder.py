"""detach.runfolder: the run's summary in status.json, old folders summarised from config.yaml,
and `detach-run list` and the dashboard agreeing on what a run folder says."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from detach.config import load_run_config, resolve
from detach.runfolder.folder import RunFolder
from detach.runfolder.messages import (
    MAX_TEXT, BodyGeom, RunSummary, SceneMessage, SceneObject, SceneTarget, Status,
)
from detach.runfolder.summary import summary_of_config
from detach.runs.listing import run_row
from server.run_index import RunIndex

ROOT = Path(__file__).resolve().parents[1]
OLD_RUNS = sorted((ROOT / "results/laptop").glob("*/2*/"))


def test_a_new_run_folder_carries_its_summary_in_status_json(tmp_path: Path) -> None:
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", seed=4)
    run = RunFolder.create(tmp_path, cfg)
    written = json.loads(run.status_path.read_text())["summary"]
    assert written == {"task": cfg.task_name, "model": "mlp", "seed": 4,
                       "samples_per_iteration": cfg.sim.num_envs * cfg.train.num_steps_per_env}
    assert run.summary() == summary_of_config(cfg) == RunSummary.from_json(written)
    run.set_state("running", iteration=3)
    assert run.status().summary == summary_of_config(cfg), "later updates keep it"
    assert Status.from_json(Status("queued").to_json()).summary is None


def test_old_run_folders_are_summarised_from_their_config_yaml() -> None:
    assert OLD_RUNS, "the committed cell folders of results/laptop"
    for path in OLD_RUNS[:6]:
        run = RunFolder(path)
        assert run.status().summary is None, "written before status.json had a summary"
        cfg = load_run_config(run.config_path)
        assert run.summary() == summary_of_config(cfg), path


def test_list_and_dashboard_agree_on_dead_runs_and_implausible_evaluations(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    dead = RunFolder(shutil.copytree(OLD_RUNS[0], runs / OLD_RUNS[0].name))
    status = json.loads(dead.status_path.read_text())
    dead.status_path.write_text(json.dumps({**status, "state": "running", "pid": 2**22 + 12345}))
    bad = RunFolder(shutil.copytree(OLD_RUNS[1], runs / OLD_RUNS[1].name))
    result = json.loads(bad.eval_path.read_text())
    bad.eval_path.write_text(json.dumps({**result, "trials": 0}))
    infos = {i.run_id: i for i in RunIndex(runs).refresh()}
    rows = {r["run"]: r for r in map(run_row, (dead, bad))}
    assert rows[dead.path.name]["state"] == infos[dead.path.name].shown_state == "dead"
    assert rows[bad.path.name]["lh_sr"] == "invalid"
    assert any("'trials' must be >= 1" in p for p in infos[bad.path.name].problems)
    for name, row in rows.items():
        assert (row["task"], row["model"], row["seed"]) == (infos[name].task, infos[name].model, infos[name].seed)


def test_a_malformed_scene_is_salvaged_into_a_typed_message_with_notes() -> None:
    """The dashboard draws /scene only as a `SceneMessage`: a message that breaks the format is
    salvaged part by part (the well-formed object, path and target kept; each bad part named
    in a note; one bad geom drops the geoms, so the character is drawn as a sphere per body),
    and a well-formed message reads the same as `from_json`."""
    raw = {"objects": [{"name": "ok", "pos": [0, 0, 0.5], "bbox": [1, 1, 1]}, "not an object", {"pos": "xyz"}],
           "trajectories": {"0": [[0, 0], "bad"], "1": [[0, 0], [1, 2]]},
           "targets": [{"subtask": 0, "skill": "sit" * 40, "pos": [1, 2, 0.5], "color": [999, -4, 3]},
                       {"subtask": 1, "skill": "climb", "pos": [float("nan"), 0, 0]}],
           "bodies": ["a", "b"], "body_geoms": [{"type": "capsule", "size": "x"}]}
    scene, notes = SceneMessage.salvage(raw)
    assert [o.name for o in scene.objects] == ["ok"] and scene.objects[0].quat == [1.0, 0.0, 0.0, 0.0]
    assert scene.trajectories == {"1": [[0.0, 0.0], [1.0, 2.0]]}
    assert [(t.subtask, len(t.skill), t.color) for t in scene.targets] == [(0, MAX_TEXT, [255, 0, 3])]
    assert scene.bodies == ["a", "b"] and scene.body_geoms == []
    named = " ".join(notes)
    for part in ("object 1", "object 2", "trajectory 0", "target 1", "body_geoms"):
        assert f"/scene {part}: skipped" in named, notes
    assert SceneMessage.salvage("garbage")[1] == ["/scene: skipped (expected an object, found str)"]
    good = SceneMessage("lh1", [SceneObject("box", "Box", "Box/b/mesh.obj", [1, 0, 0.2], [1, 0, 0, 0],
                                            [0.4, 0.4, 0.4], False)], {"0": [[0.0, 0.0], [1.0, 1.0]]},
                        [SceneTarget(0, "carry", [1.0, 0.0, 0.2], [1, 2, 3])], ["pelvis"],
                        [BodyGeom("pelvis", "sphere", [0.09], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])])
    wire = json.loads(json.dumps(good.to_json()))
    assert SceneMessage.salvage(wire) == (SceneMessage.from_json(wire), [])
