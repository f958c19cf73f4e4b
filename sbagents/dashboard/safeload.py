"""Bounded loaders of the small files of a run dir (JSON, YAML, text, CSV, ``.npz``), all through
:class:`~sbagents.dashboard.folders.RunFiles`.

Each returns the data, or None (an empty result) and one sentence in ``notes`` when the file is over its byte
limit, not text, malformed, or would make data the dashboard cannot send: YAML goes through a safe loader and
JSON through ``json``, then :func:`json_data` copies the result into plain JSON types with at most
:data:`MAX_NODES` values and :data:`MAX_DEPTH` levels (a YAML alias bomb or a deeply nested list gives a note, not
gigabytes of JSON or a recursion error). ``.npz`` files are opened with ``allow_pickle=False`` and their members'
sizes and array headers are checked before any array is read. Nothing is unpickled or evaluated.
"""

from __future__ import annotations

import csv
import datetime
import io
import json
import math
import zipfile
from collections.abc import Sequence
from typing import Any

import numpy as np
import yaml

from sbagents.dashboard.folders import FileTooLarge, RunFiles, human_size

#: Byte limit of a JSON, YAML or text file (``summary.json``, ``args.yml``, ``command.txt``, ``safety.json``).
SMALL_FILE_BYTES = 1 << 20
#: Byte limit of a callback's CSV (``adversarial.csv``, ``fairness.csv``).
TABLE_BYTES = 16 << 20
#: Uncompressed bytes an ``.npz`` may hold (``evaluations.npz``).
NPZ_BYTES = 64 << 20
#: Values (counting every container and scalar) and nesting levels loaded JSON/YAML data may have.
MAX_NODES = 200_000
MAX_DEPTH = 64

_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class DataTooComplex(ValueError):
    """Loaded data has more than :data:`MAX_NODES` values or :data:`MAX_DEPTH` levels."""


def json_data(value: Any, max_nodes: int = MAX_NODES, max_depth: int = MAX_DEPTH) -> Any:
    """A copy of ``value`` in JSON types (dict with str keys, list, str, int, float, bool, None): sets and tuples
    become lists, dates ISO strings, bytes and other objects their ``repr``.

    :raises DataTooComplex: more than ``max_nodes`` values (shared references count each time) or ``max_depth``
        levels.
    """
    budget = [max_nodes]

    def copy(v: Any, depth: int) -> Any:
        budget[0] -= 1
        if budget[0] < 0:
            raise DataTooComplex(f"more than {max_nodes:,} values")
        if depth > max_depth:
            raise DataTooComplex(f"nested deeper than {max_depth} levels")
        if v is None or isinstance(v, (bool, str)):
            return v
        if isinstance(v, int):
            return v if abs(v) < 1 << 63 else float(v) if v.bit_length() < 1024 else str(v)
        if isinstance(v, float):
            return v if math.isfinite(v) else None
        if isinstance(v, dict):
            return {str(k): copy(x, depth + 1) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [copy(x, depth + 1) for x in v]
        if isinstance(v, (set, frozenset)):
            return sorted((copy(x, depth + 1) for x in v), key=repr)
        if isinstance(v, (datetime.date, datetime.time)):
            return v.isoformat()
        return repr(v)[:200]

    return copy(value, 0)


def read_bytes(run: RunFiles, name: str, notes: list[str], limit: int) -> bytes | None:
    """The bytes of ``name`` (None when missing, outside the served folder or not a regular file; None and a note
    when over ``limit`` bytes)."""
    try:
        return run.read_bytes(name, limit)
    except FileTooLarge as exc:
        notes.append(f"{exc}; not shown")
        return None


def read_text(run: RunFiles, name: str, notes: list[str], limit: int | None = None) -> str | None:
    """``name`` as text, at most ``limit`` bytes (default :data:`SMALL_FILE_BYTES`); bytes that are not UTF-8 become
    U+FFFD, with a note."""
    data = read_bytes(run, name, notes, SMALL_FILE_BYTES if limit is None else limit)
    if data is None:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        notes.append(f"{name} is not UTF-8 text; undecodable bytes are shown as \ufffd")
        return data.decode("utf-8", "replace")


def _load(run: RunFiles, name: str, notes: list[str], kind: str) -> Any:
    data = read_bytes(run, name, notes, SMALL_FILE_BYTES)
    if data is None:
        return None
    try:
        text = data.decode("utf-8")
        value = json.loads(text) if kind == "json" else yaml.load(text, Loader=_YAML_LOADER)  # a SafeLoader
        return json_data(value)
    except Exception as exc:  # a malformed file: the parsers raise many kinds (ValueError, YAMLError, RecursionError)
        notes.append(f"{name} could not be read ({type(exc).__name__}: {str(exc)[:80]}); showing the rest")
        return None


def read_json(run: RunFiles, name: str, notes: list[str]) -> Any:
    """``name``'s JSON as plain data, or None (with a note when it exists but is not usable)."""
    return _load(run, name, notes, "json")


def read_yaml(run: RunFiles, name: str, notes: list[str]) -> Any:
    """``name``'s YAML (safe loader) as plain JSON data, or None (with a note when it exists but is not usable)."""
    return _load(run, name, notes, "yaml")


def read_mapping(run: RunFiles, name: str, notes: list[str]) -> dict[str, Any] | None:
    """``name`` (``.json``: JSON, else YAML) when it holds a mapping; a note and None when it holds anything else."""
    value = read_json(run, name, notes) if name.endswith(".json") else read_yaml(run, name, notes)
    if value is None or isinstance(value, dict):
        return value
    notes.append(f"{name} holds a {type(value).__name__}, not a mapping; not shown")
    return None


def read_csv_rows(run: RunFiles, name: str, notes: list[str]) -> list[dict[str, str]]:
    """Rows of a small CSV written by a callback (a partial last line is dropped)."""
    text = read_text(run, name, notes, TABLE_BYTES)
    if not text:
        return []
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    try:
        return list(csv.DictReader(io.StringIO(text.replace("\x00", ""))))
    except csv.Error as exc:
        notes.append(f"{name} is malformed ({exc}); not shown")
        return []


def read_npz(run: RunFiles, name: str, keys: Sequence[str], notes: list[str]) -> dict[str, np.ndarray] | None:
    """The arrays ``keys`` of the ``.npz`` file ``name`` (those it has), or None (with a note when it exists but
    cannot be read: not a zip, members over :data:`NPZ_BYTES` in all, an array header that promises more data than
    its member holds, object arrays)."""
    fh = run.open(name)
    if fh is None:
        return None
    try:
        with fh, zipfile.ZipFile(fh) as archive:
            infos = {i.filename.removesuffix(".npy"): i for i in archive.infolist()}
            if sum(i.file_size for i in infos.values()) > NPZ_BYTES:
                raise FileTooLarge(f"over {human_size(NPZ_BYTES)} uncompressed")
            out = {}
            for key in keys:
                if key in infos:
                    with archive.open(infos[key]) as member:
                        out[key] = _read_npy(member, infos[key].file_size)
            return out
    except Exception as exc:  # a half-written or foreign file: zipfile and numpy raise many kinds
        notes.append(f"{name} could not be read ({type(exc).__name__}: {str(exc)[:80]}); not shown")
        return None


def _read_npy(member: Any, size: int) -> np.ndarray:
    """One ``.npy`` member of ``size`` bytes, after checking that its header's shape fits in them."""
    fmt = np.lib.format
    version = fmt.read_magic(member)
    read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
    shape, fortran, dtype = read_header(member)
    if dtype.hasobject:
        raise ValueError("object arrays are not read")
    count = math.prod(shape)
    if count * dtype.itemsize > size:
        raise ValueError(f"its header promises {shape} {dtype} in {size} bytes")
    data = member.read(count * dtype.itemsize)
    if len(data) < count * dtype.itemsize:
        raise ValueError("truncated array data")
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape, order="F" if fortran else "C")
