"""Training state kept beside a model, in files that hold numbers only: ``VecNormalize`` statistics
(``vecnormalize.npz``) and replay buffers (``replay_buffer.npz``).

SB3 writes both as pickles, and unpickling a file runs whatever code it names. These ``.npz`` files are read with
``numpy.load(allow_pickle=False)``: arrays, plus one JSON string of settings. A ``.pkl`` of a run made before
sbagents wrote them is loaded only when the user trusts it (``--trust-run``, :mod:`sbagents.safe_load`).

Both writers are atomic (:mod:`sbagents.atomic`).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from sbagents.atomic import write_npz
from sbagents.errors import UsageError
from sbagents.plain_data import short_message
from sbagents.safe_load import load_pickle_file

#: The statistics file of a run dir (of one model; ``vecnormalize.<group>.npz`` for a group's).
VECNORMALIZE_FILE = "vecnormalize.npz"
#: The ``VecNormalize`` statistics of the moment ``best_model.zip`` was kept (``evaluate --load-best`` uses them).
BEST_VECNORMALIZE_FILE = "vecnormalize_best.npz"
#: The replay buffer file of a run dir (``--save-replay-buffer``).
REPLAY_BUFFER_FILE = "replay_buffer.npz"
#: Format version written into the settings of both files.
FORMAT = 1

_SETTINGS = "__settings__"
_VECNORMALIZE_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon", "norm_obs_keys")


def legacy_path(path: Path) -> Path:
    """The pickle an older run kept in place of ``path`` (``vecnormalize.npz`` -> ``vecnormalize.pkl``)."""
    return path.with_suffix(".pkl")


def existing(path: Path | None) -> Path | None:
    """``path`` if it exists, else the legacy pickle beside it if that exists, else None."""
    if path is None:
        return None
    if path.exists():
        return path
    legacy = legacy_path(path)
    return legacy if legacy.exists() else None


#: The most a statistics file may unpack to (a replay buffer's limit is its model's buffer size).
MAX_STATS_BYTES = 64 << 20


def check_npz_size(path: Path, what: str, max_bytes: int) -> None:
    """Refuse (one line) an ``.npz`` whose members would unpack to more than ``max_bytes``, before reading any.

    :raises UsageError: too large, or not a zip file.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
        if isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile) and exc.errno is not None:
            raise
        raise UsageError(f"{path} is not a valid {what} file ({type(exc).__name__}: {short_message(exc)})") from None
    total = sum(info.file_size for info in infos)
    _check_headers(path, what)
    settings = sum(info.file_size for info in infos if info.filename == f"{_SETTINGS}.npy")
    if settings > 1 << 20:
        raise UsageError(f"{path}: its settings take {settings} bytes; a {what} file's take a few hundred")
    if len(infos) > 4096 or total > max_bytes:
        raise UsageError(f"{path} unpacks to {total} bytes in {len(infos)} arrays; a {what} file of this model "
                         f"holds at most {max_bytes}")


def _check_headers(path: Path, what: str) -> None:
    """Every member's ``.npy`` header must describe no more data than the member holds (a header may claim a shape
    of 10^12 elements, which numpy would allocate before it reads)."""
    import math

    from numpy.lib import format as npy

    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                with archive.open(info) as member:
                    version = npy.read_magic(member)
                    reader = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
                    shape, _, dtype = reader(member, max_header_size=10_000)
                    if dtype.hasobject or math.prod(shape) * dtype.itemsize > info.file_size:
                        raise ValueError(f"{info.filename} claims {shape} {dtype}, more than its {info.file_size} "
                                         "bytes")
    except UsageError:
        raise
    except Exception as exc:  # noqa: BLE001 - a corrupt header or member raises many kinds
        raise UsageError(f"{path} is not a valid {what} file ({type(exc).__name__}: {short_message(exc)})") from None


def _read_npz(path: Path, what: str, max_bytes: int = MAX_STATS_BYTES) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The arrays and the settings of one of these files (one-line errors for anything malformed; at most
    ``max_bytes`` unpacked, checked before anything is read)."""
    check_npz_size(path, what, max_bytes)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except OSError as exc:
        if not isinstance(exc, zipfile.BadZipFile) and exc.errno is not None:
            raise
        raise UsageError(f"{path} is not a valid {what} file ({type(exc).__name__}: {short_message(exc)})") from None
    except Exception as exc:  # noqa: BLE001 - numpy's header parser raises many kinds (tokenize, zlib, value, ...)
        raise UsageError(f"{path} is not a valid {what} file ({type(exc).__name__}: {short_message(exc)})") from None
    try:
        settings = json.loads(str(arrays.pop(_SETTINGS)))
    except (KeyError, ValueError) as exc:
        raise UsageError(f"{path} is not a valid {what} file (no settings: {exc})") from None
    if not isinstance(settings, dict) or settings.get("format") != FORMAT:
        raise UsageError(f"{path} is not a {what} file of format {FORMAT}")
    return arrays, settings


# --- VecNormalize ---------------------------------------------------------------------------------------------
def save_vecnormalize(venv: Any, path: str | Path) -> Path:
    """Write the statistics and settings of a ``VecNormalize`` to ``path`` (``.npz``, atomically)."""
    arrays: dict[str, Any] = {}
    obs_rms = getattr(venv, "obs_rms", None)  # SB3 keeps none with norm_obs false (rewards scaled only)
    rms = {} if obs_rms is None else obs_rms if isinstance(obs_rms, dict) else {"": obs_rms}
    for key, stats in rms.items():
        arrays |= {f"obs_rms/{key}/mean": stats.mean, f"obs_rms/{key}/var": stats.var,
                   f"obs_rms/{key}/count": np.asarray(stats.count, np.float64)}
    arrays |= {"ret_rms/mean": venv.ret_rms.mean, "ret_rms/var": venv.ret_rms.var,
               "ret_rms/count": np.asarray(venv.ret_rms.count, np.float64)}
    settings = {k: getattr(venv, k) for k in _VECNORMALIZE_KEYS}
    settings |= {"format": FORMAT, "dict_obs": isinstance(obs_rms, dict)}
    arrays[_SETTINGS] = np.asarray(json.dumps(settings))
    return write_npz(path, **arrays)


def load_vecnormalize(path: str | Path, venv: Any, trust: bool = False) -> Any:
    """A ``VecNormalize`` around ``venv`` with the statistics saved at ``path`` (``.npz``; a legacy ``.pkl`` only
    with ``trust``).

    :raises UsageError: the file is malformed or its statistics do not fit ``venv``'s observations.
    """
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from stable_baselines3.common.vec_env import VecNormalize

    path = Path(path)
    if path.suffix == ".pkl":
        return load_pickle_file(path, "VecNormalize statistics", trust,
                                lambda p: VecNormalize.load(str(p), venv))
    arrays, settings = _read_npz(path, "VecNormalize statistics")
    try:
        kwargs = {k: settings[k] for k in _VECNORMALIZE_KEYS}
        norm = VecNormalize(venv, **kwargs)
        keys = sorted({name.split("/")[1] for name in arrays if name.startswith("obs_rms/")})
        if keys or norm.norm_obs:  # norm_obs false: SB3 keeps no observation statistics, nor does the file
            loaded = {key: _rms(arrays, f"obs_rms/{key}", RunningMeanStd) for key in keys}
            obs_rms = loaded if settings.get("dict_obs") else loaded[""]
            _check_same_shapes(norm.obs_rms, obs_rms)
            norm.obs_rms = obs_rms
        norm.ret_rms = _rms(arrays, "ret_rms", RunningMeanStd)
    except (KeyError, TypeError, ValueError, AssertionError) as exc:
        raise UsageError(f"{path} does not fit this env's observations ({type(exc).__name__}: {exc})") from None
    return norm


def _real(array: np.ndarray, name: str) -> np.ndarray:
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} holds {array.dtype} values, not real numbers")
    return array


def _rms(arrays: dict[str, np.ndarray], prefix: str, cls: Any) -> Any:
    for part in ("mean", "var", "count"):
        _real(arrays[f"{prefix}/{part}"], f"{prefix}/{part}")
    if arrays[f"{prefix}/var"].shape != arrays[f"{prefix}/mean"].shape or arrays[f"{prefix}/count"].size != 1:
        raise ValueError(f"{prefix}: var of shape {arrays[f'{prefix}/var'].shape} for a mean of shape "
                         f"{arrays[f'{prefix}/mean'].shape} (and one count)")
    mean, var, count = (arrays[f"{prefix}/{part}"].astype(np.float64) for part in ("mean", "var", "count"))
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0) and np.isfinite(count)
            and count >= 0):
        raise ValueError(f"{prefix} holds a mean or variance that is not finite, a negative variance or count")
    stats = cls(shape=arrays[f"{prefix}/mean"].shape)
    stats.mean = arrays[f"{prefix}/mean"].astype(np.float64)
    stats.var = arrays[f"{prefix}/var"].astype(np.float64)
    stats.count = float(arrays[f"{prefix}/count"])
    return stats


def _check_same_shapes(expected: Any, loaded: Any) -> None:
    if isinstance(expected, dict) != isinstance(loaded, dict):
        raise ValueError("the file normalizes Dict observations and the env does not, or the other way round")
    pairs = expected.keys() if isinstance(expected, dict) else [None]
    for key in pairs:
        want = expected[key] if key is not None else expected
        got = loaded.get(key) if key is not None else loaded
        if got is None or np.shape(want.mean) != np.shape(got.mean):
            raise ValueError(f"observation statistics of shape {np.shape(got.mean) if got is not None else None}, "
                             f"the env's observations have shape {np.shape(want.mean)}"
                             + (f" (key {key!r})" if key is not None else ""))


# --- replay buffers -------------------------------------------------------------------------------------------
def _plain_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not plain data")


def _saved_class(buffer: Any) -> str:
    """The class name a replay buffer's file records: its ``saved_as`` where it has one, else its own class's."""
    saved_as = getattr(buffer, "saved_as", None)
    return saved_as if isinstance(saved_as, str) else type(buffer).__name__


def save_replay_buffer(buffer: Any, path: str | Path, num_timesteps: int | None = None) -> Path:
    """Write a replay buffer's arrays and position to ``path`` (``.npz``, atomically): every numpy array attribute
    (also per key of Dict observations), object arrays (HER's ``infos``) as JSON, and ``pos``/``full``. The file
    names the buffer's class, or the class whose state it holds where the buffer says so (``saved_as``: a subclass
    that adds no saved state, so that either class reads the file).

    :param num_timesteps: the model's step count when the buffer was saved (recorded, so that continuing a model
        saved at another step can tell the buffer is not its own: :func:`replay_buffer_steps`).
    """
    arrays: dict[str, Any] = {}
    for name, value in vars(buffer).items():
        if isinstance(value, np.ndarray) and value.dtype == object:
            try:
                arrays[f"json/{name}"] = np.asarray(json.dumps(value.tolist(), default=_plain_json))
            except TypeError as exc:
                raise UsageError(f"cannot save the replay buffer's {name}: {exc}") from None
        elif isinstance(value, np.ndarray):
            arrays[f"array/{name}"] = value
        elif isinstance(value, dict) and value and all(isinstance(v, np.ndarray) for v in value.values()):
            arrays |= {f"dict/{name}/{key}": v for key, v in value.items()}
    settings = {"format": FORMAT, "class": _saved_class(buffer), "pos": int(buffer.pos), "full": bool(buffer.full),
                "buffer_size": int(buffer.buffer_size), "n_envs": int(buffer.n_envs)}
    if num_timesteps is not None:
        settings["num_timesteps"] = int(num_timesteps)
    arrays[_SETTINGS] = np.asarray(json.dumps(settings))
    return write_npz(path, **arrays)


def replay_buffer_steps(path: str | Path) -> int | None:
    """The model step count recorded with the replay buffer at ``path`` (None: a legacy ``.pkl``, or a file saved
    before sbagents recorded it); only the file's settings are read.

    :raises UsageError: the file is not a replay buffer file.
    """
    path = Path(path)
    if path.suffix == ".pkl":
        return None
    check_npz_size(path, "replay buffer", 1 << 62)  # the settings member alone is bounded here
    try:
        with np.load(path, allow_pickle=False) as data:
            settings = json.loads(str(data[_SETTINGS]))
    except OSError as exc:
        if not isinstance(exc, zipfile.BadZipFile) and exc.errno is not None:
            raise
        raise UsageError(f"{path} is not a valid replay buffer file ({type(exc).__name__}: {short_message(exc)})"
                         ) from None
    except Exception as exc:  # noqa: BLE001 - numpy's and json's parsers raise many kinds on a corrupt file
        raise UsageError(f"{path} is not a valid replay buffer file ({type(exc).__name__}: {short_message(exc)})"
                         ) from None
    steps = settings.get("num_timesteps") if isinstance(settings, dict) else None
    return steps if isinstance(steps, int) and not isinstance(steps, bool) else None


def load_replay_buffer(buffer: Any, path: str | Path, trust: bool = False, model: Any = None) -> None:
    """Fill ``buffer`` (the model's, built from its config) with the one saved at ``path`` (``.npz``; a legacy
    ``.pkl`` only with ``trust``, through ``model.load_replay_buffer``).

    :raises UsageError: the file is malformed, or was saved from a buffer of another size, kind or spaces.
    """
    path = Path(path)
    if path.suffix == ".pkl":
        load_pickle_file(path, "a replay buffer", trust, lambda p: model.load_replay_buffer(str(p)))
        return
    expected = sum(v.nbytes for v in vars(buffer).values() if isinstance(v, np.ndarray)) + sum(
        a.nbytes for v in vars(buffer).values() if isinstance(v, dict) for a in v.values() if isinstance(a, np.ndarray))
    arrays, settings = _read_npz(path, "replay buffer", expected + MAX_STATS_BYTES)
    mine = {"class": _saved_class(buffer), "buffer_size": int(buffer.buffer_size), "n_envs": int(buffer.n_envs)}
    theirs = {k: settings.get(k) for k in mine}
    if theirs.get("class") == type(buffer).__name__:  # a file written before the class named its saved state
        theirs["class"] = mine["class"]
    if theirs != mine:
        raise UsageError(f"{path} holds a {theirs['class']} of buffer_size {theirs['buffer_size']} for "
                         f"{theirs['n_envs']} envs; this model's is a {mine['class']} of buffer_size "
                         f"{mine['buffer_size']} for {mine['n_envs']} envs")
    updates: dict[str, Any] = {}
    for name, value in arrays.items():
        kind, _, rest = name.partition("/")
        attr, _, key = rest.partition("/")
        target = getattr(buffer, attr, None)
        if kind == "dict" and isinstance(target, dict):
            target = target.get(key)
        if kind == "json":
            try:
                value = np.asarray(json.loads(str(value)), dtype=object).reshape(np.shape(target))  # type: ignore[arg-type]
            except (ValueError, RecursionError, TypeError) as exc:
                raise UsageError(f"{path}: {rest} is not valid ({type(exc).__name__}: {exc})") from None
        if not isinstance(target, np.ndarray) or not isinstance(value, np.ndarray) or target.shape != value.shape or (
                kind != "json" and target.dtype != value.dtype):
            raise UsageError(f"{path}: {rest} does not fit this model's replay buffer "
                             f"({getattr(value, 'shape', None)} {getattr(value, 'dtype', '')} vs "
                             f"{getattr(target, 'shape', None)} {getattr(target, 'dtype', '')})")
        updates[name] = (target, value)
    pos, full = settings.get("pos"), settings.get("full")
    if isinstance(pos, bool) or not isinstance(pos, int) or not 0 <= pos <= buffer.buffer_size \
            or not isinstance(full, bool):
        raise UsageError(f"{path}: its position {pos!r:.40} / full {full!r:.20} do not fit a buffer of "
                         f"{buffer.buffer_size}")
    for target, value in updates.values():  # all checked first: a mismatch leaves the buffer as it was
        target[...] = value
    buffer.pos, buffer.full = pos, full
