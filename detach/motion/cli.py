"""`detach-motion`: import BVH clips, list clips, write the built-in clips.

    detach-motion import FILE.bvh --map cmu [--skill walk] [--out DIR] [--scale S] [--fps F] [--name N]
    detach-motion list [DIR] [--check]
    detach-motion builtin --out DIR

User errors (missing/invalid files, unknown map or skill, a map joint missing from the BVH)
print one line `detach-motion: error: ...` naming the file and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from detach.motion.bvh_import import BvhError
from detach.motion.clip import ClipError, MotionClip, load_clips, save_clip
from detach.motion.retarget import RetargetError, available_maps
from detach.motion.labels import MOTION_LABELS

_USER_ERRORS = (BvhError, ClipError, RetargetError)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="detach-motion", description="Motion clips of the detach humanoid.")
    sub = p.add_subparsers(dest="cmd", required=True)
    imp = sub.add_parser("import", help="retarget a BVH file to the humanoid and write an npz clip")
    imp.add_argument("file", help="BVH file")
    imp.add_argument("--map", default="cmu",
                     help=f"joint map: a shipped name ({', '.join(available_maps())}) or a YAML path (default cmu)")
    imp.add_argument("--skill", default="walk", help=f"clip label, one of {', '.join(MOTION_LABELS)} (default walk)")
    imp.add_argument("--out", default=".", help="output folder (default: current folder)")
    imp.add_argument("--scale", type=float, default=None, help="metres per BVH unit (default: the map's)")
    imp.add_argument("--fps", type=float, default=None, help="resample to this frame rate (default: the BVH's)")
    imp.add_argument("--name", default=None, help="clip name (default: the file name without extension)")
    ls = sub.add_parser("list", help="list clips of a folder (the built-in clips without DIR)")
    ls.add_argument("dir", nargs="?", default=None)
    ls.add_argument("--check", action="store_true", help="also measure kinematic plausibility (slower)")
    bi = sub.add_parser("builtin", help="write the built-in synthetic clips as npz files")
    bi.add_argument("--out", required=True, help="output folder")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return {"import": _import, "list": _list, "builtin": _builtin}[args.cmd](args)
    except _USER_ERRORS as e:
        print(f"detach-motion: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # e.g. unwritable output folder
        print(f"detach-motion: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 2


def _import(args) -> int:
    from detach.motion.retarget import import_bvh

    if args.skill not in MOTION_LABELS:
        raise ClipError(f"{args.file}: unknown skill label {args.skill!r}; expected one of {', '.join(MOTION_LABELS)}")
    clip, clipped = import_bvh(args.file, args.map, skill=args.skill, name=args.name, scale=args.scale, fps=args.fps)
    out = save_clip(clip, Path(args.out) / f"{clip.name}.npz")
    travel = float(((clip.root_pos[-1, :2] - clip.root_pos[0, :2]) ** 2).sum() ** 0.5)
    print(f"wrote {out}: {clip.name} skill={clip.skill} {clip.num_frames} frames at {clip.fps:g} fps "
          f"({clip.duration:.2f} s), root travel {travel:.2f} m, "
          f"{100 * clipped:.1f}% of angles clipped to joint ranges")
    return 0


def _list(args) -> int:
    if args.dir is None:
        from detach.motion.builtin import builtin_clips

        clips, where = builtin_clips(), "built-in synthetic clips"
    else:
        clips, where = load_clips(args.dir), str(args.dir)
    print(f"{where}: {len(clips)} clip(s)")
    head = f"{'name':<20} {'skill':<8} {'frames':>6} {'fps':>6} {'secs':>6} {'m/s':>5}"
    if args.check:
        head += f" {'foot_min':>8} {'self_min':>8} {'skate':>6}"
    print(head)
    for c in clips:
        print(_row(c, args.check))
    return 0


def _row(c: MotionClip, check: bool) -> str:
    speed = float(((c.root_pos[-1, :2] - c.root_pos[0, :2]) ** 2).sum() ** 0.5) / max(c.duration, 1e-9)
    row = f"{c.name:<20} {c.skill:<8} {c.num_frames:>6} {c.fps:>6.1f} {c.duration:>6.2f} {speed:>5.2f}"
    if check:
        from detach.motion.plausibility import check_clip

        p = check_clip(c)
        row += f" {p.lowest_foot:>8.3f} {p.min_self_distance:>8.3f} {p.foot_skate:>6.2f}"
    return row


def _builtin(args) -> int:
    from detach.motion.builtin import builtin_clips

    clips = builtin_clips()
    for c in clips:
        save_clip(c, Path(args.out) / f"{c.name}.npz")
    print(f"wrote {len(clips)} built-in clips to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
