"""Atomic file writes: every file sbagents writes into a run dir (models, checkpoints, statistics, summaries,
configs, exports) goes to a temporary name in the same folder and is renamed into place once complete.

A process killed mid-write (``kill -9``, a power cut after the data reached the disk) or a full disk therefore
never leaves a file under its final name that looks complete but is not: the reader sees the previous version or
no file. A failed write removes its temporary file; a full or read-only disk becomes a one-line
:class:`~sbagents.errors.UsageError` that names the file (``cannot write logs/.../best_model.zip: No space left on
device; nothing was replaced``).

The temporary file is made by :func:`tempfile.mkstemp` (an unpredictable name, created with ``O_EXCL``, so it
never follows a symlink) and the rename replaces whatever is at the final name, a symlink included, without
following it: a run dir shipped with symlinks at temporary or final names cannot make a write land outside it.
Nothing here opens a final name for writing.

Appended logs (monitor CSVs, transparency logs, ``progress.csv``) are streams, not files written here: a cut leaves
a shorter log whose last line may be partial, and their readers skip such a line.

Importing this module needs only the standard library.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import errno
import io
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

from sbagents.errors import UsageError

#: errno values that mean "this disk or folder cannot take the file" (reported as one line, not a traceback).
_DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}


def _umask() -> int:
    """The process umask, read without changing it where ``/proc`` tells it (changing it, even briefly, would
    affect files other threads create)."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status", encoding="ascii",
                                                        errors="replace") as fh:
        for line in fh:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: Files and folders made here get the mode a plain ``open``/``mkdir`` would give them (``mkstemp`` and ``mkdtemp``
#: alone would make them private to the owner).
_MODE = 0o666 & ~_umask()
_DIR_MODE = 0o777 & ~_umask()


def _create_temporary(path: Path, suffix: str) -> tuple[int, Path]:
    """Create the temporary file for ``path`` with :func:`tempfile.mkstemp` and return its open descriptor and name."""
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    except OSError as exc:
        raise_disk_error(exc, path)
        raise
    if hasattr(os, "fchmod"):
        try:
            os.fchmod(fd, _MODE)
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(name)
            raise
    return fd, Path(name)


def temporary_name(path: Path, suffix: str = ".partial") -> Path:
    """Create and return a new, empty temporary file to write ``path``'s content to: hidden, in the same folder
    (so the rename is atomic), with a suffix that never looks like the final file's
    (``.best_model.zip.k3j_x9q2.partial``).

    The name is unpredictable and the file is created with :func:`tempfile.mkstemp` (``O_CREAT | O_EXCL``, which
    never follows a symlink), so a symlink planted in the folder (a run dir from elsewhere) can never redirect the
    write. A writer that needs a particular suffix (ffmpeg takes the format from it) passes it as ``suffix``.
    The caller removes the file when it does not rename it.

    :raises UsageError: the disk is full, over quota or read-only, or the folder is not writable (naming ``path``).
    """
    fd, tmp = _create_temporary(path, suffix)
    os.close(fd)
    return tmp


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str = ".partial") -> Iterator[Path]:
    """Yield the path of a new temporary file (:func:`temporary_name`) to write ``path``'s content to; on a normal
    exit it is flushed to disk and renamed to ``path`` (replacing an older version, or a symlink, atomically: a
    symlink at ``path`` is replaced, never followed); on an exception it is removed and ``path`` is untouched.

    The writer must write exactly the path it is given (the file exists, empty, when it gets it).

    :raises UsageError: the disk is full, over quota or read-only, or the folder is not writable (naming ``path``).
    """
    final = Path(path)
    tmp: Path | None = None
    try:
        tmp = temporary_name(final, suffix)
        yield tmp
        _fsync(tmp)
        os.replace(tmp, final)
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise_disk_error(exc, final)
        raise


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[BinaryIO]:
    """Yield a binary file object open on a new temporary file for ``path`` (see :func:`atomic_path`); on a normal
    exit its data is flushed to disk and the file renamed to ``path``; on an exception it is removed.

    :raises UsageError: the disk is full, over quota or read-only, or the folder is not writable (naming ``path``).
    """
    final = Path(path)
    tmp: Path | None = None
    try:
        fd, tmp = _create_temporary(final, ".partial")
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    except BaseException as exc:
        if tmp is not None:
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
    if path.is_symlink() or not path.is_file():
        raise FileNotFoundError(errno.ENOENT, "the writer left no regular file", str(path))
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_file(path) as fh:
        fh.write(data)
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
    then rename it to ``path``; returns ``path``. The writer must write exactly the path it is given (an existing,
    empty regular file with an unpredictable name: see :func:`temporary_name`)."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_npz(path: str | Path, **arrays: Any) -> Path:
    """``np.savez`` of ``arrays`` to ``path`` atomically (through a file object: numpy would append ``.npz`` to
    the temporary name); returns ``path``."""
    import numpy as np

    with atomic_file(path) as fh:
        np.savez(fh, **arrays)
    return Path(path)


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


def staging_dir(path: str | Path) -> Path:
    """Create and return a new, empty hidden folder next to ``path`` (:func:`tempfile.mkdtemp`: an unpredictable
    name, created by this call) to write a folder's content into before :func:`replace_dir` publishes it."""
    final = Path(path)
    try:
        staged = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".partial"))
    except OSError as exc:
        raise_disk_error(exc, final)
        raise
    os.chmod(staged, _DIR_MODE)
    return staged


def replace_dir(staged: str | Path, path: str | Path) -> Path:
    """Rename the complete folder ``staged`` (from :func:`staging_dir`) to ``path``, replacing an older folder there;
    returns ``path``.

    Where the kernel has ``renameat2(RENAME_EXCHANGE)`` (Linux) the two folders swap names in one step, so a reader
    sees the old folder or the new one, never none; elsewhere the old folder is first renamed aside. The old folder
    is then deleted. A symlink or file at ``path`` is removed, never followed.
    """
    staged, final = Path(staged), Path(path)
    if final.is_symlink() or (final.exists() and not final.is_dir()):
        final.unlink()
    if not final.exists():
        os.replace(staged, final)
        return final
    if _exchange(staged, final):
        shutil.rmtree(staged, ignore_errors=True)  # now the old folder
        return final
    old = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".old"))
    os.replace(final, old)  # onto an empty folder: allowed
    os.replace(staged, final)
    shutil.rmtree(old, ignore_errors=True)
    return final


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names of ``a`` and ``b`` atomically (Linux ``renameat2`` with ``RENAME_EXCHANGE``); False where the
    C library or the file system does not offer it."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def run_subfolder(run_dir: str | Path, name: str, create: bool = True) -> Path:
    """The folder ``<run dir>/<name>`` (``videos``, ``export``) where sbagents writes by default, made if missing
    and ``create`` (else the caller makes it).

    A run dir may come from someone else: a symlink at that name (or one that leads the folder out of the run dir)
    would send the writes elsewhere, so it is refused instead of followed.

    :raises UsageError: one line naming the link.
    """
    root = Path(run_dir)
    folder = root / name
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise UsageError(f"{folder} is a symlink or not a folder; sbagents writes only into real folders inside the "
                         "run dir (remove it, or pass an output folder)")
    if not create and not folder.exists():
        return folder
    folder.mkdir(exist_ok=True)
    real_root, real = os.path.realpath(root), os.path.realpath(folder)
    if os.path.commonpath([real_root, real]) != real_root:
        raise UsageError(f"{folder} leads out of the run dir ({real}); remove it, or pass an output folder")
    return folder
