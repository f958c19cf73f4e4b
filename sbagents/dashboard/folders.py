"""The served log folders and the only way the dashboard turns a URL into a file: :class:`ServedFolders`.

A file is reachable when its real path (symlinks resolved) lies under the real path of one served folder.
Absolute paths, ``..`` components, NUL bytes and symlinks that lead out of the folder resolve to ``None``
(the app answers 404), whatever the folder contains.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from sbagents.errors import UsageError


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
        except OSError:
            return None
        return real if real == base or real.is_relative_to(base) else None

    def relative(self, root: int, path: Path) -> str:
        """``path`` (under folder ``root``) as the POSIX string :meth:`resolve` takes."""
        return path.relative_to(self.roots[root]).as_posix()
