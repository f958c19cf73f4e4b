"""Atomic file writes: every file sbagents writes into a run dir (models, checkpoints, statistics, summaries,
configs, exports) goes to a temporary name in the same folder and is renamed into place once complete.

A process killed mid-write (``kill -9``, a power cut after the data reached the disk) or a full disk therefore
never leaves a file under its final name that looks complete but is not: the reader sees the previous version or
no file. A failed write removes its temporary file; a full or read-only disk becomes a one-line
:class:`~sbagents.errors.UsageError` that names the file (``cannot write logs/.../best_model.zip: No space left on
device; nothing was replaced``).

Appended logs (monitor CSVs, transparency logs, ``progress.csv``) are streams, not files written here: a cut leaves
a shorter log whose last line may be partial, and their readers skip such a line.

Importing this module needs only the standard library.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError

#: errno values that mean "this disk or folder cannot take the file" (reported as one line, not a traceback).
_DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}


def temporary_name(path: Path) -> Path:
    """The temporary name ``path`` is written under: hidden, in the same folder (so the rename is atomic), unique
    per process, with a suffix that never looks like the final file's (``.best_model.zip.4711.partial``)."""
    return path.with_name(f".{path.name}.{os.getpid()}.partial")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; on a normal exit it is flushed to disk and renamed
    to ``path`` (replacing an older version atomically); on an exception it is removed and ``path`` is untouched.

    :raises UsageError: the disk is full, over quota or read-only, or the folder is not writable (naming ``path``).
    """
    final = Path(path)
    tmp = temporary_name(final)
    try:
        yield tmp
        _fsync(tmp)
        os.replace(tmp, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise_disk_error(exc, final)
        raise


def raise_disk_error(exc: BaseException, path: str | Path) -> None:
    """Turn ``exc`` into a one-line :class:`UsageError` naming ``path`` when it says the disk or folder cannot take
    the file (full, over quota, read-only, not writable); otherwise return (the caller re-raises ``exc``)."""
    if isinstance(exc, OSError) and exc.errno in _DISK_ERRORS:
        raise UsageError(f"cannot write {path}: {exc.strerror}; nothing was replaced") from None


def _fsync(path: Path) -> None:
    """Flush ``path``'s data to the disk (so a rename never publishes a file whose data is still in flight)."""
    if not path.is_file():
        raise FileNotFoundError(errno.ENOENT, "the writer produced no file", str(path))
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON (with a final newline) to ``path`` atomically; returns ``path``."""
    return write_text(path, json.dumps(data, indent=2) + "\n")


def write_csv(path: str | Path, fieldnames: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> Path:
    """Write ``rows`` (mappings; keys outside ``fieldnames`` are ignored) as a CSV with a header, atomically."""
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=list(fieldnames), extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return write_text(path, text.getvalue())


def write_with(path: str | Path, writer: Callable[[Path], Any]) -> Path:
    """Let ``writer(tmp)`` write the file (an SB3 ``model.save``, ``np.savez``, ``fig.savefig``, an ONNX export),
    then rename it to ``path``; returns ``path``. The writer must write exactly the path it is given."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_npz(path: str | Path, **arrays: Any) -> Path:
    """``np.savez`` of ``arrays`` to ``path`` atomically (through a file object: numpy would append ``.npz`` to
    the temporary name); returns ``path``."""
    import numpy as np

    def writer(tmp: Path) -> None:
        with tmp.open("wb") as fh:
            np.savez(fh, **arrays)

    return write_with(path, writer)


def save_figure(figure: Any, path: str | Path, **kwargs: Any) -> Path:
    """``figure.savefig`` to ``path`` atomically, in the format of ``path``'s suffix (matplotlib would read the
    temporary name's); returns ``path``."""
    fmt = Path(path).suffix.lstrip(".") or "png"
    return write_with(path, lambda tmp: figure.savefig(tmp, format=fmt, **kwargs))


def save_model(model: Any, path: str | Path) -> Path:
    """``model.save`` (an SB3 algorithm) to ``path`` atomically; returns ``path``.

    SB3 appends ``.zip`` only to a name without a suffix, and the temporary name has one, so it writes the path
    it is given.
    """
    return write_with(path, lambda tmp: model.save(str(tmp)))
