"""Loading an SB3 model zip that may come from someone else: the model is *rebuilt* from numbers and names.

An SB3 zip holds its weights (``policy.pth``, optimizer states, ``pytorch_variables.pth``) and a ``data`` JSON whose
``:serialized:`` entries (spaces, schedules, the policy class, the last rollout's arrays, ...) are cloudpickle
payloads that ``BaseAlgorithm.load`` would unpickle: a crafted entry runs any code it likes, and even a restricted
unpickler that calls numpy's own helpers lets a file choose pointers numpy dereferences. So by default no
``:serialized:`` entry is decoded at all. :func:`load_model` builds the model from:

- the algorithm class the caller names (the run's ``--algo``, with its extensions' class);
- the policy class: found by its module and name in the entry's plain-text description, resolved like a config's
  import path (:mod:`sbagents.import_paths`: checked before any import) and required to be a policy; else the run's
  ``policy`` hyperparameter;
- constructor arguments: the run's resolved hyperparameters when the caller has them (validated like any config),
  else the JSON-native fields of ``data`` that are constructor parameters (``gamma``, ``n_steps``, a plain
  ``policy_kwargs``), each a bounded plain value; a ``policy_kwargs`` holding classes is rebuilt from its plain
  description (the classes by name, allow-listed);
- the spaces: the env's (when given), checked against the plain JSON record sbagents saves with every model
  (:mod:`sbagents.spaces_record`); without an env, the record itself; for a zip written elsewhere (RL Zoo's) the
  plain description of Box and Discrete spaces, or the env;
- counters (``num_timesteps``, ...) from JSON, and entries a class declares it rebuilds from plain data
  (:data:`PLAIN_ENTRIES_ATTR`: a constrained model's Lagrange multiplier);
- the weights, read with ``torch.load(weights_only=True)`` and set with ``exact_match=True``.

With ``trust=True`` (``--trust-run``) the zip is loaded by SB3 as it is, unpickling its entries: for models whose
entries cannot be rebuilt from plain data (a schedule written as a Python closure, a custom policy class outside the
allow-list).
"""

from __future__ import annotations

import inspect
import io
import json
import math
import os
import pickle
import re
import zipfile
import zlib
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError
from sbagents.import_paths import resolve_path
from sbagents.plain_data import TRUST_FLAG, UntrustedContentError
from sbagents.plain_data import short_message as _short

__all__ = ["PLAIN_ENTRIES_ATTR", "TRUST_FLAG", "UntrustedContentError", "load_model", "load_pickle_file",
           "read_model_data", "read_weights", "record_spaces"]

# gymnasium, numpy and torch are imported where they are needed: ``sbagents.serve`` imports this module's
# neighbours and must stay free of them.

#: A class attribute of an algorithm: ``{entry: builder(description, data) -> value}`` for ``:serialized:`` entries
#: the class rebuilds from their plain description (the JSON fields SB3 writes beside each payload).
PLAIN_ENTRIES_ATTR = "plain_entries"

#: Packages whose classes a model may name (policy, buffers, activation, optimizer, features extractor).
REFERENCE_PREFIXES: tuple[str, ...] = ("stable_baselines3", "sb3_contrib", "sbagents", "torch.nn", "torch.optim")

#: The most a model file may unpack to (every member together: 48 MiB, ``SBAGENTS_MAX_MODEL_BYTES`` for bigger
#: models; a 512x3 TQC with its optimizers takes ~30 MiB, an Atari CNN 7), and its ``data`` JSON alone.
MAX_UNPACKED_BYTES = int(os.environ.get("SBAGENTS_MAX_MODEL_BYTES", 48 << 20))
MAX_DATA_BYTES = 16 << 20
#: The most nested a plain value from ``data`` may be, and the largest integer it may hold.
_MAX_DEPTH = 8
_MAX_INT = 1 << 40

#: ``data`` fields that are counters and settings of the run, copied when they are plain numbers.
_COUNTERS: frozenset[str] = frozenset({
    "num_timesteps", "_total_timesteps", "_num_timesteps_at_start", "_episode_num", "_n_updates", "_n_calls",
    "_current_progress_remaining", "_stats_window_size", "exploration_rate", "seed",
})
#: Constructor parameters never taken from a file.
_RUNTIME = frozenset({"self", "policy", "env", "device", "verbose", "tensorboard_log", "_init_setup_model",
                      "seed", "monitor_wrapper", "support_multi_env", "supported_action_spaces"})
#: Parameters that only size training buffers, bounded when a model is loaded for evaluation.
_EVAL_SIZES: dict[str, int] = {"buffer_size": 16, "n_steps": 8}


def read_model_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` JSON of an SB3 model zip (nothing decoded).

    :raises UsageError: the file is missing, not a zip, truncated, too large, or holds no valid ``data`` entry.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"model file {path} does not exist")
    try:
        with zipfile.ZipFile(path) as archive:
            _check_sizes(archive, path)
            if "data" not in archive.namelist():
                raise UsageError(f"{path} is a zip file but not an SB3 model (no 'data' entry)")
            raw = archive.read("data")
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, RuntimeError, ValueError, NotImplementedError) as exc:
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


def _check_sizes(archive: zipfile.ZipFile, path: Path) -> None:
    infos = archive.infolist()
    if len(infos) > 256:
        raise UsageError(f"{path} has {len(infos)} members; an SB3 model has a handful")
    total = sum(info.file_size for info in infos)
    data = next((info.file_size for info in infos if info.filename == "data"), 0)
    if total > MAX_UNPACKED_BYTES or data > MAX_DATA_BYTES:
        raise UsageError(f"{path} unpacks to {total} bytes (data {data}); sbagents loads models up to "
                         f"{MAX_UNPACKED_BYTES} bytes ({MAX_DATA_BYTES} of data; set SBAGENTS_MAX_MODEL_BYTES "
                         "for a bigger model you trust)")


def read_weights(path: str | Path, device: str = "cpu") -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """The state dicts (``policy``, ``policy.optimizer``, ...) and PyTorch variables of a model zip, read with
    ``torch.load(weights_only=True)`` (tensors and containers only).

    :raises UsageError: a member that is not such a file, or not a mapping of state dicts.
    """
    import torch

    path = Path(path)
    params: dict[str, dict[str, Any]] = {}
    variables: dict[str, Any] = {}
    try:
        with zipfile.ZipFile(path) as archive:
            _check_sizes(archive, path)
            for name in archive.namelist():
                if not name.endswith(".pth"):
                    continue
                loaded = torch.load(io.BytesIO(archive.read(name)), map_location=device, weights_only=True)
                if not isinstance(loaded, dict):
                    raise UsageError(f"{path}: {name} is not a state dict")
                if name in ("pytorch_variables.pth", "tensors.pth"):
                    variables = loaded
                else:
                    params[name[: -len(".pth")]] = loaded
    except UsageError:
        raise
    except Exception as exc:  # noqa: BLE001 - torch's restricted unpickler raises many kinds on a corrupt file
        raise UsageError(f"{path}: its weights cannot be read ({type(exc).__name__}: {_short(exc)})") from None
    if "policy" not in params:
        raise UsageError(f"{path} holds no policy weights (policy.pth)")
    return params, variables


# --- plain values from data ---------------------------------------------------------------------------------------
def _plain(value: Any, depth: int = 0) -> bool:
    """Whether a JSON value is small plain data (bounded depth and integers, finite floats)."""
    if depth > _MAX_DEPTH:
        return False
    if value is None or isinstance(value, bool | str):
        return not isinstance(value, str) or len(value) <= 4096
    if isinstance(value, int):
        return abs(value) <= _MAX_INT
    if isinstance(value, float):
        return True
    if isinstance(value, list):
        return len(value) <= 4096 and all(_plain(v, depth + 1) for v in value)
    if isinstance(value, dict):
        return len(value) <= 256 and all(isinstance(k, str) and _plain(v, depth + 1) for k, v in value.items())
    return False


def _serialized(item: Any) -> bool:
    return isinstance(item, dict) and ":serialized:" in item


_CLASS_TEXT = re.compile(r"^<class '([A-Za-z_][\w.]*)'>$")
_METHOD_TEXT = re.compile(r"^<function ([A-Za-z_]\w*)\.\w+ at 0x[0-9a-f]+>$")


def _class_by_name(dotted: str, what: str, bases: tuple[type, ...], trusted: Iterable[str]) -> type:
    """The class ``dotted`` names, resolved from the allow-list (never importing a module the name chooses) and
    required to derive from ``bases``."""
    obj, _ = resolve_path(dotted, what, REFERENCE_PREFIXES, trusted)
    if not (inspect.isclass(obj) and issubclass(obj, bases)):
        raise UsageError(f"{what} {dotted!r} is not a {' or '.join(b.__name__ for b in bases)} class")
    return obj


def _described_class(item: Any) -> str | None:
    """``module.Name`` of a class from SB3's plain description of a pickled class (its ``__module__`` and the
    qualified names of its methods), or of a ``"<class '...'>"`` text; None when it names no single class."""
    if isinstance(item, str):
        found = _CLASS_TEXT.match(item)
        return found.group(1) if found else None
    if not isinstance(item, dict) or not isinstance(item.get("__module__"), str):
        return None
    names = {m.group(1) for v in item.values() if isinstance(v, str) and (m := _METHOD_TEXT.match(v))}
    return f"{item['__module__']}.{names.pop()}" if len(names) == 1 else None


def _policy_kwargs(item: Any, trusted: Iterable[str]) -> dict[str, Any]:
    """``policy_kwargs`` from ``data``: as it is when plain, else rebuilt from its description (plain values kept,
    classes resolved by name)."""
    import torch

    if not isinstance(item, dict):
        return {}
    if not _serialized(item):
        return {k: v for k, v in item.items() if k != "device"} if _plain(item) else {}
    kwargs: dict[str, Any] = {}
    for key, value in item.items():
        if key.startswith(":") or key == "device":
            continue
        name = _CLASS_TEXT.match(value) if isinstance(value, str) else None
        if name:
            bases: tuple[type, ...] = (torch.optim.Optimizer,) if key == "optimizer_class" else (torch.nn.Module,)
            kwargs[key] = _class_by_name(name.group(1), f"policy_kwargs {key}", bases, trusted)
        elif _plain(value) and not (isinstance(value, str) and value.startswith("<")):
            kwargs[key] = value
        else:
            raise UntrustedContentError(
                f"policy_kwargs {key!r} is {str(value)[:60]!r}, which only unpickling would build (pass {TRUST_FLAG} "
                "if you trust where the model came from)")
    return kwargs


# --- the spaces ---------------------------------------------------------------------------------------------------
def _described_space(item: Any) -> Any:
    """A Box or Discrete space from SB3's plain description of a pickled one (zips without sbagents' record)."""
    import numpy as np
    from gymnasium import spaces

    if not isinstance(item, dict):
        return None
    kind = item.get(":type:")
    try:
        if kind == "<class 'gymnasium.spaces.discrete.Discrete'>":
            return spaces.Discrete(int(str(item["n"])), start=int(str(item.get("start", "0"))))
        if kind == "<class 'gymnasium.spaces.box.Box'>":
            shape = tuple(int(v) for v in item["_shape"])
            if math.prod(shape) > 1 << 22:
                return None
            dtype = np.dtype(str(item["dtype"]))
            if dtype.kind not in "fiub":
                return None
            bounds = []
            for key in ("low", "high"):
                text = str(item[key])
                if "..." in text or len(text) > 1 << 20:
                    return None
                values = [float(v) for v in text.replace("[", " ").replace("]", " ").split()]
                bounds.append(np.array(values if len(values) != 1 else values * math.prod(shape)).reshape(shape))
            return spaces.Box(bounds[0].astype(dtype), bounds[1].astype(dtype), shape=shape, dtype=dtype)
    except (KeyError, ValueError, TypeError, OverflowError):
        return None
    return None


def _model_spaces(data: dict[str, Any], env: Any, path: Path) -> tuple[Any, Any]:
    """The model's spaces: the env's, checked against the file's record (or description); else the record's."""
    from sbagents.spaces_record import RECORD_KEY, check_record, describe, same_space

    recorded = check_record(data[RECORD_KEY], str(path)) if RECORD_KEY in data else None
    if env is not None:
        found = (env.observation_space, env.action_space)
        expected = recorded or (_described_space(data.get("observation_space")),
                                _described_space(data.get("action_space")))
        for what, have, want in zip(("observation", "action"), found, expected, strict=True):
            if want is None:
                continue
            if recorded is not None and not same_space(have, want):
                raise UsageError(f"{path} was trained on the {what} space {describe(want)}; this env's is "
                                 f"{describe(have)}")
            if recorded is None and (type(have) is not type(want) or getattr(have, "shape", None) != want.shape):
                raise UsageError(f"{path} was trained on the {what} space {describe(want)}; this env's is "
                                 f"{describe(have)}")
        return found
    if recorded is not None:
        return recorded
    described = (_described_space(data.get("observation_space")), _described_space(data.get("action_space")))
    if described[0] is None or described[1] is None:
        raise UsageError(f"{path} carries no plain record of its spaces (written by another tool or an older "
                         f"sbagents) and they are not Box or Discrete: load it with its env, or pass {TRUST_FLAG} if "
                         "you trust where it came from")
    return described


def record_spaces(model: Any) -> None:
    """Give ``model`` the plain record of its spaces, which SB3 then saves in the zip's ``data`` JSON."""
    from sbagents.spaces_record import RECORD_KEY, spaces_record

    record = spaces_record(model.observation_space, model.action_space)
    if record is not None:
        setattr(model, RECORD_KEY, record)


# --- the policy class ---------------------------------------------------------------------------------------------
def _algo_of_policy(dotted: str) -> str | None:
    from sbagents.algos import ALGOS

    for name, entry in ALGOS.items():
        for policy in getattr(entry.cls, "policy_aliases", {}).values():
            if f"{policy.__module__}.{policy.__qualname__}" == dotted:
                return name
    return None


def _policy_class(cls: Any, data: dict[str, Any], hyperparams: Mapping[str, Any] | None, path: Path,
                  trusted: Iterable[str]) -> Any:
    from stable_baselines3.common.policies import BasePolicy

    aliases: dict[str, Any] = getattr(cls, "policy_aliases", {})
    chosen = (hyperparams or {}).get("policy")
    if isinstance(chosen, type):
        return chosen
    item = data.get("policy_class")
    dotted = _described_class(item)
    if dotted is None:
        if isinstance(chosen, str) and chosen in aliases:
            return aliases[chosen]
        raise UntrustedContentError(f"{path}: its policy class is not described by name, so only unpickling would "
                                    f"build it (pass {TRUST_FLAG} if you trust where the model came from)")
    for policy in aliases.values():
        if f"{policy.__module__}.{policy.__qualname__}" == dotted:
            return policy
    other = _algo_of_policy(dotted)
    if other is not None:
        raise UsageError(f"{path} is a {other} model (its policy is {dotted.rsplit('.', 1)[-1]}), not a "
                         f"{cls.__name__} one: use --algo {other}")
    return _class_by_name(dotted, "policy_class", (BasePolicy,), trusted)


# --- constructor arguments ----------------------------------------------------------------------------------------
def _parameters(cls: Any) -> set[str]:
    """The keyword arguments ``cls(...)`` accepts (its ``__init__``'s, and its bases' while each passes ``**kwargs``
    on)."""
    names: set[str] = set()
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters.values()
        names |= {p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}
        if not any(p.kind == p.VAR_KEYWORD for p in params):
            break
    return names - _RUNTIME


def _constructor_kwargs(cls: Any, data: dict[str, Any], hyperparams: Mapping[str, Any] | None,
                        trusted: Iterable[str], for_training: bool) -> dict[str, Any]:
    from stable_baselines3.common.buffers import BaseBuffer

    accepted = _parameters(cls)
    kwargs: dict[str, Any] = {}
    for key, item in data.items():
        if key not in accepted:
            continue
        if key == "policy_kwargs":
            kwargs[key] = _policy_kwargs(item, trusted)
        elif key == "replay_buffer_class" and _serialized(item):
            dotted = _described_class(item)
            if dotted is not None:
                kwargs[key] = _class_by_name(dotted, key, (BaseBuffer,), trusted)
        elif not _serialized(item) and _plain(item):
            kwargs[key] = item
    if hyperparams is not None:
        kwargs.update({k: v for k, v in hyperparams.items() if k in accepted})
    if not for_training:
        for key, bound in _EVAL_SIZES.items():
            if isinstance(kwargs.get(key), int):
                kwargs[key] = max(1, min(kwargs[key], bound))
        buffer = kwargs.get("replay_buffer_class")
        if isinstance(buffer, type) and any(k.__name__ == "HerReplayBuffer" for k in buffer.__mro__):
            kwargs["replay_buffer_class"], kwargs["replay_buffer_kwargs"] = None, {}  # HER samples need the env
    return kwargs


# --- loading ------------------------------------------------------------------------------------------------------
#: Exceptions of a model file that loads but is broken inside (bad weights, shapes that do not fit the env).
_LOAD_ERRORS: tuple[type[BaseException], ...] = (
    zipfile.BadZipFile, zlib.error, EOFError, KeyError, ValueError, RuntimeError, AssertionError,
    pickle.UnpicklingError, TypeError, AttributeError, MemoryError, IndexError, OverflowError,
)


def load_model(cls: Any, path: str | Path, *, env: Any = None, device: str = "cpu", trust: bool = False,
               trusted_modules: Iterable[str] = (), hyperparams: Mapping[str, Any] | None = None,
               for_training: bool | None = None, **kwargs: Any) -> Any:
    """The model at ``path``, rebuilt from plain data and weights (see the module docstring); nothing in the file is
    unpickled unless ``trust``.

    :param cls: the SB3 algorithm class (``PPO``, a constrained or robust subclass, ...).
    :param env: the env to attach (its spaces must match the model's record).
    :param trust: load the zip as SB3 does, unpickling its entries (the user vouches for the file).
    :param trusted_modules: modules the user named (``--gym-packages``), whose classes the model may name.
    :param hyperparams: the run's resolved constructor arguments (they take precedence over the file's).
    :param for_training: the model will train on (default: when ``env`` is given); otherwise buffers that only
        training fills are kept small.
    :param kwargs: attributes to set on the model (as ``cls.load``'s keyword arguments do).
    :raises UsageError: one line: the file is missing, corrupt, needs trust, or does not fit ``env``.
    """
    path = Path(path)
    data = read_model_data(path)  # a clear line for a missing, empty or truncated file
    if trust:
        from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

        if env is None and not for_training and issubclass(cls, OffPolicyAlgorithm):
            kwargs = {"replay_buffer_class": None, "replay_buffer_kwargs": {}, **kwargs}  # HER's needs the env
        try:
            return cls.load(str(path), env=env, device=device, **kwargs)
        except UsageError:
            raise
        except _LOAD_ERRORS as exc:
            raise UsageError(f"cannot load the model {path} ({type(exc).__name__}: {_short(exc)})") from None
    try:
        model = _rebuild(cls, path, data, env, device, tuple(trusted_modules), hyperparams,
                         env is not None if for_training is None else for_training, kwargs)
    except UsageError:
        raise
    except RecursionError:
        raise UsageError(f"cannot load the model {path}: its data is nested too deeply") from None
    except _LOAD_ERRORS as exc:
        raise UsageError(f"cannot load the model {path} ({type(exc).__name__}: {_short(exc)})") from None
    return model


def _rebuild(cls: Any, path: Path, data: dict[str, Any], env: Any, device: str, trusted: tuple[str, ...],
             hyperparams: Mapping[str, Any] | None, for_training: bool, attributes: dict[str, Any]) -> Any:
    from stable_baselines3.common.utils import get_device
    from stable_baselines3.common.vec_env.patch_gym import _patch_env

    params, variables = read_weights(path)
    if env is not None:
        env = cls._wrap_env(_patch_env(env) if not hasattr(env, "num_envs") else env, 0)
    obs_space, act_space = _model_spaces(data, env, path)
    policy = _policy_class(cls, data, hyperparams, path, trusted)
    ctor = _constructor_kwargs(cls, data, hyperparams, trusted, for_training)
    ctor.pop("policy", None)
    if "target_entropy" in _parameters(cls) and not isinstance(ctor.get("target_entropy"), int | float):
        import numpy as np  # "auto" (the saved value is a numpy scalar): what SAC and TQC compute from the env

        ctor["target_entropy"] = -float(np.prod(act_space.shape))
    try:
        model = cls(policy=policy, env=env, device=device, _init_setup_model=False, **ctor)
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        raise UsageError(f"{path}: its settings do not build a {cls.__name__} ({_short(exc)})") from None
    if env is None:
        model.observation_space, model.action_space = obs_space, act_space
        model.n_envs = 1
    for key in _COUNTERS:
        value = data.get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and abs(value) <= _MAX_INT:
            setattr(model, key, value)
    for key, build in getattr(cls, PLAIN_ENTRIES_ATTR, {}).items():
        if key in data:
            setattr(model, key, build(data[key], data))
    model.__dict__.update(attributes)
    model.device = get_device(device)
    model._setup_model()
    try:
        model.set_parameters(params, exact_match=True, device=device)
    except (RuntimeError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise UsageError(f"{path}: its weights do not fit a {cls.__name__} with these settings and spaces "
                         f"({_short(exc)})") from None
    _, variable_names = model._get_torch_save_params()
    for name, value in variables.items():
        if name not in variable_names or value is None:
            continue
        from stable_baselines3.common.save_util import recursive_getattr

        target = recursive_getattr(model, name)
        if getattr(value, "shape", None) != target.shape:
            raise UsageError(f"{path}: variable {name} has the wrong shape")
        target.data.copy_(value.data)
    if getattr(model, "use_sde", False):
        model.policy.reset_noise()
    if hasattr(getattr(model, "weights", None), "shape"):  # ARS: a flat copy of the policy's parameters
        import torch

        model.weights = torch.nn.utils.parameters_to_vector(model.policy.parameters()).detach()
    record_spaces(model)
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
