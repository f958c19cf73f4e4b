"""Bytes of a transparency log for :class:`sbagents.dashboard.logindex.LogIndex`: range reads, gzip, index cache.

- **Plain CSV**: offsets are file offsets and :class:`_RangeReader` seeks to them. The index is cached on disk
  under ``sbagents.cache.cache_dir("logindex")`` (never next to the log: served log folders are read-only), named
  by a hash of the resolved path, with the file's size, mtime, inode and hashes of its first bytes and of the
  bytes before the indexed end (:func:`_load_index_cache`, :func:`_save_index_cache`). A second process reuses
  it when the file is the same or only grew (then only the tail is scanned).
- **CSV.gz**: the callback writes gzip in append mode with sync flushes, so a file is one or more gzip members
  and, while training runs, the last member is unfinished. The file is decompressed with
  ``zlib.decompressobj(wbits=31)`` fed chunk by chunk (:class:`GzCursor`); a finished member's ``unused_data``
  starts the next member; an unfinished or truncated tail yields what decompressed so far (rows end at newlines,
  so a row cut off by the truncation is not returned) and bytes that are not gzip stop the scan without an
  error. Offsets are offsets in the uncompressed stream; random access uses *checkpoints*
  (:class:`_GzScanner`): every ~16 MiB of output the decompressor is copied (``decompressobj.copy()``) with its
  compressed and uncompressed offsets, and every member start is one. A page decompresses from the checkpoint
  before it. Checkpoints live in memory only: a zlib decompressor's state (its 32 KiB window and bit position)
  cannot be pickled or restored from the standard library, so a new process re-scans a ``.gz`` log (about as
  fast as ``gzip -dc``; the row offsets would be useless without the decompressor states).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from sbagents.cache import cache_dir
from sbagents.dashboard.folders import open_regular

#: Compressed bytes read per step of a ``.gz`` scan; each decompress call outputs at most :data:`GZ_MAX_OUT`.
GZ_READ_BYTES = 1 << 20
GZ_MAX_OUT = 4 << 20
#: Uncompressed bytes between two decompressor checkpoints of a ``.gz`` log.
CHECKPOINT_BYTES = 16 << 20
#: Format version of the on-disk index cache.
CACHE_VERSION = 1
#: Bytes hashed at the start of the file and before the indexed end to recognise a cached file.
HASH_BYTES = 4096


@dataclass
class GzCheckpoint:
    """A point from which a ``.gz`` log can be decompressed: compressed offset, decompressor state, output offset.

    ``state`` is None at the start of a gzip member (a fresh decompressor is made there).
    """

    comp: int
    state: Any
    upos: int


class GzCursor:
    """Decompresses a (multi-member, possibly unfinished) gzip file from a checkpoint onwards, step by step."""

    def __init__(self, ck: GzCheckpoint) -> None:
        self.comp = ck.comp  # compressed offset of inp[0] (everything before it has been fed)
        self.inp = b""
        self.d: Any = ck.state.copy() if ck.state is not None else None
        self.upos = ck.upos  # uncompressed offset of the next output byte
        self.broken = False

    def checkpoint(self) -> GzCheckpoint:
        return GzCheckpoint(self.comp, self.d.copy() if self.d is not None else None, self.upos)

    def at_member_start(self) -> bool:
        return self.d is None

    def step(self, fh: IO[bytes], read_size: int = GZ_READ_BYTES) -> bytes | None:
        """Decompress some more; None when nothing more can be decompressed from the file as it is now."""
        while not self.broken:
            if not self.inp:
                fh.seek(self.comp)
                self.inp = fh.read(read_size)
                if not self.inp:
                    return None
            if self.d is None:
                self.d = zlib.decompressobj(wbits=31)
            try:
                out = self.d.decompress(self.inp, GZ_MAX_OUT)
            except zlib.error:  # not gzip data (garbage after a member, a member cut off by another one)
                self.broken = True
                return None
            rest = self.d.unused_data if self.d.eof else self.d.unconsumed_tail
            consumed = len(self.inp) - len(rest)
            self.comp += consumed
            self.inp = rest
            self.upos += len(out)
            if self.d.eof:
                self.d = None  # the next member (if any) starts at self.comp
            if out or consumed:
                return out
            more = fh.read(read_size)  # no progress: zlib needs more input than we gave it
            if not more:
                return None
            self.inp += more
        return None


class _GzScanner:
    """Decompresses a ``.gz`` log from its start for indexing and records the checkpoints on the way (every
    member start and every :data:`CHECKPOINT_BYTES` of output)."""

    def __init__(self) -> None:
        self.cursor = GzCursor(GzCheckpoint(0, None, 0))
        self.checkpoints: list[GzCheckpoint] = [GzCheckpoint(0, None, 0)]

    def known_size(self) -> int:
        """Compressed bytes of the file examined so far."""
        return self.cursor.comp + len(self.cursor.inp)

    def scan(self, path: Path, step_bytes: int, max_bytes: int,
             consume: Callable[[int, bytes], None]) -> tuple[int, bool]:
        """Decompress about ``step_bytes`` more (less than ``max_bytes`` before the last step), passing each output
        and its uncompressed offset to ``consume``; returns the bytes produced and whether the file (as it is now)
        has nothing more to decompress."""
        cur = self.cursor
        with open_regular(path) as fh:
            produced = 0
            while produced < max_bytes:
                base = cur.upos
                out = cur.step(fh, min(step_bytes, GZ_READ_BYTES))
                if out is None:
                    return produced, True
                consume(base, out)
                produced += len(out)
                last = self.checkpoints[-1]
                if cur.at_member_start():  # a member ended: the next one starts here
                    if cur.comp != last.comp:
                        self.checkpoints.append(cur.checkpoint())
                elif cur.upos - last.upos >= CHECKPOINT_BYTES:
                    self.checkpoints.append(cur.checkpoint())
                if produced >= step_bytes:
                    break
        return produced, False


class _RangeReader:
    """Reads uncompressed byte ranges of a log; sequential reads of a ``.gz`` log continue one decompressor."""

    def __init__(self, path: Path, checkpoints: list[GzCheckpoint] | None) -> None:
        self.fh: IO[bytes] = open_regular(path)  # closed by close()
        self.checkpoints = checkpoints  # None: plain file
        self.cursor: GzCursor | None = None
        self.buf = b""
        self.buf_start = 0

    def close(self) -> None:
        self.fh.close()

    def read(self, start: int, end: int) -> bytes:
        """Bytes ``[start, end)`` of the (uncompressed) log; shorter if the file ends before ``end``."""
        if end <= start:
            return b""
        if self.checkpoints is None:
            self.fh.seek(start)
            return self.fh.read(end - start)
        buf_end = self.buf_start + len(self.buf)
        ck = self._checkpoint_before(start)
        if self.cursor is None or start < self.buf_start or ck.upos > buf_end:
            self.cursor = GzCursor(ck)
            self.buf, self.buf_start = b"", ck.upos
        parts = []
        while True:
            buf_end = self.buf_start + len(self.buf)
            if buf_end > start:
                lo, hi = start - self.buf_start, min(end - self.buf_start, len(self.buf))
                parts.append(self.buf[lo:hi])
                start = self.buf_start + hi
                if start >= end:
                    break
            out = self.cursor.step(self.fh)
            if out is None:
                break
            self.buf, self.buf_start = out, buf_end
        return b"".join(parts)

    def _checkpoint_before(self, upos: int) -> GzCheckpoint:
        assert self.checkpoints is not None
        cks = self.checkpoints
        lo, hi = 0, len(cks) - 1
        while lo < hi:  # last checkpoint with upos <= the offset
            mid = (lo + hi + 1) // 2
            if cks[mid].upos <= upos:
                lo = mid
            else:
                hi = mid - 1
        return cks[lo]


# ---------------------------------------------------------------------- on-disk index cache (plain CSV)
@dataclass
class _CachedIndex:
    """An index read from the cache: the header line, row offsets, rows and bytes indexed, the file size now."""

    header: bytes
    header_end: int
    offsets: list[int]
    rows: int
    scan_pos: int
    size: int


def _cache_file(path: Path, block_rows: int) -> Path:
    """Where the index of ``path`` (resolved) with ``block_rows`` rows per block is cached."""
    return cache_dir("logindex") / f"{hashlib.sha256(str(path).encode()).hexdigest()[:32]}-{block_rows}.npz"


def _file_hashes(fh: IO[bytes], end: int) -> tuple[str, str]:
    """Hashes of the first :data:`HASH_BYTES` and of the :data:`HASH_BYTES` before ``end``."""
    fh.seek(0)
    head = hashlib.sha1(fh.read(min(HASH_BYTES, end))).hexdigest()
    fh.seek(max(end - HASH_BYTES, 0))
    tail = hashlib.sha1(fh.read(min(HASH_BYTES, end))).hexdigest()
    return head, tail


def _load_index_cache(cache_file: Path, path: Path, block_rows: int) -> _CachedIndex | None:
    """The cached index of ``path`` if ``cache_file`` holds one for this file as it is now (or a prefix of it)."""
    try:
        with np.load(cache_file, allow_pickle=False) as npz:
            meta = json.loads(str(npz["meta"]))
            offsets = npz["offsets"]
        st = os.lstat(path)
        if (
            meta.get("version") != CACHE_VERSION
            or meta["block_rows"] != block_rows
            or meta["inode"] != st.st_ino
            or meta["scan_pos"] > st.st_size
            or meta["path"] != str(path)
        ):
            return None
        with open_regular(path) as fh:
            if list(_file_hashes(fh, meta["scan_pos"])) != [meta["head_sha"], meta["tail_sha"]]:
                return None
            fh.seek(0)
            header = fh.read(meta["header_end"])
    except (OSError, ValueError, KeyError, TypeError, json.JSONDecodeError):
        return None
    return _CachedIndex(header, meta["header_end"], [int(x) for x in offsets.tolist()], meta["rows"],
                        meta["scan_pos"], st.st_size)


def _save_index_cache(cache_file: Path, path: Path, block_rows: int, offsets: list[int], rows: int, scan_pos: int,
                      header_end: int) -> bool:
    """Write the index of ``path`` (rows and offsets up to byte ``scan_pos``) to ``cache_file``; False on error."""
    try:
        st = os.lstat(path)
        with open_regular(path) as fh:
            head, tail = _file_hashes(fh, scan_pos)
        meta = {"version": CACHE_VERSION, "path": str(path), "size": st.st_size,
                "mtime_ns": st.st_mtime_ns, "inode": st.st_ino, "block_rows": block_rows,
                "rows": rows, "scan_pos": scan_pos, "header_end": header_end,
                "head_sha": head, "tail_sha": tail}
        tmp = cache_file.with_name(f"{cache_file.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        with open(tmp, "wb") as fh:
            np.savez(fh, offsets=np.asarray(offsets, dtype=np.int64), meta=np.array(json.dumps(meta)))
        os.replace(tmp, cache_file)
    except OSError:
        return False
    return True


class BoundedLines:
    """Cuts a stream of bytes into complete lines with bounded memory: a line longer than ``limit`` bytes is dropped
    up to its newline instead of being held.

    :param limit: the longest line kept (bytes, newline excluded).
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.carry = b""  # the unfinished last line
        self.skipping = False  # inside a line over the limit

    def feed(self, data: bytes) -> tuple[bytes, bool]:
        """The complete lines ``data`` finishes (up to and including the last newline), and whether a line over the
        limit started being dropped in it."""
        if self.skipping:
            nl = data.find(b"\n")
            if nl < 0:
                return b"", False
            data, self.skipping = data[nl + 1 :], False
        data = self.carry + data
        cut = data.rfind(b"\n") + 1
        block, self.carry = data[:cut], data[cut:]
        dropped = len(self.carry) > self.limit
        if dropped:
            self.carry, self.skipping = b"", True
        return block, dropped
