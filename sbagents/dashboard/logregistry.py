"""The transparency logs open in this process: one :class:`~sbagents.dashboard.logindex.LogIndex` per file
(:func:`open_log`), indexed once in a background thread (:func:`index_in_background`).

Each log has its own lock: opening a log (which reads its header, at most
:data:`~sbagents.dashboard.logindex.MAX_HEADER_BYTES`) and indexing it hold only that log's lock, so a big log being
indexed never makes a request for another log wait. The registry's own lock only guards its dicts.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

from sbagents.dashboard.logindex import LogIndex

_LOGS: dict[Path, LogIndex] = {}
_OPENING: dict[Path, threading.Lock] = {}
_REGISTRY_LOCK = threading.Lock()
_INDEXING: set[Path] = set()


def open_log(path: Path, resolved: bool = False) -> LogIndex:
    """The :class:`LogIndex` of ``path``, shared process-wide (keyed by the resolved path; thread-safe).

    A file that was replaced or truncated since it was indexed (another inode, or smaller) gets a new index.
    The returned index may be incomplete: call :meth:`LogIndex.refresh` (e.g. :func:`index_in_background`).

    :param resolved: ``path`` is already a real path (the dashboard's) and is not resolved again: a symlink swapped
        in since it was checked makes the open fail instead of being followed (see :class:`LogIndex`).
    :raises OSError: the file cannot be opened (gone, not a regular file, or reached through a symlink swapped in).
    """
    key = Path(os.path.abspath(path)) if resolved else Path(path).resolve()
    with _REGISTRY_LOCK:
        lock = _OPENING.setdefault(key, threading.Lock())
    with lock:  # only requests for this log wait while it is opened
        with _REGISTRY_LOCK:
            index = _LOGS.get(key)
        if index is None or index.is_stale():
            index = LogIndex(key, resolved=True)
            with _REGISTRY_LOCK:
                _LOGS[key] = index
                _INDEXING.discard(key)
        return index


def index_in_background(index: LogIndex) -> None:
    """Index the whole log once in a daemon thread (pages asked for meanwhile are served from what is indexed)."""
    key = index.path
    with _REGISTRY_LOCK:
        if key in _INDEXING or index.problem is not None:
            return
        _INDEXING.add(key)
    threading.Thread(target=_refresh, args=(index,), name="sbagents-log-index", daemon=True).start()


def _refresh(index: LogIndex) -> None:
    try:
        index.refresh()
    except OSError:  # the file went away while it was indexed: a later request re-opens it
        with _REGISTRY_LOCK:
            _INDEXING.discard(index.path)


__all__ = ["index_in_background", "open_log"]
