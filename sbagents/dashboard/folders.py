"""The served log folders and the only way the dashboard turns a name into a file: :class:`ServedFolders` (URLs)
and :class:`RunFiles` (the files of one run dir, for every reader).

A file is reachable when its real path (symlinks resolved) lies under the real path of one served folder.
Absolute paths, ``..`` components, NUL bytes and symlinks that lead out of the folder resolve to ``None``
(the app answers 404, a reader treats the file as missing), whatever the folder contains. Files are opened
through :func:`open_regular`, once: component by component from ``/`` without following any symlink (a real path
has none, so a symlink swapped in after the check, at the file's name or at any folder above it, makes the open
fail instead of leading out), without blocking, and only when the opened file is a regular file (a FIFO would block
the request, a device would never end); everything after that reads the open file, never the path again, with a
byte limit (:meth:`RunFiles.read_bytes`).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from sbagents.errors import UsageError

#: ``os.open`` flags of every file the dashboard reads: no blocking on a FIFO, no symlink as the last component.
_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
#: ``os.open`` flags of each folder on the way to a file: a folder, not a symlink (``O_PATH``: no read permission
#: needed, as for a path lookup).
_DIR_FLAGS = (getattr(os, "O_PATH", os.O_RDONLY) | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0)
              | getattr(os, "O_CLOEXEC", 0))
#: macOS: ``open`` itself refuses a symlink anywhere in the path.
_NOFOLLOW_ANY = getattr(os, "O_NOFOLLOW_ANY", 0)
#: Whether folders can be walked with ``dir_fd`` (POSIX).
_WALK = os.open in os.supports_dir_fd and hasattr(os, "O_DIRECTORY") and hasattr(os, "O_NOFOLLOW")


def _open_no_symlinks(path: str) -> int:
    """A file descriptor of the absolute ``path`` opened with :data:`_OPEN_FLAGS`, reached without following any
    symlink: each folder is opened from the one before (``O_DIRECTORY | O_NOFOLLOW``), the file last."""
    if _NOFOLLOW_ANY:
        return os.open(path, _OPEN_FLAGS | _NOFOLLOW_ANY)
    if not _WALK:  # no dir_fd (Windows): only the last component is checked
        return os.open(path, _OPEN_FLAGS)
    parts = Path(path).parts
    if len(parts) < 2:
        raise IsADirectoryError(f"{path} is not a file")
    dir_fd = os.open(parts[0], _DIR_FLAGS)
    try:
        for part in parts[1:-1]:
            fd = os.open(part, _DIR_FLAGS, dir_fd=dir_fd)
            os.close(dir_fd)
            dir_fd = fd
        return os.open(parts[-1], _OPEN_FLAGS, dir_fd=dir_fd)
    finally:
        os.close(dir_fd)


def open_regular(path: Path) -> BinaryIO:
    """``path`` opened once for binary reading if it is a regular file, reached without following any symlink.

    ``path`` is a real path (:meth:`ServedFolders.resolve` gives one): a symlink on the way to it (at its name or at
    any folder above) was swapped in after the path was checked, and the open fails rather than follow it. Where
    ``/proc/self/fd`` exists, the opened file's path must still be ``path`` (a folder above it was not moved away
    meanwhile). The open does not block (``O_NONBLOCK``), so a FIFO swapped in is refused, not waited on. Read the
    returned file, never ``path`` again.

    :raises OSError: it is missing, not a regular file (FIFO, device, socket, folder), or reached through a symlink.
    """
    text = os.path.abspath(path)
    fd = _open_no_symlinks(text)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(f"{path.name} is not a regular file")
        try:
            opened = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:  # no /proc (macOS): the open itself refused symlinks
            opened = text
        if opened != text:
            raise OSError(f"{path.name} is no longer at {text}")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


@dataclass(frozen=True)
class ServedFolders:
    """Log folders served read-only, addressed by their position: folder ``i`` is ``/run/<i>/...``.

    :param roots: the folders' real paths (symlinks resolved).
    """

    roots: tuple[Path, ...]

    @classmethod
    def from_paths(cls, folders: Sequence[str | Path]) -> ServedFolders:
        """Check that every folder exists (else :class:`UsageError`) and resolve it."""
        if not folders:
            raise UsageError("-f/--log-folder: give at least one log folder")
        roots = []
        for folder in folders:
            path = Path(folder).expanduser()
            if not path.is_dir():
                raise UsageError(f"-f/--log-folder {folder}: no such folder (give the folder train -f wrote to)")
            roots.append(path.resolve())
        return cls(tuple(roots))

    def label(self, root: int) -> str:
        """How folder ``root`` is shown: its name (with its index when several folders share one)."""
        name = self.roots[root].name or str(self.roots[root])
        same = [r for r in self.roots if r.name == self.roots[root].name]
        return name if len(same) == 1 else f"{name} ({root})"

    def resolve(self, root: int, relative: str) -> Path | None:
        """The real path of ``relative`` inside folder ``root``, or None if it is not a file or folder there.

        :param root: index of the served folder.
        :param relative: a POSIX path relative to that folder ("" is the folder itself).
        """
        if not 0 <= root < len(self.roots) or "\x00" in relative or "\\" in relative:
            return None
        parts = PurePosixPath(relative).parts
        if relative.startswith("/") or any(p in ("..", "/") for p in parts):
            return None
        base = self.roots[root]
        try:
            real = Path(os.path.realpath(base.joinpath(*parts), strict=True))
        except (OSError, ValueError):
            return None
        return real if real == base or real.is_relative_to(base) else None

    def relative(self, root: int, path: Path) -> str:
        """``path`` (under folder ``root``) as the POSIX string :meth:`resolve` takes."""
        return path.relative_to(self.roots[root]).as_posix()

    def run(self, root: int, relative: str) -> RunFiles | None:
        """The files of the folder ``relative`` of served folder ``root``, or None when it is not a folder there."""
        path = self.resolve(root, relative)
        return RunFiles(self, root, relative, path) if path is not None and path.is_dir() else None


class FileTooLarge(Exception):
    """A file is over the byte limit its reader allows."""


@dataclass(frozen=True)
class RunFiles:
    """The files of one run dir, each reached through :meth:`ServedFolders.resolve` (names are POSIX paths relative
    to the run dir, e.g. ``summary.json``, ``videos/clip.csv``): a name whose real path leaves the served folder is
    a missing file.

    :param folders: the served folders.
    :param root: index of the served folder the run dir is in.
    :param rel: the run dir relative to that folder ("" is the folder itself).
    :param path: the run dir's real path.
    """

    folders: ServedFolders
    root: int
    rel: str
    path: Path

    def resolve(self, name: str) -> Path | None:
        """The real path of ``name`` if it exists under the served folder, else None."""
        return self.folders.resolve(self.root, f"{self.rel}/{name}" if self.rel else name)

    def file(self, name: str) -> Path | None:
        """The real path of ``name`` if it is a regular file under the served folder, else None."""
        path = self.resolve(name)
        try:
            return path if path is not None and stat.S_ISREG(os.lstat(path).st_mode) else None
        except OSError:
            return None

    def folder(self, name: str) -> Path | None:
        """The real path of ``name`` if it is a folder under the served folder, else None."""
        path = self.resolve(name)
        return path if path is not None and path.is_dir() else None

    def stat(self, name: str) -> os.stat_result | None:
        """``os.lstat`` of the regular file ``name`` (None when :meth:`file` is None)."""
        path = self.file(name)
        try:
            return os.lstat(path) if path is not None else None
        except OSError:
            return None

    def glob(self, pattern: str) -> list[str]:
        """Names of the regular files matching ``pattern`` (``Path.glob`` syntax, relative to the run dir) that are
        under the served folder, sorted."""
        fixed = []  # the pattern's folder before any wildcard: nothing to list when it leads out
        for part in PurePosixPath(pattern).parent.parts:
            if any(c in part for c in "*?["):
                break
            fixed.append(part)
        if fixed and self.folder("/".join(fixed)) is None:
            return []
        names = sorted(p.relative_to(self.path).as_posix() for p in self.path.glob(pattern))
        return [name for name in names if self.file(name) is not None]

    def folders_here(self) -> list[str]:
        """Names of the run dir's sub-folders that are under the served folder, sorted."""
        try:
            entries = sorted(e.name for e in os.scandir(self.path) if e.is_dir())
        except OSError:
            return []
        return [name for name in entries if self.folder(name) is not None]

    def open(self, name: str) -> BinaryIO | None:
        """``name`` opened for binary reading (see :func:`open_regular`), or None when it is missing, outside the
        served folder or not a regular file."""
        path = self.file(name)
        if path is None:
            return None
        try:
            return open_regular(path)
        except OSError:
            return None

    def read_bytes(self, name: str, limit: int) -> bytes | None:
        """The bytes of ``name`` (None when :meth:`open` is None).

        :raises FileTooLarge: the file has more than ``limit`` bytes (only ``limit + 1`` are read).
        """
        fh = self.open(name)
        if fh is None:
            return None
        with fh:
            try:
                data = fh.read(limit + 1)
            except OSError:
                return None
        if len(data) > limit:
            raise FileTooLarge(f"{name} is over {human_size(limit)}")
        return data


def human_size(n_bytes: int) -> str:
    """``n_bytes`` as a short size: ``1000 B``, ``64 KiB``, ``1.5 MiB``."""
    size, unit = float(n_bytes), "B"
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            break
        size /= 1024
    return f"{size:.3g} {unit}" if unit != "B" else f"{n_bytes} B"
