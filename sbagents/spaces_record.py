"""Gymnasium spaces as plain JSON, so a saved model can be rebuilt without unpickling its spaces.

A model sbagents saves carries :data:`RECORD_KEY` in its ``data`` JSON: its observation and action spaces as numbers
and names (``{"type": "Box", "shape": [4], "dtype": "float32", "low": ..., "high": ...}``). Loading rebuilds the
spaces from that record (:func:`space_from_json`), or takes an env's spaces and checks them against it
(:func:`same_space`). Sizes are bounded, so a record cannot make the loader allocate much memory.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.errors import UsageError

#: The ``data`` field that holds the record (an attribute of the model, saved by SB3 as plain JSON).
RECORD_KEY = "sbagents_spaces"

#: At most this many numbers in one space (an 84x84x4 image stack has 28,224; a 210x160x3 frame 100,800).
MAX_ELEMENTS = 1 << 22
#: At most this deep a nesting of Dict and Tuple spaces.
MAX_DEPTH = 6
#: At most this many sub-spaces in one Dict or Tuple.
MAX_CHILDREN = 1024
_DTYPES = ("float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
           "uint64", "bool")


def _number(value: Any) -> Any:
    """A float for JSON: non-finite values as strings (``"inf"``), so the record is strict JSON."""
    value = float(value)
    return value if math.isfinite(value) else str(value)


def _bounds(array: np.ndarray) -> Any:
    """One number when every element is the same, else a flat list."""
    flat = np.asarray(array, dtype=np.float64).ravel()
    if flat.size and np.all(flat == flat[0]):
        return _number(flat[0])
    return [_number(v) for v in flat]


def space_to_json(space: spaces.Space[Any]) -> dict[str, Any]:
    """``space`` as plain JSON (:mod:`module docstring <sbagents.spaces_record>`).

    :raises ValueError: a kind of space the record does not describe (the model then has no record).
    """
    if isinstance(space, spaces.Box):
        return {"type": "Box", "shape": list(space.shape), "dtype": str(space.dtype), "low": _bounds(space.low),
                "high": _bounds(space.high)}
    if isinstance(space, spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if isinstance(space, spaces.MultiDiscrete):
        return {"type": "MultiDiscrete", "nvec": np.asarray(space.nvec).tolist(),
                "start": np.asarray(space.start).tolist(), "dtype": str(space.dtype)}
    if isinstance(space, spaces.MultiBinary):
        return {"type": "MultiBinary", "n": np.asarray(space.n).tolist()}
    if isinstance(space, spaces.Dict):
        return {"type": "Dict", "spaces": [[str(k), space_to_json(s)] for k, s in space.spaces.items()]}
    if isinstance(space, spaces.Tuple):
        return {"type": "Tuple", "spaces": [space_to_json(s) for s in space.spaces]}
    raise ValueError(f"no plain record for {type(space).__name__} spaces")


def spaces_record(observation_space: spaces.Space[Any], action_space: spaces.Space[Any]) -> dict[str, Any] | None:
    """The record of a model's two spaces, or None when one of them has no plain description."""
    try:
        return {"observation_space": space_to_json(observation_space), "action_space": space_to_json(action_space)}
    except ValueError:
        return None


class BadRecord(ValueError):
    """A record that does not describe a space (the message says what is wrong)."""


def _int(value: Any, what: str, low: int = 0, high: int = 1 << 62) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise BadRecord(f"{what} must be an integer in [{low}, {high}], got {value!r:.40}")
    return value


def _shape(value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or len(value) > 8:
        raise BadRecord(f"shape must be a list of at most 8 sizes, got {value!r:.60}")
    shape = tuple(_int(v, "a size", 0, MAX_ELEMENTS) for v in value)
    if math.prod(shape) > MAX_ELEMENTS:
        raise BadRecord(f"shape {shape} has more than {MAX_ELEMENTS} elements")
    return shape


def _float(value: Any) -> float:
    if isinstance(value, str) and value in ("inf", "-inf", "nan"):
        return float(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BadRecord(f"a bound must be a number, got {value!r:.40}")
    return float(value)


def _bound_array(value: Any, shape: tuple[int, ...], dtype: np.dtype[Any]) -> np.ndarray:
    size = math.prod(shape)
    if isinstance(value, list):
        if len(value) != size:
            raise BadRecord(f"{len(value)} bounds for a shape of {size} elements")
        flat = np.array([_float(v) for v in value], dtype=np.float64)
    else:
        flat = np.full(size, _float(value), dtype=np.float64)
    return flat.reshape(shape).astype(dtype) if np.issubdtype(dtype, np.floating) else flat.reshape(shape)


def space_from_json(record: Any, depth: int = 0) -> spaces.Space[Any]:
    """The space a record describes (only numbers and names are read; sizes are bounded).

    :raises BadRecord: a malformed record.
    """
    if depth > MAX_DEPTH or not isinstance(record, dict):
        raise BadRecord("a space must be a JSON object, nested at most 6 deep")
    kind = record.get("type")
    if kind == "Box":
        shape = _shape(record.get("shape"))
        if record.get("dtype") not in _DTYPES:
            raise BadRecord(f"dtype must be one of {', '.join(_DTYPES)}, got {record.get('dtype')!r:.40}")
        dtype = np.dtype(record["dtype"])
        low = _bound_array(record.get("low"), shape, dtype)
        high = _bound_array(record.get("high"), shape, dtype)
        try:
            return spaces.Box(low=low, high=high, shape=shape, dtype=dtype)  # type: ignore[arg-type]
        except (ValueError, TypeError, OverflowError) as exc:
            raise BadRecord(f"not a Box: {exc}") from None
    if kind == "Discrete":
        return spaces.Discrete(_int(record.get("n"), "n", 1), start=_int(record.get("start", 0), "start", -(1 << 62)))
    if kind == "MultiDiscrete":
        nvec, start = record.get("nvec"), record.get("start")
        if not isinstance(nvec, list) or not isinstance(start, list) or len(nvec) != len(start) \
                or len(nvec) > MAX_ELEMENTS:
            raise BadRecord("MultiDiscrete needs flat nvec and start lists of one length")
        if record.get("dtype") not in _DTYPES:
            raise BadRecord("MultiDiscrete needs an integer dtype")
        return spaces.MultiDiscrete([_int(v, "nvec", 1) for v in nvec], dtype=record["dtype"],
                                    start=[_int(v, "start", -(1 << 62)) for v in start])
    if kind == "MultiBinary":
        n = record.get("n")
        return spaces.MultiBinary(list(_shape(n)) if isinstance(n, list) else _int(n, "n", 1, MAX_ELEMENTS))
    if kind in ("Dict", "Tuple"):
        items = record.get("spaces")
        if not isinstance(items, list) or len(items) > MAX_CHILDREN:
            raise BadRecord(f"{kind} needs a list of at most {MAX_CHILDREN} spaces")
        if kind == "Tuple":
            return spaces.Tuple([space_from_json(s, depth + 1) for s in items])
        pairs = []
        for item in items:
            if not (isinstance(item, list) and len(item) == 2 and isinstance(item[0], str)):
                raise BadRecord("Dict spaces are [name, space] pairs")
            pairs.append((item[0], space_from_json(item[1], depth + 1)))
        return spaces.Dict(dict(pairs))
    raise BadRecord(f"unknown space type {kind!r:.40}")


def same_space(a: spaces.Space[Any], b: spaces.Space[Any]) -> bool:
    """Whether two spaces are the same kind, shape, dtype and bounds (exact: a record is written from the space)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, spaces.Box):
        assert isinstance(b, spaces.Box)
        return (a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a.low, b.low, equal_nan=True)
                and np.array_equal(a.high, b.high, equal_nan=True))
    if isinstance(a, spaces.Dict):
        assert isinstance(b, spaces.Dict)
        return list(a.spaces) == list(b.spaces) and all(same_space(a[k], b[k]) for k in a.spaces)
    if isinstance(a, spaces.Tuple):
        assert isinstance(b, spaces.Tuple)
        return len(a.spaces) == len(b.spaces) and all(same_space(x, y) for x, y in zip(a.spaces, b.spaces, strict=True))
    return bool(a == b)


def describe(space: spaces.Space[Any]) -> str:
    """A short description for messages (``Box(4,) float32``, ``Discrete(5)``)."""
    if isinstance(space, spaces.Box):
        return f"Box{space.shape} {space.dtype}"
    return str(space)[:80]


def check_record(record: Any, what: str) -> tuple[spaces.Space[Any], spaces.Space[Any]]:
    """The two spaces of a model's record.

    :param what: the model file, for the message.
    :raises UsageError: a malformed record (one line).
    """
    if not isinstance(record, dict):
        raise UsageError(f"{what}: its {RECORD_KEY} entry is not a JSON object")
    try:
        return space_from_json(record.get("observation_space")), space_from_json(record.get("action_space"))
    except (BadRecord, RecursionError) as exc:
        raise UsageError(f"{what}: its record of the model's spaces is malformed ({exc})") from None
