"""Resolving an import path that came from a file, checked *before* anything is imported.

Importing a module runs its top-level code: ``numpy.f2py.__main__`` runs f2py's command line, a ``conftest`` or a
test module runs fixtures. So a name from a config, a run dir or a model file is checked first and then found
without importing anything of the file's choosing:

- every component must be a plain identifier that does not start with an underscore-underscore (``__main__``,
  ``__init__``) and is not a test or build module (``conftest``, ``tests``, ``testing``, ``setup``);
- the module must lie inside an allowed or a trusted package (the caller says which);
- for an allowed (not user-named) package, the object is found by attribute access from the top-level package (which
  sbagents imports itself) and from modules already imported; the only modules imported on the way are sbagents' own
  (whose import runs no code of consequence) and the fixed list in :data:`IMPORTABLE_MODULES`;
- a module the user named on the command line (``--gym-packages``, ``--env my_pkg...``) is trusted: naming it is
  vouching for it, and its submodules may be imported.

Only the standard library is imported here.
"""

from __future__ import annotations

import importlib
import keyword
import sys
from collections.abc import Iterable
from types import ModuleType
from typing import Any

from sbagents.errors import UsageError

#: Module names never imported from a path a file gave, even inside an allowed or trusted package.
REFUSED_COMPONENTS: frozenset[str] = frozenset({"conftest", "tests", "testing", "setup", "distutils", "f2py"})

#: Modules of allowed packages that are imported on request although nothing has imported them yet (their import
#: only defines classes).
IMPORTABLE_MODULES: frozenset[str] = frozenset({
    "stable_baselines3.common.atari_wrappers",
    "stable_baselines3.common.sb2_compat.rmsprop_tf_like",
    "stable_baselines3.common.torch_layers",
    "stable_baselines3.common.vec_env",
    "stable_baselines3.common.buffers",
    "stable_baselines3.her.her_replay_buffer",
    "gymnasium.wrappers",
    "torch.nn",
    "torch.optim",
})

#: Packages whose own modules may be imported by a path from a file (sbagents' modules define, they do not act).
OWN_PACKAGES: tuple[str, ...] = ("sbagents",)


def within(module: str, prefixes: Iterable[str]) -> bool:
    """Whether ``module`` is one of ``prefixes`` or inside one of them."""
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def split_path(path: str, what: str = "object") -> tuple[str, str]:
    """``package.module.Name`` or ``package.module:Name`` -> ``(module, qualified attribute)``, every component
    checked (identifiers only, no dunder names, no test or build modules).

    :raises UsageError: a malformed or refused path.
    """
    module, sep, attr = path.partition(":")
    if not sep:
        module, _, attr = path.rpartition(".")
    if not module or not attr:
        raise UsageError(f"{what} {path!r:.120} must be an import path like 'package.module.Name'")
    for part in (*module.split("."), *attr.split(".")):
        if not part.isidentifier() or keyword.iskeyword(part):
            raise UsageError(f"{what} {path!r:.120} is not an import path (bad component {part!r:.40})")
        if part.startswith("__") or part in REFUSED_COMPONENTS:
            raise UsageError(f"{what} {path!r:.120} names {part!r}, which sbagents never imports from a path a file "
                             "gives (importing it would run code)")
    return module, attr


def _find_module(module: str, trusted: bool) -> ModuleType | None:
    """The module ``module``, imported only when that is allowed (see the module docstring); None if it cannot be
    reached without importing something else."""
    if module in sys.modules:
        return sys.modules[module]
    if trusted or module in IMPORTABLE_MODULES or within(module, OWN_PACKAGES):
        return importlib.import_module(module)
    top, _, rest = module.partition(".")
    found: Any = importlib.import_module(top) if top in sys.modules or within(top, IMPORTABLE_MODULES) else None
    if found is None:
        found = sys.modules.get(top)
    for part in rest.split(".") if rest else ():
        found = getattr(found, part, None)
        if not isinstance(found, ModuleType):
            return None
    return found if isinstance(found, ModuleType) else None


def resolve_path(path: str, what: str, allowed: Iterable[str], trusted: Iterable[str] = ()) -> tuple[Any, bool]:
    """The object an import path from a file names, and whether it came from a trusted (user-named) module.

    :param allowed: packages whose objects may be named without the user vouching (the caller checks the kind).
    :param trusted: modules the user named on the command line.
    :raises UsageError: one line: malformed, outside both lists, or not reachable without importing other modules.
    """
    module, attr = split_path(path, what)
    allowed, trusted = tuple(allowed), tuple(trusted)
    is_trusted = within(module, trusted)
    if not is_trusted and not within(module, allowed):
        raise UsageError(
            f"{what} {path!r:.120} is outside the import allow-list ({', '.join(allowed)}): a config may not import "
            f"code from elsewhere; if {module.split('.')[0]!r} is your own package, name it with --gym-packages to "
            "trust it")
    try:
        found = _find_module(module, is_trusted)
    except ImportError as exc:
        raise UsageError(f"cannot import {what} {path!r:.120}: {exc}") from None
    if found is None:
        raise UsageError(f"{what} {path!r:.120}: module {module!r} is not loaded by its package, and sbagents imports "
                         "no other module a file names; name it with --gym-packages if you trust it")
    obj: Any = found
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise UsageError(f"cannot import {what} {path!r:.120}: {module!r} has no {attr!r}") from None
        if isinstance(obj, ModuleType):
            raise UsageError(f"{what} {path!r:.120} names a module, not a class or function")
    return obj, is_trusted
