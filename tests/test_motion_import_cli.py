"""`detach-motion import` of several files and folders: one line per file, failures that do not
stop the batch, no silent overwrites, path length and speed, and a start-up that imports no
heavy module for --help."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from detach.motion.cli import main
from detach.motion.clip import load_clip
from detach.motion.travel import root_travel
from tests.test_motion_files import write_bvh

KNEE = np.zeros(4)
STILL = np.zeros((4, 3))


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def test_a_folder_imports_each_file_and_a_bad_one_does_not_stop_the_rest(tmp_path, capsys):
    write_bvh(tmp_path / "in" / "a" / "walk_a.bvh", "mixamo", STILL, KNEE)
    write_bvh(tmp_path / "in" / "b" / "walk_b.bvh", "hips_chest", STILL, KNEE)
    (tmp_path / "in" / "b" / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    assert main(["import", str(tmp_path / "in"), "--out", str(tmp_path / "out")]) == 2
    captured = capsys.readouterr()
    err = _lines(captured.err)
    assert len(err) == 1 and "broken.bvh" in err[0] and "Traceback" not in captured.err
    out = _lines(captured.out)
    assert out[0].startswith("[1/3] wrote ") and "walk_a" in out[0]  # sorted: a/walk_a, b/broken, b/walk_b
    assert out[1].startswith("[3/3] wrote ") and "walk_b" in out[1]
    assert out[-1] == f"imported 2 of 3 file(s) -> {tmp_path / 'out'}; 1 failed"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["walk_a.npz", "walk_b.npz"]


def test_two_inputs_with_one_name_do_not_overwrite_each_other(tmp_path, capsys):
    first = write_bvh(tmp_path / "tokenhsi" / "sit" / "mesh.bvh", "mixamo", STILL, KNEE)
    second = write_bvh(tmp_path / "tokenhsi" / "walk" / "mesh.bvh", "mixamo", STILL + [0, 0, 1.0], KNEE)
    assert main(["import", str(first), str(second), "--out", str(tmp_path / "out")]) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and "clip name 'mesh' is already used by" in err[0] and "walk/mesh.bvh" in err[0]
    assert load_clip(tmp_path / "out" / "mesh.npz").meta["source"] == str(first)


def test_an_existing_clip_from_another_source_needs_force(tmp_path, capsys):
    one = write_bvh(tmp_path / "x" / "clip.bvh", "mixamo", STILL, KNEE)
    other = write_bvh(tmp_path / "y" / "clip.bvh", "mixamo", STILL, np.full(4, 30.0))
    out = tmp_path / "out"
    assert main(["import", str(one), "--out", str(out)]) == 0
    assert main(["import", str(one), "--out", str(out)]) == 0  # the same source again: replaced quietly
    capsys.readouterr()
    assert main(["import", str(other), "--out", str(out)]) == 2
    err = _lines(capsys.readouterr().err)
    assert len(err) == 1 and "already holds a clip from" in err[0] and "--force" in err[0]
    assert load_clip(out / "clip.npz").meta["source"] == str(one)
    assert main(["import", str(other), "--out", str(out), "--force"]) == 0
    assert load_clip(out / "clip.npz").meta["source"] == str(other)


def test_usage_errors(tmp_path, capsys):
    a = write_bvh(tmp_path / "a.bvh", "mixamo", STILL, KNEE)
    b = write_bvh(tmp_path / "b.bvh", "mixamo", STILL, KNEE)
    assert main(["import", str(a), str(b), "--name", "x"]) == 2
    assert "--name applies to a single input; 2 motion files given" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["import", str(tmp_path / "empty")]) == 2
    assert "empty: no .bvh or .amc files in this folder" in capsys.readouterr().err
    (tmp_path / "notes.txt").write_text("x")
    assert main(["import", str(tmp_path / "notes.txt")]) == 2
    assert "unsupported file type '.txt'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["import"])
    assert e.value.code == 2


def test_speed_is_the_path_not_the_net_displacement(tmp_path, capsys):
    """Forward 1 m and back in 2.4 s at 30 fps (~0.83 m/s): net ~0, path 2 m."""
    t = np.linspace(0.0, 2.4, 73)
    forward = 100.0 * np.where(t < 1.2, t / 1.2, 2.0 - t / 1.2)  # cm
    root = np.stack([np.zeros_like(t), np.zeros_like(t), forward], axis=1)
    path = write_bvh(tmp_path / "there_and_back.bvh", "mixamo", root, np.zeros(len(t)))
    assert main(["import", str(path), "--out", str(tmp_path)]) == 0
    line = capsys.readouterr().out
    assert "root path 2.00 m (net 0.00 m), mean path speed 0.83 m/s" in line, line
    assert main(["list", str(tmp_path)]) == 0
    row = capsys.readouterr().out.splitlines()[2].split()
    assert row[0] == "there_and_back" and row[-2:] == ["2.00", "0.83"]


def test_root_travel_ignores_jitter_but_keeps_turns():
    fps = 120.0
    t = np.arange(0, 4.0, 1 / fps)
    circle = np.stack([np.cos(np.pi * t / 2), np.sin(np.pi * t / 2), np.zeros_like(t)], axis=1)  # 1 m radius, 4 s
    noisy = circle + np.random.default_rng(0).normal(scale=0.001, size=circle.shape)  # 1 mm mocap jitter
    travel = root_travel(noisy, fps)
    assert travel.path_length == pytest.approx(2 * np.pi, rel=0.01)
    assert travel.net_displacement < 0.02 and travel.path_speed == pytest.approx(np.pi / 2, rel=0.01)
    idle = np.random.default_rng(1).normal(scale=0.001, size=circle.shape)  # standing still, jittering
    frame_to_frame = np.linalg.norm(np.diff(idle[:, :2], axis=0), axis=1).sum() / 4.0
    assert root_travel(idle, fps).path_speed < 0.02 < 0.1 < frame_to_frame  # m/s: every-frame sums would say walking


def test_help_starts_without_heavy_imports():
    """`detach-motion --help` must not pay for torch, MuJoCo or numpy (it took ~7 s)."""
    code = ("import sys\nfrom detach.motion import cli\ntry:\n    cli.main(['import', '--help'])\n"
            "except SystemExit:\n    pass\nheavy = [m for m in ('torch', 'mujoco', 'numpy', 'trimesh') "
            "if m in sys.modules]\nprint('HEAVY', heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout
    assert "--map MAP" in out and "HEAVY []" in out, out
