"""Loading an SB3 model zip that may come from someone else, without running code from it.

An SB3 zip holds its weights (``policy.pth``, read by torch with ``weights_only=True``) and a ``data`` JSON whose
``:serialized:`` entries (spaces, schedules, the policy class, buffers of the last rollout, ...) are cloudpickle
payloads that ``BaseAlgorithm.load`` would unpickle: a crafted entry runs any code it likes. sbagents hands every
such entry to SB3 through ``custom_objects`` instead, decoded by :class:`~sbagents.plain_data.PlainDataUnpickler`,
which builds plain data only (arrays, spaces, schedules, references to policy and network classes). Anything else
stops the load with one line that names the entry and says how to trust the file (:data:`TRUST_FLAG`). Entries
that are legitimately beyond plain data and that the model rebuilds from its weights (ARS's weight vector) are
rebuilt after loading. With ``trust=True`` the zip is loaded by SB3 as it is (the entries are unpickled).
"""

from __future__ import annotations

import base64
import binascii
import json
import pickle
import zipfile
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError
from sbagents.plain_data import (
    TRUST_FLAG,
    PlainDataUnpickler,
    UntrustedContentError,
    plain_loads,
    register_plain_class,
)
from sbagents.plain_data import short_message as _short

__all__ = ["TRUST_FLAG", "PlainDataUnpickler", "UntrustedContentError", "custom_objects", "load_model",
           "load_pickle_file", "plain_loads", "read_model_data", "register_plain_class", "untrusted_pickle"]

#: Entries of a model's data that SB3 rebuilds or resets when it is loaded, with what sbagents puts in their place
#: when they cannot be decoded (ARS's torch weight vector: the policy's parameters, set by :func:`_after_load`).
REBUILT_AFTER_LOAD: frozenset[str] = frozenset({"weights"})


def read_model_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` JSON of an SB3 model zip (nothing decoded).

    :raises UsageError: the file is missing, not a zip, truncated, or holds no valid ``data`` entry.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"model file {path} does not exist")
    try:
        with zipfile.ZipFile(path) as archive:
            if "data" not in archive.namelist():
                raise UsageError(f"{path} is a zip file but not an SB3 model (no 'data' entry)")
            raw = archive.read("data")
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, RuntimeError) as exc:
        if isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile) and exc.errno is not None:
            raise
        raise UsageError(f"{path} is not an SB3 model file, or not a complete one (empty, truncated or not a zip: "
                         f"{_short(exc)})") from None
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise UsageError(f"{path}: its 'data' entry is not valid JSON ({_short(exc)})") from None
    if not isinstance(data, dict):
        raise UsageError(f"{path}: its 'data' entry is not a JSON object")
    return data


def custom_objects(path: str | Path, trusted_modules: Iterable[str] = ()) -> dict[str, Any]:
    """Every ``:serialized:`` entry of the model at ``path``, decoded as plain data (for SB3's ``custom_objects``);
    entries of :data:`REBUILT_AFTER_LOAD` that are not plain data become None.

    :raises UntrustedContentError: an entry needs more than plain data.
    """
    objects: dict[str, Any] = {}
    for key, item in read_model_data(path).items():
        if not (isinstance(item, dict) and ":serialized:" in item):
            continue
        try:
            payload = base64.b64decode(str(item[":serialized:"]).encode(), validate=True)
        except (binascii.Error, ValueError):
            raise UsageError(f"{path}: entry {key!r} is corrupt (not base64)") from None
        try:
            objects[key] = plain_loads(payload, f"{path} (entry {key!r})", trusted_modules)
        except UntrustedContentError:
            if key not in REBUILT_AFTER_LOAD:
                raise
            objects[key] = None
    return objects


def _after_load(model: Any, objects: dict[str, Any]) -> None:
    """Rebuild what :func:`custom_objects` could not decode from the loaded weights."""
    if "weights" in objects and objects["weights"] is None and hasattr(model, "weights"):
        import torch

        model.weights = torch.nn.utils.parameters_to_vector(model.policy.parameters()).detach()


#: Exceptions of a model file that loads but is broken inside (bad weights, shapes that do not fit the env).
_LOAD_ERRORS: tuple[type[BaseException], ...] = (
    zipfile.BadZipFile, zlib.error, EOFError, KeyError, ValueError, RuntimeError, AssertionError,
    pickle.UnpicklingError, TypeError, AttributeError, MemoryError,
)


def load_model(cls: Any, path: str | Path, *, env: Any = None, device: str = "cpu", trust: bool = False,
               trusted_modules: Iterable[str] = (), **kwargs: Any) -> Any:
    """``cls.load(path, ...)`` without executing anything from the file (see the module docstring).

    :param cls: the SB3 algorithm class (``PPO``, a constrained or robust subclass, ...).
    :param env: the env to attach (its spaces must match the model's).
    :param trust: load the zip as SB3 does, unpickling its entries (the user vouches for the file).
    :param trusted_modules: module prefixes (the user's packages) whose classes the model may name.
    :param kwargs: further arguments of ``cls.load`` (they replace loaded attributes).
    :raises UsageError: one line: the file is missing, corrupt, needs trust, or does not fit ``env``.
    """
    objects = None if trust else custom_objects(path, trusted_modules)
    if trust:
        read_model_data(path)  # a clear line for a missing, empty or truncated file
    try:
        model = cls.load(str(path), env=env, device=device, custom_objects=objects, **kwargs)
    except UsageError:
        raise
    except _LOAD_ERRORS as exc:
        raise UsageError(f"cannot load the model {path} ({type(exc).__name__}: {_short(exc)})") from None
    if objects is not None:
        _after_load(model, objects)
    return model


def untrusted_pickle(path: Path, what: str) -> UntrustedContentError:
    """The one-line refusal of a pickle file an older run kept (``what`` it holds), naming :data:`TRUST_FLAG`."""
    return UntrustedContentError(
        f"{path} is a pickle ({what} of an older run); unpickling runs any code it holds, so sbagents does not "
        f"load it by default: pass {TRUST_FLAG} if you trust where the run came from")


def load_pickle_file(path: str | Path, what: str, trust: bool, loader: Callable[[Path], Any]) -> Any:
    """Load a pickle file of an older run (``vecnormalize.pkl``, ``replay_buffer.pkl``) with ``loader`` only when
    the user trusts it; otherwise refuse in one line that says why and how.

    :raises UntrustedContentError: without ``trust``.
    """
    path = Path(path)
    if not trust:
        raise untrusted_pickle(path, what)
    try:
        return loader(path)
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, KeyError, AttributeError, ImportError,
            IndexError) as exc:
        raise UsageError(f"{path} is corrupt ({type(exc).__name__}: {_short(exc)})") from None
