"""`detach-motion`: import mocap (BVH, CMU ASF/AMC) as clips of our humanoid, list and check
clips, write the built-in clips.

    detach-motion import PATH... [--map auto|NAME|FILE.yaml] [--skill walk] [--out DIR] [--scale S]
                                 [--fps F] [--name N] [--amc-fps 120] [--force]
    detach-motion list [DIR] [--check]
    detach-motion builtin --out DIR

`import` takes files and folders (searched recursively for .bvh and .amc); an AMC needs its
ASF skeleton: given among the paths, or found beside it (`01.asf` for `01_02.amc`, or the only
.asf in its folder). Each input gets one line as soon as it is done (also in non-terminal
logs); a bad one gets one line `detach-motion: error: FILE: ...` on stderr and the others go
on; exit status 2 if any failed. A clip file is never silently replaced by a clip from another
source (use --force).

Start-up is kept fast: this module imports only the standard library at load time; numpy,
MuJoCo and the retargeting code are imported by the commands that need them.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

MAPS_DIR = Path(__file__).parent / "maps"
MOTION_SUFFIXES = (".bvh", ".amc")


class UsageError(ValueError):
    """Bad arguments or inputs found before any import; one line."""


def _shipped_maps() -> list[str]:
    return sorted(p.stem for p in MAPS_DIR.glob("*.yaml"))


def _parser() -> argparse.ArgumentParser:
    from detach.motion.labels import MOTION_LABELS  # a plain tuple: cheap

    p = argparse.ArgumentParser(prog="detach-motion", description="Motion clips of the detach humanoid.")
    sub = p.add_subparsers(dest="cmd", required=True)
    imp = sub.add_parser("import", help="retarget BVH or ASF/AMC mocap to the humanoid and write npz clips",
                         description="Retarget mocap files to the humanoid: BVH files, CMU ASF/AMC pairs, or "
                                     "folders of them. One line per file.")
    imp.add_argument("paths", nargs="+", metavar="PATH",
                     help="BVH / AMC files (an AMC with its ASF, given here or found beside it) or folders of them")
    imp.add_argument("--map", default="auto",
                     help=f"joint map: auto (pick by joint names; default), a shipped name "
                          f"({', '.join(_shipped_maps())}) or a YAML path (format: docs/MOCAP.md)")
    imp.add_argument("--skill", default="walk", help=f"clip label, one of {', '.join(MOTION_LABELS)} (default walk)")
    imp.add_argument("--out", default=".", help="output folder (default: current folder)")
    imp.add_argument("--scale", type=float, default=None, help="metres per source unit (default: the map's)")
    imp.add_argument("--fps", type=float, default=None, help="resample to this frame rate (default: the source's)")
    imp.add_argument("--name", default=None, help="clip name for a single input (default: its file name)")
    imp.add_argument("--amc-fps", type=float, default=120.0,
                     help="frame rate of AMC files, which do not store one (default 120, CMU's)")
    imp.add_argument("--force", action="store_true", help="replace clip files written from another source")
    ls = sub.add_parser("list", help="list clips of a folder (the built-in clips without DIR)")
    ls.add_argument("dir", nargs="?", default=None)
    ls.add_argument("--check", action="store_true",
                    help="also measure kinematic plausibility (slower) and show each imported clip's retarget "
                         "check (clip%%: angles clipped, bone_deg: mean bone-direction error); flags: FLOAT (both "
                         "feet a few cm above their support in most frames), BELOW, RANGE, SELF, RETARGET (a "
                         "retarget target missed: docs/MOCAP.md)")
    bi = sub.add_parser("builtin", help="write the built-in synthetic clips as npz files")
    bi.add_argument("--out", required=True, help="output folder")
    return p


def _user_errors() -> tuple[type[Exception], ...]:
    from detach.motion.bvh_import import BvhError
    from detach.motion.clip import ClipError
    from detach.motion.joint_map import RetargetError

    return BvhError, ClipError, RetargetError, UsageError


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `detach-motion`; returns the exit code (argparse usage errors exit 2)."""
    args = _parser().parse_args(argv)
    try:
        return {"import": _import, "list": _list, "builtin": _builtin}[args.cmd](args)
    except UsageError as e:
        print(f"detach-motion: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # e.g. unwritable output folder
        print(f"detach-motion: error: {e.filename or ''}: {e.strerror or e}", file=sys.stderr)
        return 2
    except Exception as e:
        if isinstance(e, _user_errors()):
            print(f"detach-motion: error: {e}", file=sys.stderr)
            return 2
        raise


# ---- import ------------------------------------------------------------------------------------


def expand_inputs(paths: Sequence[str]) -> tuple[list[Path], list[Path]]:
    """(motion files .bvh/.amc in the given order, folders expanded sorted; ASF files given).
    UsageError for a missing path or an unsupported file type."""
    motions: list[Path] = []
    skeletons: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in MOTION_SUFFIXES)
            if not found:
                raise UsageError(f"{path}: no .bvh or .amc files in this folder")
            motions.extend(found)
        elif path.suffix.lower() == ".asf":
            if not path.is_file():
                raise UsageError(f"{path}: no such file")
            skeletons.append(path)
        elif path.suffix.lower() in MOTION_SUFFIXES or not path.exists():
            motions.append(path)  # a missing file is reported by its reader, one line
        else:
            raise UsageError(f"{path}: unsupported file type '{path.suffix}' (expected .bvh, .amc, .asf or a folder)")
    if not motions:
        raise UsageError("no motion files given (.bvh or .amc; an .asf is only the skeleton of .amc files)")
    return motions, skeletons


def skeleton_for(amc: Path, given: Sequence[Path]) -> Path:
    """The ASF of an AMC: the only one given, else a given/neighbouring one whose name is the
    AMC's subject prefix (`01.asf` for `01_02.amc`), else the only .asf beside the AMC."""
    from detach.motion.asf_import import AsfError

    subject = amc.stem.split("_")[0]
    if len(given) == 1:
        return given[0]
    for candidates in (given, sorted(amc.parent.glob("*.asf")) + sorted(amc.parent.glob("*.ASF"))):
        named = [p for p in candidates if p.stem == subject]
        if named:
            return named[0]
    beside = sorted({*amc.parent.glob("*.asf"), *amc.parent.glob("*.ASF")})
    if len(beside) == 1 and not given:
        return beside[0]
    raise AsfError(f"{amc}: no ASF skeleton for this AMC (give it: detach-motion import SUBJECT.asf {amc.name}; "
                   f"looked for {subject}.asf beside it{' and among ' + str(len(given)) + ' given' if given else ''})")


def _import(args) -> int:
    from detach.motion.labels import MOTION_LABELS

    if args.skill not in MOTION_LABELS:
        raise UsageError(f"--skill: unknown skill label {args.skill!r}; expected one of {', '.join(MOTION_LABELS)}")
    motions, skeletons = expand_inputs(args.paths)
    if args.name is not None and len(motions) > 1:
        raise UsageError(f"--name applies to a single input; {len(motions)} motion files given")
    from detach.motion.joint_map import load_map

    jmap = None if args.map == "auto" else load_map(args.map)
    written: dict[Path, Path] = {}
    failed = 0
    errors = _user_errors()
    for k, path in enumerate(motions, 1):
        prefix = f"[{k}/{len(motions)}] " if len(motions) > 1 else ""
        try:
            print(prefix + _import_one(path, skeletons, jmap, args, written), flush=True)
        except errors as e:
            failed += 1
            print(f"detach-motion: error: {e}", file=sys.stderr, flush=True)
    if len(motions) > 1:
        print(f"imported {len(motions) - failed} of {len(motions)} file(s) -> {args.out}"
              + (f"; {failed} failed" if failed else ""))
    return 2 if failed else 0


def _import_one(path: Path, skeletons: Sequence[Path], jmap, args, written: dict[Path, Path]) -> str:
    """Import one file; returns its report line."""
    from detach.motion.asf_import import read_asf_amc
    from detach.motion.bvh_import import read_bvh
    from detach.motion.clip import save_clip
    from detach.motion.retarget import retarget

    if path.suffix.lower() == ".amc":
        source = read_asf_amc(skeleton_for(path, skeletons), path, fps=args.amc_fps)
    else:
        source = read_bvh(path)
    name = args.name or path.stem
    out = Path(args.out) / f"{name}.npz"
    if out in written:
        raise UsageError(f"{path}: clip name '{name}' is already used by {written[out]} in this import; "
                         "rename one file or import them into different folders")
    _refuse_overwrite(out, path, args.force)
    clip, clipped = retarget(source, jmap, skill=args.skill, name=name, scale=args.scale, fps=args.fps)
    save_clip(clip, out)
    written[out] = path
    return _report(out, clip, clipped)


def _refuse_overwrite(out: Path, source: Path, force: bool) -> None:
    """UsageError when `out` holds a clip imported from another file (unless `force`)."""
    if force or not out.exists():
        return
    from detach.motion.clip import ClipError, load_clip

    try:
        previous = load_clip(out).meta.get("source")
    except ClipError:
        previous = None
    if previous is None or Path(previous).resolve() != source.resolve():
        raise UsageError(f"{out}: already holds a clip from {previous or 'an unknown source'}; "
                         f"use --name, another --out, or --force to replace it")


def _report(out: Path, clip, clipped: float) -> str:
    from detach.motion.plausibility import FLOAT_CLEARANCE, foot_clearance
    from detach.motion.retarget_check import RetargetCheck
    from detach.motion.travel import root_travel

    travel = root_travel(clip.root_pos, clip.fps)
    worst = ", ".join(f"{name} {frames:.0%} of frames (max {excess:.2f} rad over)"
                      for name, frames, excess in _worst_clipping(clip.meta.get("clipping", {})))
    grounded = float((foot_clearance(clip).min(axis=1) <= FLOAT_CLEARANCE).mean())
    line = (f"wrote {out}: {clip.name} skill={clip.skill} map={clip.meta.get('map')} {clip.num_frames} frames at "
            f"{clip.fps:g} fps ({clip.duration:.2f} s), root path {travel.path_length:.2f} m "
            f"(net {travel.net_displacement:.2f} m), mean path speed {travel.path_speed:.2f} m/s, "
            f"{100 * clipped:.1f}% of angles clipped to joint ranges{' (' + worst + ')' if worst else ''}, "
            f"a foot on the floor in {grounded:.0%} of frames")
    check = RetargetCheck.from_meta(clip.meta)
    if check is not None:
        line += f", {check.summary()}"
        missed = check.problems(clip.skill)
        if missed:
            line += f" (CHECK: {'; '.join(missed)})"
    if grounded < 0.5:
        line += " (FLOATING: check the map's axes/scale)"
    return line


def _worst_clipping(clipping: dict, count: int = 3) -> list[tuple[str, float, float]]:
    rows = [(name, v["frames"], math.radians(v["max_excess_deg"])) for name, v in clipping.items()]
    return sorted(rows, key=lambda r: (-r[1], -r[2]))[:count]


# ---- list / builtin ----------------------------------------------------------------------------


def _list(args) -> int:
    from detach.motion.clip import load_clips

    if args.dir is None:
        from detach.motion.builtin import builtin_clips

        clips, where = builtin_clips(), "built-in synthetic clips"
    else:
        clips, where = load_clips(args.dir), str(args.dir)
    print(f"{where}: {len(clips)} clip(s)")
    head = f"{'name':<20} {'skill':<8} {'frames':>6} {'fps':>6} {'secs':>6} {'path_m':>7} {'m/s':>5}"
    if args.check:
        head += (f" {'foot_min':>8} {'float%':>6} {'self_min':>8} {'skate':>6} {'clip%':>6} {'bone_deg':>8} "
                 f"{'worst_joint':<16} flags")
    print(head)
    for c in clips:
        print(_row(c, args.check), flush=True)
    return 0


def _row(c, check: bool) -> str:
    from detach.motion.travel import root_travel

    travel = root_travel(c.root_pos, c.fps)
    row = (f"{c.name:<20} {c.skill:<8} {c.num_frames:>6} {c.fps:>6.1f} {c.duration:>6.2f} "
           f"{travel.path_length:>7.2f} {travel.path_speed:>5.2f}")
    if check:
        from detach.motion.plausibility import check_clip

        from detach.motion.retarget_check import RetargetCheck

        p = check_clip(c)
        row += (f" {p.lowest_foot:>8.3f} {100 * p.floating_fraction:>6.1f} {p.min_self_distance:>8.3f} "
                f"{p.foot_skate:>6.2f} ")
        imported = RetargetCheck.from_meta(c.meta)
        flags = p.flags()
        if imported is None:  # built-in clips, or imported before the check existed
            row += f"{'-':>6} {'-':>8} {'-':<16} "
        else:
            worst = imported.worst(1)[0] if imported.joints else None
            row += (f"{100 * imported.clipped_fraction:>6.1f} {imported.bone_error_deg:>8.1f} "
                    f"{(f'{worst.name}:{worst.bone_error_deg:.0f}' if worst else '-'):<16} ")
            if imported.problems(c.skill):
                flags.append("RETARGET")
        row += " ".join(flags) or "-"
    return row


def _builtin(args) -> int:
    from detach.motion.builtin import builtin_clips
    from detach.motion.clip import save_clip

    clips = builtin_clips()
    for c in clips:
        save_clip(c, Path(args.out) / f"{c.name}.npz")
    print(f"wrote {len(clips)} built-in clips to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
