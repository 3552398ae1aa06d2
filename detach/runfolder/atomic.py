"""Writing a run folder's files whole or not at all.

JSON, YAML and checkpoint files are written through `atomic_writer` (a fsynced temporary
file, then a rename), so a reader never sees half a file, and files get the user's umask;
stdout.log and log.mcap grow by appending instead and read up to a crash.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
from pathlib import Path
from typing import IO, Any, Iterator

from detach.runfolder.names import TEMP_SUFFIX


@contextlib.contextmanager
def atomic_writer(path: Path, binary: bool = True) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces `path` when the block ends without an error.

    Readers see the old file or the complete new one, never a part: the data is fsynced
    before the rename and the folder after it, so a power cut cannot leave an empty file
    under the final name either. The file gets the user's umask (0666 & ~umask, unlike
    tempfile's 0600), so a dashboard run by another user can read it. On any failure (a
    full disk, a signal) the temporary file is removed and the error re-raised.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}")
    f = open(tmp, "xb") if binary else open(tmp, "x", encoding="utf-8")  # 0666 & ~umask
    try:
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    fsync_folder(path.parent)


def fsync_folder(folder: Path) -> None:
    """Make a rename or unlink in `folder` durable (best effort: not every filesystem can)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)




def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path, binary=False) as f:
        f.write(text)


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")
