"""Incremental reader of a run's log.mcap: each refresh reads only the bytes added since.

It returns the package's typed messages (`metric_messages`, `scene_message`,
`episode_frames`); the raw JSON objects stay available (`metrics`, `scene`) for tools that
show whatever a log holds.

Why not `detach.runfolder.mcap_reader.iter_messages`: it decompresses and parses the whole file on
every call (a 100 MB log takes seconds), and MCAP's own indexes sit in the summary section,
which exists only after the writer closed the file. This reader walks the top-level records
from the offset it reached last time. After every chunk the writer puts MessageIndex
records (channel id -> offsets of its messages inside the chunk), so a chunk that holds
only /episode/bodies and /tf messages is skipped without decompressing it; its offset is
remembered, so loading one episode later decompresses only that episode's chunks.

Record layout (MCAP spec): opcode u8, length u64, content. Integers are little-endian;
strings are u32 length + UTF-8. A record that extends past the end of the file is a
still-growing (or truncated) tail: reading stops before it and resumes there next time.
"""

from __future__ import annotations

import json
import os
import struct
import threading
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lz4.frame
import numpy as np
import zstandard

from detach.runfolder import files as run_files
from detach.runfolder.messages import ContractError, EpisodeFrame, MetricsMessage, SceneMessage
from detach.runfolder.names import EPISODE_TOPIC, METRICS_TOPIC, SCENE_TOPIC

MAGIC = b"\x89MCAP0\r\n"
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
LAST_OPCODE = 0x0F
"""Highest opcode of MCAP v0 (DataEnd); anything above (or 0) means the bytes are corrupt."""
_REC = struct.Struct("<BQ")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_DATA_AT = _REC.size + _MSG_HEAD.size
"""Offset of a message's payload from the start of its record."""
EpisodeKey = tuple[int, int]
"""(episode, trial) of a recorded episode: an evaluation records its trials under one episode
number (the checkpoint's iteration)."""
NO_EPISODE: EpisodeKey = (-1, 0)
BODIES, METRICS, SCENE = EPISODE_TOPIC, METRICS_TOPIC, SCENE_TOPIC


@dataclass
class ChunkRef:
    """Where the /episode/bodies messages of one chunk are; decoded lazily."""

    data_offset: int
    """File offset of the (compressed) chunk records."""
    data_length: int
    compression: str
    uncompressed_size: int
    bodies: list[int]
    """Offsets of the /episode/bodies message records inside the uncompressed records."""
    episodes: list[EpisodeKey] | None = None
    """(episode, trial) of each message in `bodies`, once the chunk was decoded."""
    frames: list[int] | None = None
    """Frame number of each message in `bodies` (-1 if unknown), with `episodes`."""
    crc: int = 0
    """CRC-32 of the uncompressed records (0: the writer wrote none)."""


_local = threading.local()


def _decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == "zstd":
        # One decompressor per thread: creating one costs more than a small chunk's work,
        # and an instance must not be shared between threads.
        zstd = getattr(_local, "zstd", None)
        if zstd is None:
            zstd = _local.zstd = zstandard.ZstdDecompressor()
        return zstd.decompress(data, max_output_size=size)
    if compression == "lz4":
        return lz4.frame.decompress(data)
    if compression == "":
        return data
    raise ValueError(f"unsupported chunk compression {compression!r}")


def _string(buf: bytes | memoryview, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, at)
    return bytes(buf[at + 4: at + 4 + n]).decode("utf-8"), at + 4 + n


class LogTail:
    """Metrics, scene and an episode index of one log.mcap, kept up to date cheaply.

    Thread-safe: the dashboard's poller and its scene loader share one instance.
    """

    def __init__(self, path: Path, chunk_cache: int = 16) -> None:
        self.path = Path(path)
        self._lock = threading.RLock()
        self._cache: OrderedDict[int, bytes] = OrderedDict()
        self._cache_size = chunk_cache
        self._reset()

    def _reset(self) -> None:
        self.offset = 0
        """File offset up to which every record has been read."""
        self.size = 0
        self.inode: int | None = None
        self.channels: dict[int, str] = {}
        self.metrics: list[dict[str, Any]] = []
        self.metric_times: list[float] = []
        """Log time of each /metrics message (Unix seconds; the wall-time axis of the curves)."""
        self.metric_messages: list[tuple[MetricsMessage, float]] = []
        """The /metrics messages that follow the format, with their log times (Unix seconds)."""
        self.scene: dict[str, Any] | None = None
        self.scene_message: SceneMessage | None = None
        """The latest /scene, typed; None without one or when it does not follow the format."""
        self.chunks: list[ChunkRef] = []
        self.complete = False
        """The footer and the closing magic were read: the writer closed the file."""
        self._expect_magic = True
        self.stopped: str | None = None
        """Why reading stopped for good (corrupt bytes); None while everything parses."""
        self.bad_chunk: str | None = None
        """A chunk whose frames could not be decompressed (reading goes on past it)."""
        self.version = 0
        """Bumped whenever new messages were read (cheap change detection for callers)."""
        self._cache.clear()

    @property
    def problem(self) -> str | None:
        """What is wrong with the file: why reading stopped, else a chunk left out, else None."""
        return self.stopped or self.bad_chunk

    @problem.setter
    def problem(self, text: str | None) -> None:
        self.stopped = text

    # --- scanning -----------------------------------------------------------------------
    def refresh(self) -> bool:
        """Read what was appended since the last call; True if anything new was read."""
        with self._lock:
            try:
                st = os.stat(self.path)
            except OSError:
                if self.inode is not None:
                    self._reset()
                    return True
                return False
            if st.st_ino != self.inode or st.st_size < self.size:
                self._reset()  # replaced or rewritten: start over
                self.inode = st.st_ino
            self.size = st.st_size
            if self.stopped is not None or self.offset >= self.size:
                return False
            before = (len(self.metrics), len(self.chunks), self.scene is not None,
                      self.complete)
            try:  # a regular file inside its run folder only: never a FIFO or a link out
                fd = run_files.open_run_file(self.path.parent, self.path.name)
            except run_files.RunFileError as exc:
                self.problem = f"{self.path.name} {exc.why}"
                return False
            except OSError:
                return False
            with os.fdopen(fd, "rb") as f:
                try:
                    self._scan(f, st.st_size)
                except (struct.error, IndexError, ValueError) as exc:  # a record cut or zeroed
                    self.problem = self.stopped or (
                        f"{self.path.name}: corrupt record near byte {self.offset} ({exc}); "
                        f"showing what was read before it")
            changed = before != (len(self.metrics), len(self.chunks),
                                 self.scene is not None, self.complete)
            if changed:
                self.version += 1
            return changed

    @property
    def pending_bytes(self) -> int:
        """Bytes after the last complete record (a growing or truncated tail)."""
        return max(0, self.size - self.offset)

    def _scan(self, f, size: int) -> None:
        pending: tuple[int, int, str, int] | None = None  # chunk awaiting its indexes
        indexes: dict[int, list[int]] = {}
        pos = self.offset
        while True:
            if self._expect_magic:  # start of the file, or of a stream appended on resume
                if pos + len(MAGIC) > size:
                    break
                f.seek(pos)
                if f.read(len(MAGIC)) != MAGIC:
                    self.problem = (f"{self.path.name}: {size - pos} unexpected bytes after the "
                                    f"footer" if pos else
                                    f"{self.path.name}: not an MCAP file (bad magic bytes)")
                    break
                pos = self.offset = pos + len(MAGIC)
                self._expect_magic = self.complete = False
                continue
            if pos + _REC.size > size:
                break
            f.seek(pos)
            opcode, length = _REC.unpack(f.read(_REC.size))
            if opcode == 0 or opcode > LAST_OPCODE:
                self.problem = (f"{self.path.name}: corrupt record at byte {pos} (opcode {opcode}); "
                                f"showing what was read before it")
                break
            end = pos + _REC.size + length
            if end > size:
                break  # the tail is still being written (or was cut off)
            if opcode == MESSAGE_INDEX:
                if pending is not None:
                    content = f.read(length)
                    (channel,) = struct.unpack_from("<H", content)
                    entries = np.frombuffer(content, dtype="<u8", offset=6)
                    indexes[channel] = entries[1::2].astype(np.int64).tolist()
                pos = self.offset = end
                continue
            if pending is not None:
                self._finish_chunk(f, pending, indexes)
                pending, indexes = None, {}
                f.seek(pos + _REC.size)
            if opcode == CHUNK:
                pending = self._chunk_header(f, pos, length)
            elif opcode == CHANNEL:
                self._channel(f.read(length))
            elif opcode == MESSAGE:
                self._top_level_message(f.read(length), pos, length)
            elif opcode == FOOTER:
                f.seek(end)
                closing = f.read(len(MAGIC))
                if len(closing) < len(MAGIC):
                    break  # the closing magic is not there yet
                if closing != MAGIC:
                    self.problem = f"{self.path.name}: bad closing magic at byte {end}"
                    break
                end += len(MAGIC)
                self.complete = self._expect_magic = True
            pos = self.offset = end
        if pending is not None:
            # Its indexes may still be on their way (or never come): decode the chunk itself.
            self._finish_chunk(f, pending, {}, trust_index=False)

    def _chunk_header(self, f, pos: int, length: int) -> tuple[int, int, str, int, int]:
        head = f.read(min(length, 64))
        usize, crc = struct.unpack_from("<QI", head, 16)
        compression, at = _string(head, 28)
        (data_len,) = struct.unpack_from("<Q", head, at)
        return pos + _REC.size + at + 8, data_len, compression, usize, crc

    def _finish_chunk(self, f, chunk: tuple[int, int, str, int, int], indexes: dict[int, list[int]],
                      trust_index: bool = True) -> None:
        """Use the chunk's MessageIndex records if they name only known channels, else decode it."""
        data_offset, data_len, compression, usize, crc = chunk
        topics = {self.channels.get(c) for c in indexes}
        if trust_index and indexes and None not in topics:
            by_topic: dict[str, list[int]] = {}
            for c, offs in indexes.items():
                by_topic.setdefault(self.channels[c], []).extend(offs)
            bodies = sorted(by_topic.get(BODIES, []))
            if bodies:
                self.chunks.append(ChunkRef(data_offset, data_len, compression, usize, bodies, crc=crc))
            wanted = sorted(by_topic.get(METRICS, []) + by_topic.get(SCENE, []))
            if not wanted:
                return
            records = self._read_chunk(f, data_offset, data_len, compression, usize)
            if records is None:
                return
            for off in wanted:
                self._message(records, off)
            return
        records = self._read_chunk(f, data_offset, data_len, compression, usize)
        if records is None:
            return
        bodies = self._scan_records(records)
        if bodies:
            self.chunks.append(ChunkRef(data_offset, data_len, compression, usize, bodies, crc=crc))

    def _read_chunk(self, f, data_offset: int, data_len: int, compression: str,
                    usize: int) -> bytes | None:
        f.seek(data_offset)
        try:
            return _decompress(f.read(data_len), compression, usize)
        except Exception as exc:  # noqa: BLE001 - one bad chunk must not hide the rest
            self.problem = self.stopped or (
                f"{self.path.name}: chunk at byte {data_offset} does not decompress ({exc}); "
                f"skipped")
            return None

    def _scan_records(self, records: bytes) -> list[int]:
        """Channels, metrics and scene from decoded chunk records; offsets of body frames."""
        bodies, at, n = [], 0, len(records)
        while at + _REC.size <= n:
            opcode, length = _REC.unpack_from(records, at)
            if at + _REC.size + length > n:
                break
            if opcode == CHANNEL:
                self._channel(records[at + _REC.size: at + _REC.size + length])
            elif opcode == MESSAGE:
                (channel,) = struct.unpack_from("<H", records, at + _REC.size)
                if self.channels.get(channel) == BODIES:
                    bodies.append(at)
                else:
                    self._message(records, at)
            at += _REC.size + length
        return bodies

    def _channel(self, content: bytes) -> None:
        channel_id, _schema = struct.unpack_from("<HH", content)
        topic, _ = _string(content, 4)
        self.channels[channel_id] = topic

    def _message(self, records: bytes, at: int) -> None:
        """Parse one /metrics or /scene message record at `at` (others are ignored)."""
        if not 0 <= at <= len(records) - _DATA_AT:
            self.problem = self.stopped or (
                f"{self.path.name}: a message index points past its chunk; message skipped")
            return
        _op, length = _REC.unpack_from(records, at)
        channel, _sequence, log_time, _publish = _MSG_HEAD.unpack_from(records, at + _REC.size)
        topic = self.channels.get(channel)
        if topic not in (METRICS, SCENE):
            return
        try:
            msg = json.loads(records[at + _DATA_AT: at + _REC.size + length])
        except ValueError:
            return
        if not isinstance(msg, dict):
            return
        if topic == METRICS:
            self.metrics.append(msg)
            self.metric_times.append(log_time / 1e9)
            try:
                self.metric_messages.append((MetricsMessage.from_json(msg), log_time / 1e9))
            except ContractError:
                pass  # shown raw (`metrics`), left out of the typed series
        else:  # the latest: an evaluation appended to the log records its scene again
            self.scene = msg
            try:
                self.scene_message = SceneMessage.from_json(msg)
            except (ContractError, KeyError, TypeError, ValueError):
                self.scene_message = None

    def _top_level_message(self, content: bytes, pos: int, length: int) -> None:
        """Messages outside chunks (an unchunked writer): treat each as a one-record chunk."""
        record = _REC.pack(MESSAGE, length) + content
        (channel,) = struct.unpack_from("<H", content)
        if self.channels.get(channel) == BODIES:
            self.chunks.append(ChunkRef(pos, len(record), "", len(record), [0]))
        else:
            self._message(record, 0)

    # --- episodes -----------------------------------------------------------------------
    def _records(self, chunk: ChunkRef) -> bytes:
        cached = self._cache.get(chunk.data_offset)
        if cached is not None:
            self._cache.move_to_end(chunk.data_offset)
            return cached
        with open(self.path, "rb") as f:
            f.seek(chunk.data_offset)
            raw = f.read(chunk.data_length)
        data = _decompress(raw, chunk.compression, chunk.uncompressed_size)
        if chunk.crc and zlib.crc32(data) != chunk.crc:  # zeroed or altered bytes may still decompress
            raise ValueError("CRC mismatch")
        self._cache[chunk.data_offset] = data
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return data

    def _episodes_of(self, chunk: ChunkRef) -> list[EpisodeKey]:
        if chunk.episodes is None:
            try:
                records = self._records(chunk)
            except Exception as exc:  # noqa: BLE001 - an undecodable chunk holds no episode: say so
                self.bad_chunk = self.bad_chunk or (f"{self.path.name}: chunk at byte {chunk.data_offset} cannot "
                                                    f"be decompressed ({type(exc).__name__}); its frames are left out")
                chunk.episodes, chunk.frames = [NO_EPISODE] * len(chunk.bodies), [-1] * len(chunk.bodies)
                return chunk.episodes
            eps, frames = [], []
            for at in chunk.bodies:
                msg = self._payload(records, at)
                eps.append(_key(msg) if msg else NO_EPISODE)
                frame = msg.get("frame", -1) if msg else -1
                frames.append(frame if isinstance(frame, int) else -1)
            chunk.episodes, chunk.frames = eps, frames
        return chunk.episodes

    def _starts_in(self, chunk: ChunkRef, key: EpisodeKey) -> bool:
        """Whether `chunk` holds frame 0 of the recorded episode `key`."""
        return any(k == key and f == 0 for k, f in zip(self._episodes_of(chunk), chunk.frames or []))

    @staticmethod
    def _payload(records: bytes, at: int) -> dict[str, Any] | None:
        if not 0 <= at <= len(records) - _DATA_AT:
            return None  # an index pointing past its chunk
        _op, length = _REC.unpack_from(records, at)
        try:
            msg = json.loads(records[at + _DATA_AT: at + _REC.size + length])
        except ValueError:
            return None
        return msg if isinstance(msg, dict) else None

    def episode_keys(self) -> list[EpisodeKey]:
        """Every recorded (episode, trial) in the file (decodes each frame chunk once, then
        cached)."""
        with self._lock:
            found: set[EpisodeKey] = set()
            for chunk in self.chunks:
                found.update(self._episodes_of(chunk))
            found.discard(NO_EPISODE)
            return sorted(found)

    def episode_numbers(self) -> list[int]:
        """The episode numbers in the file (each may hold several trials)."""
        return sorted({e for e, _t in self.episode_keys()})

    def newest_episode(self) -> EpisodeKey | None:
        """The recorded episode of the last frame in the file; decodes only the last frame
        chunk."""
        with self._lock:
            for chunk in reversed(self.chunks):
                eps = [e for e in self._episodes_of(chunk) if e != NO_EPISODE]
                if eps:
                    return eps[-1]
            return None

    def episode_frames(self, key: EpisodeKey | int | None = None
                       ) -> tuple[EpisodeKey, list[EpisodeFrame]] | None:
        """(key, frames in file order) of the recorded episode `key` ((episode, trial), or an
        episode number for its trial 0; default: the newest); None when it has no frame. Frames
        that do not follow the format are left out.

        The newest episode is found by walking back from the end of the file, so a long log
        costs only the chunks of that episode; any other episode needs the full index
        (built once per chunk and cached).
        """
        with self._lock:
            if key is None:
                key = self.newest_episode()
                if key is None:
                    return None
                # Walk back to the chunk with its frame 0. Trials recorded side by side share
                # chunks, and a chunk may hold no frame of this one (cut between envs), so a
                # chunk without it ends the walk only once no frame of its number is in it.
                chunks, seen = [], False
                for chunk in reversed(self.chunks):
                    keys = self._episodes_of(chunk)
                    if key in keys:
                        chunks.append(chunk)
                        seen = True
                        if self._starts_in(chunk, key):
                            break
                    elif seen and all(k[0] != key[0] for k in keys):
                        break
                chunks.reverse()
            else:
                key = (key, 0) if isinstance(key, int) else tuple(key)
                chunks = [c for c in self.chunks if key in self._episodes_of(c)]
            frames = []
            for chunk in chunks:
                records = self._records(chunk)
                for at, ep in zip(chunk.bodies, chunk.episodes or []):
                    if ep == key:
                        msg = self._payload(records, at)
                        try:
                            frames.append(EpisodeFrame.from_json(msg))
                        except (ContractError, TypeError, ValueError):
                            continue
            return (key, frames) if frames else None


def _key(msg: dict[str, Any]) -> EpisodeKey:
    try:
        return int(msg.get("episode", -1)), int(msg.get("trial", 0) or 0)
    except (TypeError, ValueError):
        return NO_EPISODE


def closed_cleanly(path: Path) -> bool | None:
    """Whether a log.mcap starts and ends with the MCAP magic (the writer closed it), from
    16 bytes; None if it does not even start like an MCAP file. The run index uses this to
    check finished runs without reading their logs (a full scan says why a log is broken)."""
    try:
        with os.fdopen(run_files.open_run_file(path.parent, path.name), "rb") as f:
            head = f.read(len(MAGIC))
            if head != MAGIC:
                return None
            if f.seek(0, os.SEEK_END) < 2 * len(MAGIC) + _REC.size:
                return False  # the writer has only just started
            f.seek(-len(MAGIC), os.SEEK_END)
            return f.read(len(MAGIC)) == MAGIC
    except (OSError, ValueError):  # missing, or refused (a FIFO, a link out of the run)
        return None
