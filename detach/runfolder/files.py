"""The one reader of a run folder's files, for the CLI and the dashboard alike.

A run folder may be hostile (a shared runs folder, a folder copied from elsewhere) or just
broken, and its readers run unattended (`detach-run list`, `detach-run table`, the
dashboard's poll thread, which holds a lock while it reads). So every file is opened here,
and only if it is:
- a regular file: a FIFO would block `open()` forever, `/dev/zero` would never end;
- inside the run folder once symlinks are resolved: a `config.yaml -> /etc/shadow` link
  would otherwise be shown to every browser;
- no larger than the cap of its kind (`MAX_BYTES`), read no further than that;
- for YAML, no more than `MAX_YAML_NODES` values once aliases are expanded (an alias bomb
  of a few hundred bytes expands to gigabytes) and `MAX_YAML_DEPTH` levels.
Each refusal is a `RunFileError`: one line naming the file and why. Nothing here blocks.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

import yaml

from detach.config.yaml_source import MAX_YAML_DEPTH, MAX_YAML_NODES

MB = 1024 * 1024
MAX_BYTES: dict[str, int] = {".json": 16 * MB, ".yaml": 4 * MB, ".log": 64 * MB}
"""The largest file of each kind read (status.json and eval.json are a few KB, a resolved
config.yaml tens of KB); other kinds (log.mcap, checkpoints) are only checked, not read."""
DEFAULT_MAX_BYTES = 16 * MB


class RunFileError(ValueError):
    """A file of a run folder that is refused: its message is one line, `path: why`."""

    def __init__(self, path: Path, why: str) -> None:
        super().__init__(f"{path}: {why}")
        self.path, self.why = Path(path), why


def _kind(st_mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISDIR, "a directory")):
        if test(st_mode):
            return name
    return "not a regular file"


def resolve_inside(run_dir: Path, name: str | Path) -> Path:
    """`run_dir/name` with symlinks resolved, if it stays inside the run folder (RunFileError
    if it leaves it; FileNotFoundError passes through when it does not exist)."""
    path = Path(run_dir) / name
    root = Path(os.path.realpath(run_dir))
    real = Path(os.path.realpath(path))
    if real != root and root not in real.parents:
        raise RunFileError(path, "refused, a link that leaves the run folder")
    return real


def open_run_file(run_dir: Path, name: str | Path) -> int:
    """A read-only descriptor of a regular file inside the run folder; never blocks (a FIFO is
    opened non-blocking, then refused). OSError if missing or unreadable."""
    path = Path(run_dir) / name
    real = resolve_inside(run_dir, name)
    fd = os.open(real, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise RunFileError(path, f"refused, {_kind(mode)} instead of a regular file")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def check_run_file(run_dir: Path, name: str | Path, max_bytes: int | None = None) -> Path:
    """The path of a regular file inside the run folder within its size cap (RunFileError if
    not, OSError if missing): for readers that open the file themselves."""
    fd = open_run_file(run_dir, name)
    try:
        size = os.fstat(fd).st_size
    finally:
        os.close(fd)
    path = Path(run_dir) / name
    limit = _limit(path, max_bytes)
    if size > limit:
        raise RunFileError(path, f"refused, larger than {_size(limit)} ({_size(size)})")
    return path


def _limit(path: Path, max_bytes: int | None) -> int:
    return max_bytes if max_bytes is not None else MAX_BYTES.get(path.suffix, DEFAULT_MAX_BYTES)


def _size(n: int) -> str:
    return f"{n / MB:.0f} MB" if n >= MB else f"{n} bytes"


def read_bytes(run_dir: Path, name: str | Path, max_bytes: int | None = None) -> bytes:
    """A whole file of the run folder, refused (RunFileError) past its kind's cap."""
    path = Path(run_dir) / name
    limit = _limit(path, max_bytes)
    fd = open_run_file(run_dir, name)
    with os.fdopen(fd, "rb") as f:
        if os.fstat(f.fileno()).st_size > limit:
            raise RunFileError(path, f"refused, larger than {_size(limit)} "
                                     f"({_size(os.fstat(f.fileno()).st_size)})")
        data = f.read(limit + 1)
    if len(data) > limit:
        raise RunFileError(path, f"refused, larger than {_size(limit)}")
    return data


def read_text(run_dir: Path, name: str | Path, max_bytes: int | None = None) -> str:
    """A UTF-8 file of the run folder (RunFileError if it is not UTF-8)."""
    data = read_bytes(run_dir, name, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RunFileError(Path(run_dir) / name, "expected UTF-8 text, found undecodable bytes") from None


def read_tail(run_dir: Path, name: str | Path, max_bytes: int) -> str:
    """The last `max_bytes` of a growing file (stdout.log), decoded leniently."""
    fd = open_run_file(run_dir, name)
    with os.fdopen(fd, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(max(0, size - max_bytes))
        return f.read(max_bytes).decode("utf-8", errors="replace")


def read_json(run_dir: Path, name: str | Path, max_bytes: int | None = None) -> Any:
    """A JSON file of the run folder (RunFileError, a ValueError, if refused or malformed)."""
    path = Path(run_dir) / name
    data = read_bytes(run_dir, name, max_bytes)
    try:
        return json.loads(data)
    except RecursionError:
        raise RunFileError(path, "nested too deeply") from None
    except UnicodeDecodeError:  # json.loads guesses UTF-8/16/32 from the bytes; say what was expected
        raise RunFileError(path, "expected UTF-8 JSON, found undecodable bytes") from None
    except json.JSONDecodeError as exc:
        raise RunFileError(path, f"expected JSON, {exc}") from None


_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def parse_yaml(text: str, where: str) -> Any:
    """YAML text with the CLI's limits: at most `MAX_YAML_NODES` values counting every use of
    an alias, at most `MAX_YAML_DEPTH` levels (RunFileError naming `where` otherwise)."""
    try:
        node = yaml.compose(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise RunFileError(Path(where), f"not valid YAML ({problem})") from None
    except RecursionError:
        raise RunFileError(Path(where), f"nested more than {MAX_YAML_DEPTH} levels deep") from None
    if node is None:
        return None
    _count(node, where)
    try:
        return yaml.load(text, Loader=_YAML_LOADER)
    except yaml.YAMLError as exc:
        raise RunFileError(Path(where), f"not valid YAML ({str(exc).splitlines()[0]})") from None


def _count(root: yaml.Node, where: str) -> None:
    """Refuse a node graph that expands past the limits (counted without expanding it: each
    node's expanded size is computed once and shared by every alias of it)."""
    sizes: dict[int, int] = {}
    depths: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in sizes:
            continue
        children = ([n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode)
                    else list(node.value) if isinstance(node, yaml.SequenceNode) else [])
        if not done:
            if len(stack) > 4 * MAX_YAML_DEPTH * 1000:
                raise RunFileError(Path(where), "refused, too many values")
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in sizes)
            continue
        sizes[id(node)] = 1 + sum(sizes.get(id(c), 0) for c in children)
        depths[id(node)] = 1 + max((depths.get(id(c), 0) for c in children), default=0)
        if sizes[id(node)] > MAX_YAML_NODES:
            raise RunFileError(Path(where), f"refused, expands to more than {MAX_YAML_NODES} values "
                                              "(aliases counted at each use; a possible alias bomb)")
        if depths[id(node)] > MAX_YAML_DEPTH + 1:
            raise RunFileError(Path(where), f"refused, nested more than {MAX_YAML_DEPTH} levels deep")


def read_yaml(run_dir: Path, name: str | Path, max_bytes: int | None = None) -> Any:
    """A YAML file of the run folder, bounded in bytes and in values (`parse_yaml`)."""
    return parse_yaml(read_text(run_dir, name, max_bytes), str(Path(run_dir) / name))
