"""`detach-run play` (live viewer, camera following the character) and `--video` on `eval`
and `play` (offscreen MuJoCo on EGL or OSMesa, mp4 through PyAV), headless."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from detach import cli
from detach.runfolder.folder import RunFolder, find_runs

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=2", "train.num_steps_per_env=8", "eval.num_envs=1",
        "env.episode_length=40"]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunFolder:
    runs = tmp_path_factory.mktemp("runs")
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(runs), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    (folder,) = find_runs(runs)
    return folder


def _detach_run(*args: str) -> subprocess.CompletedProcess:
    """A fresh process: MuJoCo chooses its OpenGL platform when first imported."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    return subprocess.run([sys.executable, "-m", "detach.cli", *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=600)


def _frames(path: Path) -> list[np.ndarray]:
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


def _path_pixels(frame: np.ndarray) -> int:
    """Pixels of the Follow path ahead of the reference point (PATH_COLOR, cyan, lit):
    little red, much green and blue; the grey-blue floor and the brown puppet have red."""
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    return int(((r < 90) & (g > 120) & (b > 140) & (b - r > 90)).sum())


def _target_pixels(frame: np.ndarray) -> int:
    """Pixels of Follow's target and its ring (the skill's green, lit)."""
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    return int(((g - r > 60) & (g - b > 40)).sum())


def _verdict_pixels(frame: np.ndarray) -> int:
    """Pixels of the failure mark (red disc and caption)."""
    r, g, b = (frame[..., k].astype(int) for k in range(3))
    return int(((r > 180) & (g < 90) & (b < 90)).sum())


def test_eval_video_shows_the_task(run: RunFolder, tmp_path: Path) -> None:
    """Issue 61 item 2: a Follow evaluation's --video shows the path and the target (absent
    from the same rollout rendered without markers), and the episode's end holds its
    verdict mark."""
    from detach.runs.play import VERDICT_HOLD_S

    out = tmp_path / "eval.mp4"
    proc = _detach_run("eval", str(run.path), "--trials", "1", "--video", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "video written to" in proc.stdout and run.eval_result().trials == 1
    frames = _frames(out)
    assert len(frames) >= 2 and frames[0].shape == (480, 640, 3)
    assert 5 < float(frames[0].mean()) < 250  # a rendered scene, not a blank frame
    start = frames[:5]
    assert all(_path_pixels(f) > 100 for f in start), [_path_pixels(f) for f in start]
    assert all(_target_pixels(f) > 300 for f in start), [_target_pixels(f) for f in start]
    hold = round(VERDICT_HOLD_S * 30)
    assert all(np.array_equal(frames[-1], f) or np.abs(frames[-1].astype(int) - f).mean() < 2
               for f in frames[-hold:]), "the last frame is held"
    success = run.eval_result().lh_chain.rate == 1.0
    if not success:  # a 1-iteration policy fails: the red mark
        assert _verdict_pixels(frames[-1]) > 1000 and _verdict_pixels(frames[0]) < 50

    plain = tmp_path / "plain.mp4"
    script = ("import sys; from pathlib import Path; from detach.runs.video import choose_gl; choose_gl(); "
              "from detach.runfolder.folder import RunFolder; "
              "from detach.runs.play import PolicyRollout, record_video; "
              "record_video(PolicyRollout(RunFolder(Path(sys.argv[1]))), Path(sys.argv[2]), steps=5, markers=False)")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    proc = subprocess.run([sys.executable, "-c", script, str(run.path), str(plain)], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    bare = _frames(plain)[:5]
    assert all(_path_pixels(f) < 20 and _target_pixels(f) < 20 for f in bare), \
        [(_path_pixels(f), _target_pixels(f)) for f in bare]


def test_play_video_steps_and_size(run: RunFolder, tmp_path: Path) -> None:
    out = tmp_path / "play.mp4"
    proc = _detach_run("play", str(run.path), "--video", str(out), "--steps", "12", "--width", "320",
                       "--height", "240")
    assert proc.returncode == 0, proc.stderr[-2000:]
    frames = _frames(out)
    assert len(frames) == 13 and frames[0].shape == (240, 320, 3)
    assert not np.array_equal(frames[0], frames[-1])  # the character moved (and the camera followed it)


def test_play_live_in_viser(run: RunFolder) -> None:
    import viser

    from detach.runs.play import PolicyRollout
    from server.play_view import follow_camera, play_live

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        rollout = PolicyRollout(run)
        assert play_live(rollout, steps=5, realtime=False, server=server) == 5
        assert rollout.frame == 5 and rollout.scene.bodies
        drawn = set(server.scene._handle_from_node_name)  # the task markers of the last frame
        assert {"/play/task/path_remaining", "/play/task/target_0", "/play/task/caption"} <= drawn, drawn
        camera = SimpleNamespace(position=(3.0, 0.0, 2.0), look_at=(0.0, 0.0, 0.9))
        client = SimpleNamespace(camera=camera, atomic=lambda: _Null())
        fake = SimpleNamespace(get_clients=lambda: {0: client})
        root = np.asarray(rollout.snapshot().body_pos[0])
        follow_camera(fake, root)
        assert np.allclose(camera.look_at, [root[0], root[1], 0.9])
        assert np.allclose(np.subtract(camera.position, camera.look_at), [3.0, 0.0, 1.1])  # the user's angle kept
    finally:
        server.stop()


class _Null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def test_play_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["play", str(tmp_path / "missing")]) == 2
    assert "run folder or checkpoint not found" in capsys.readouterr().err
