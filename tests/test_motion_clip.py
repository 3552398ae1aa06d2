"""Motion clip npz format: round trip and one-line validation errors naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from detach.character.body import BODY_NAMES, DOF_NAMES
from detach.motion.clip import ClipError, MotionClip, clip_from_arrays, load_clip, load_clips, save_clip


def make_clip(name: str = "c", skill: str = "walk", frames: int = 5, fps: float = 30.0) -> MotionClip:
    rng = np.random.default_rng(0)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
    return clip_from_arrays(name, skill, fps, rng.normal(size=(frames, 3)), quat,
                            rng.uniform(-0.1, 0.1, size=(frames, len(DOF_NAMES))),
                            rng.normal(size=(frames, len(BODY_NAMES), 3)), meta={"note": "test"})


def test_round_trip(tmp_path):
    clip = make_clip()
    path = save_clip(clip, tmp_path / "sub" / "c.npz")
    back = load_clip(path)
    assert (back.name, back.skill, back.fps, back.meta) == ("c", "walk", 30.0, {"note": "test"})
    for key in ("root_pos", "root_quat", "dof_pos", "body_pos"):
        np.testing.assert_allclose(getattr(back, key), getattr(clip, key), atol=1e-6)
    assert back.num_frames == 5 and back.duration == pytest.approx(4 / 30)
    assert [c.name for c in load_clips(tmp_path / "sub")] == ["c"]
    assert not list((tmp_path / "sub").glob("*.tmp"))  # atomic write left no temp file


def _write(path, **over):
    clip = make_clip()
    data = dict(name=clip.name, skill=clip.skill, fps=clip.fps, root_pos=clip.root_pos, root_quat=clip.root_quat,
                dof_pos=clip.dof_pos, body_pos=clip.body_pos, dof_names=np.array(DOF_NAMES),
                body_names=np.array(BODY_NAMES))
    data.update(over)
    data = {k: v for k, v in data.items() if v is not None}
    np.savez(path, **data)
    return path


@pytest.mark.parametrize("over, expect", [
    (dict(dof_pos=np.zeros((5, 31))), "dof_pos has shape [5, 31], expected [5, 32]"),
    (dict(body_pos=np.zeros((4, 15, 3))), "body_pos has shape [4, 15, 3], expected [5, 15, 3]"),
    (dict(root_pos=np.full((5, 3), np.nan)), "root_pos contains NaN"),
    (dict(skill="dance"), "unknown skill label 'dance'"),
    (dict(fps=-1.0), "fps must be a positive number"),
    (dict(root_quat=np.zeros((5, 4))), "root_quat is not unit length"),
    (dict(body_pos=None), "missing key(s) body_pos"),
    (dict(dof_names=np.array(DOF_NAMES[::-1])), "dof_names do not match"),
])
def test_validation_errors_name_the_file(tmp_path, over, expect):
    path = _write(tmp_path / "bad.npz", **over)
    with pytest.raises(ClipError) as e:
        load_clip(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and expect in msg and "\n" not in msg


def test_not_a_clip_and_missing(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip at all")
    with pytest.raises(ClipError, match="junk.npz: not a motion clip npz"):
        load_clip(junk)
    with pytest.raises(ClipError, match="nope.npz: no such file"):
        load_clip(tmp_path / "nope.npz")
    with pytest.raises(ClipError, match="no such folder"):
        load_clips(tmp_path / "none")


def test_save_refuses_invalid_clip(tmp_path):
    clip = make_clip()
    clip.skill = "fly"
    with pytest.raises(ClipError, match="x.npz: unknown skill label 'fly'"):
        save_clip(clip, tmp_path / "x.npz")
    assert not (tmp_path / "x.npz").exists()
