"""A decoder of pickles that builds plain data only, for files that may come from someone else.

Unpickling runs whatever a pickle names. :class:`PlainDataUnpickler` (the pure-Python unpickler with its opcode
table overridden) builds *plain data only*:

- Python's own containers and scalars, numpy arrays, scalars, dtypes and random generators;
- gymnasium spaces, SB3's schedules, train frequencies and action noises, and classes registered with
  :func:`register_plain_class` (the Lagrange multipliers of :mod:`sbagents.constrained`), instantiated without
  ``__init__`` and filled from their state;
- *references* to classes (never calls to them) of the kinds a model names: policies, buffers, ``torch.nn``
  modules and ``torch.optim`` optimizers, from ``stable_baselines3``, ``sb3_contrib``, ``sbagents``, ``torch.nn``,
  ``torch.optim`` and the modules the user trusts by naming them (``--gym-packages``, ``--env module:...``).

Anything else (a function, a module outside that list, a call to a class, a state set on a class) raises
:class:`UntrustedContentError`: one line naming the file and entry and how to trust it (:data:`TRUST_FLAG`).
:mod:`sbagents.safe_load` uses it for SB3 model zips.
"""

from __future__ import annotations

import collections
import enum
import importlib
import io
import pickle
from collections.abc import Callable, Iterable
from typing import Any

from sbagents.errors import UsageError

#: The flag of every CLI that loads files from a run dir: trust them (load pickles as they are).
TRUST_FLAG = "--trust-run"

#: Modules whose classes a model may *name* (policy, buffers, activation, optimizer, features extractor).
REFERENCE_PREFIXES: tuple[str, ...] = ("stable_baselines3", "sb3_contrib", "sbagents", "torch.nn", "torch.optim")

_PLAIN_CLASSES: set[type] = set()


class UntrustedContentError(UsageError):
    """A file holds something that loading it would have to execute; the message names it and the trust flag."""


class _Refused(Exception):
    """Internal: the pickle asked for something outside plain data (the message says what)."""


def register_plain_class(cls: type) -> type:
    """Let :class:`PlainDataUnpickler` rebuild instances of ``cls`` (a data holder whose construction and
    ``__setstate__`` run no code of the file's choosing, e.g. a Lagrange multiplier); usable as a decorator."""
    _PLAIN_CLASSES.add(cls)
    return cls


def _safe_bit_generator(bit_generator: Any = "MT19937") -> Any:
    import numpy.random as npr

    known = {cls.__name__: cls for cls in (npr.MT19937, npr.PCG64, npr.PCG64DXSM, npr.Philox, npr.SFC64)}
    name = bit_generator.__name__ if isinstance(bit_generator, type) else bit_generator
    if not isinstance(name, str) or name not in known or (isinstance(bit_generator, type)
                                                          and bit_generator is not known[name]):
        raise _Refused(f"an unknown random bit generator {bit_generator!r}")
    return known[name]()


def _safe_generator(bit_generator: Any = "MT19937", ctor: Any = None) -> Any:
    import numpy.random as npr

    if isinstance(bit_generator, npr.BitGenerator):
        return npr.Generator(bit_generator)
    return npr.Generator(_safe_bit_generator(bit_generator))


def _safe_random_state(bit_generator: Any = "MT19937", ctor: Any = None) -> Any:
    import numpy.random as npr

    if isinstance(bit_generator, npr.BitGenerator):
        return npr.RandomState(bit_generator)
    return npr.RandomState(_safe_bit_generator(bit_generator))


def _safe_seed_sequence(cls: Any, checksum: Any, state: Any) -> Any:
    """Cython's unpickle helper of ``SeedSequence`` (a space's random generator holds one), for that class only."""
    import numpy.random.bit_generator as bg

    if cls is not bg.SeedSequence:
        raise _Refused(f"a seed sequence of class {getattr(cls, '__qualname__', cls)!r}")
    return bg.__pyx_unpickle_SeedSequence(cls, checksum, state)  # type: ignore[attr-defined]


def _numpy_functions() -> dict[tuple[str, str], Any]:
    """The numpy pickling helpers (both module spellings, numpy 1 and 2) -> what to call instead."""
    import numpy as np

    core = getattr(np, "_core", None) or np.core
    table: dict[tuple[str, str], Any] = {}
    for prefix in ("numpy.core", "numpy._core"):
        table[(f"{prefix}.multiarray", "_reconstruct")] = core.multiarray._reconstruct
        table[(f"{prefix}.multiarray", "scalar")] = core.multiarray.scalar
        table[(f"{prefix}.numeric", "_frombuffer")] = core.numeric._frombuffer
    for name, fn in (("__bit_generator_ctor", _safe_bit_generator), ("__generator_ctor", _safe_generator),
                     ("__randomstate_ctor", _safe_random_state)):
        table[("numpy.random._pickle", name)] = fn
    table[("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence")] = _safe_seed_sequence
    table[("numpy.random.bit_generator", "SeedSequence")] = np.random.SeedSequence
    table[("numpy", "ndarray")] = np.ndarray
    table[("numpy", "dtype")] = np.dtype
    return table


def _sized_refused(kind: type) -> Callable[..., Any]:
    """``bytes``/``bytearray`` from data, never from a size (``bytes(10**11)`` would fill memory)."""

    def build(*args: Any) -> Any:
        if args and isinstance(args[0], int):
            raise _Refused(f"{kind.__name__}() of a size")
        return kind(*args)

    return build


def _builtin_constructors() -> dict[tuple[str, str], Any]:
    import builtins
    import codecs

    table: dict[tuple[str, str], Any] = {("builtins", n): getattr(builtins, n)
                                         for n in ("set", "frozenset", "slice", "complex")}
    table[("builtins", "bytes")] = _sized_refused(bytes)
    table[("builtins", "bytearray")] = _sized_refused(bytearray)
    table[("_codecs", "encode")] = codecs.encode  # how protocols 0-2 spell bytes
    table[("collections", "OrderedDict")] = collections.OrderedDict
    table[("collections", "deque")] = collections.deque
    return table


def _constructible() -> set[Any]:
    """What a pickle of plain data may call (REDUCE) or instantiate (NEWOBJ)."""
    from stable_baselines3.common import noise, type_aliases, utils

    found: set[Any] = set(_numpy_functions().values()) | set(_builtin_constructors().values())
    found |= {utils.ConstantSchedule, utils.LinearSchedule, utils.FloatSchedule, type_aliases.TrainFreq,
              type_aliases.TrainFrequencyUnit, noise.NormalActionNoise, noise.OrnsteinUhlenbeckActionNoise,
              noise.VectorizedActionNoise}
    import numpy as np
    import numpy.random as npr

    found |= {np.ndarray, np.dtype, npr.MT19937, npr.PCG64, npr.PCG64DXSM, npr.Philox, npr.SFC64}
    return found | _PLAIN_CLASSES


def _reference_bases() -> tuple[type, ...]:
    """The kinds of class a model may name."""
    import torch
    from stable_baselines3.common.buffers import BaseBuffer
    from stable_baselines3.common.policies import BaseModel

    return (BaseModel, BaseBuffer, torch.nn.Module, torch.optim.Optimizer)


def _is_numpy_scalar_type(obj: Any) -> bool:
    import numpy as np

    return isinstance(obj, type) and issubclass(obj, np.generic)


def _is_space_class(obj: Any) -> bool:
    import gymnasium as gym

    return isinstance(obj, type) and issubclass(obj, gym.Space) and obj.__module__.startswith("gymnasium.spaces")


#: The pure-Python unpickler, whose opcode table a subclass can override (the C one's cannot be).
_PyUnpickler: Any = pickle._Unpickler  # type: ignore[attr-defined]


class PlainDataUnpickler(_PyUnpickler):  # type: ignore[misc]
    """An unpickler that builds plain data and class references only (see the module docstring).

    Opcodes that call or instantiate (``REDUCE``, ``NEWOBJ``, ``NEWOBJ_EX``) are allowed on the constructible set
    alone; ``INST``/``OBJ`` (protocols 0-1) and persistent ids are refused; ``BUILD`` only fills objects this
    unpickler made (never a class, so no class attribute can be overwritten).

    :param trusted_modules: further module prefixes whose classes may be named (the user's own packages).
    """

    dispatch: dict[int, Any] = dict(_PyUnpickler.dispatch)

    def __init__(self, data: bytes, trusted_modules: Iterable[str] = ()) -> None:
        super().__init__(io.BytesIO(data))
        self._prefixes = (*REFERENCE_PREFIXES, *trusted_modules)
        self._functions = {**_numpy_functions(), **_builtin_constructors()}
        self._calls = set(self._functions.values())
        self._constructible = _constructible()
        self._made: set[int] = set()

    # --- what a name may resolve to -------------------------------------------------------------------------
    def find_class(self, module: str, name: str) -> Any:
        if self.proto < 3 and self.fix_imports:  # Python 2 names in protocols 0-2 (``__builtin__.bytes``)
            import _compat_pickle

            module, name = _compat_pickle.NAME_MAPPING.get((module, name), (module, name))
            module = _compat_pickle.IMPORT_MAPPING.get(module, module)
        if (module, name) in self._functions:
            return self._functions[(module, name)]
        library = module == "numpy" or module.startswith(("numpy.", "gymnasium.spaces"))
        named = any(module == p or module.startswith(p + ".") for p in self._prefixes)
        if not (library or named):
            raise _Refused(f"{module}.{name}")
        try:
            obj = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as exc:
            raise _Refused(f"{module}.{name} ({exc})") from None
        if obj in self._constructible or _is_space_class(obj) or _is_numpy_scalar_type(obj):
            return obj
        if named and isinstance(obj, type) and issubclass(obj, _reference_bases()):
            return obj
        raise _Refused(f"{module}.{name} (not plain data, nor a policy, buffer, network or optimizer class)")

    def persistent_load(self, pid: Any) -> Any:
        raise _Refused("a persistent reference")

    # --- what may be called ---------------------------------------------------------------------------------
    def _check_new(self, cls: Any) -> None:
        """``NEWOBJ``: ``cls.__new__`` without ``__init__``, for the constructible classes."""
        if not (cls in self._constructible or _is_space_class(cls) or _is_numpy_scalar_type(cls)):
            raise _Refused(f"an instance of {getattr(cls, '__qualname__', type(cls).__name__)}")

    def _check_call(self, fn: Any) -> None:
        """``REDUCE``: a call with the pickle's arguments, for the plain-data helpers only (numpy's, containers,
        enums); never a class whose ``__init__`` would allocate from its arguments (a space, a buffer)."""
        if not (fn in self._calls or _is_numpy_scalar_type(fn)
                or (isinstance(fn, type) and issubclass(fn, enum.Enum) and fn in self._constructible)):
            raise _Refused(f"a call to {getattr(fn, '__qualname__', type(fn).__name__)}")

    def _remember(self, obj: Any) -> Any:
        self._made.add(id(obj))
        return obj

    def load_reduce(self) -> None:
        stack = self.stack
        args = stack.pop()
        fn = stack[-1]
        self._check_call(fn)
        stack[-1] = self._remember(fn(*args))

    def load_newobj(self) -> None:
        args = self.stack.pop()
        cls = self.stack.pop()
        self._check_new(cls)
        self.append(self._remember(cls.__new__(cls, *args)))

    def load_newobj_ex(self) -> None:
        kwargs = self.stack.pop()
        args = self.stack.pop()
        cls = self.stack.pop()
        self._check_new(cls)
        self.append(self._remember(cls.__new__(cls, *args, **kwargs)))

    def load_build(self) -> None:
        inst = self.stack[-2]  # the state is on top
        if isinstance(inst, type) or id(inst) not in self._made:
            raise _Refused(f"a state for {type(inst).__name__} {'class' if isinstance(inst, type) else 'object'}")
        super().load_build()

    def _refuse_old_opcode(self) -> None:
        raise _Refused("a protocol 0/1 object opcode")

    dispatch[pickle.REDUCE[0]] = load_reduce
    dispatch[pickle.NEWOBJ[0]] = load_newobj
    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex
    dispatch[pickle.BUILD[0]] = load_build
    dispatch[pickle.INST[0]] = _refuse_old_opcode
    dispatch[pickle.OBJ[0]] = _refuse_old_opcode


def plain_loads(data: bytes, what: str, trusted_modules: Iterable[str] = ()) -> Any:
    """Decode a pickle of plain data (:class:`PlainDataUnpickler`).

    :param what: the file and entry, for the error message.
    :raises UntrustedContentError: the pickle asks for more than plain data, or is corrupt.
    """
    try:
        return PlainDataUnpickler(data, trusted_modules).load()
    except _Refused as exc:
        raise UntrustedContentError(
            f"{what} needs {exc}: only unpickling, which can run code from the file, would build it, and sbagents "
            f"loads plain data only (pass {TRUST_FLAG} if you trust where this file came from)") from None
    except Exception as exc:  # noqa: BLE001 - only plain data is built, so any other failure means a corrupt file
        raise UsageError(f"{what} is corrupt ({type(exc).__name__}: {short_message(exc)})") from None


def short_message(exc: BaseException, limit: int = 160) -> str:
    """``exc``'s message on one line, at most ``limit`` characters."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
