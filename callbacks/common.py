"""Helpers shared by the trust callbacks: VecEnv introspection, output paths, exception hooks."""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize

from sbagents.callbacks.episodes import ACTED

#: Keys that SB3 / Gymnasium wrappers (and sbagents' team VecEnvs) put in ``info``: never treated as env data.
INTERNAL_INFO_KEYS = frozenset(
    {"terminal_observation", "episode", "TimeLimit.truncated", "final_observation", "final_info", ACTED}
)


def acted_slots(infos: Sequence[dict[str, Any]]) -> np.ndarray:
    """``(n_slots,)`` bool: which slots' actions were used this step (False: a PettingZoo agent that was absent,
    gone or not arrived yet; such a step is not one of that agent's steps)."""
    return np.array([info.get(ACTED, True) for info in infos], dtype=bool)


def find_vec_normalize(venv: VecEnv) -> VecNormalize | None:
    """The first ``VecNormalize`` in the wrapper chain of ``venv`` (outermost first), or None."""
    env: VecEnv = venv
    while True:
        if isinstance(env, VecNormalize):
            return env
        if not isinstance(env, VecEnvWrapper):
            return None
        env = env.venv


def agent_layout(venv: VecEnv) -> tuple[int, list[str] | None]:
    """``(n_agents, agent names)`` of a team VecEnv, ``(1, None)`` for a plain one.

    A team VecEnv (``sbagents.multiagent.group_env.GroupVecEnv``, e.g. a parameter-sharing one) exposes ``n_agents``
    and ``possible_agents``; slot ``k`` is agent ``k % n_agents`` of env ``k // n_agents``.
    """
    base = venv.unwrapped
    n_agents = getattr(base, "n_agents", None)
    agents = getattr(base, "possible_agents", None)
    if isinstance(n_agents, int) and n_agents >= 1 and agents is not None and len(agents) == n_agents:
        return n_agents, [str(a) for a in agents]
    return 1, None


def env_attr(venv: VecEnv, name: str) -> Any:
    """Attribute ``name`` of the first sub-env (through Gymnasium wrappers), or None if it has none."""
    try:  # has_attr first: a missing attribute kills a SubprocVecEnv worker in get_attr
        return venv.get_attr(name, [0])[0] if venv.has_attr(name) else None
    except AttributeError:
        return None


def output_dir(path: str | Path | None, logger_dir: str | None) -> Path:
    """Where a callback writes its files: ``path``, else the SB3 logger's dir, else the current dir."""
    if path is not None:
        out = Path(path)
    elif logger_dir:
        out = Path(logger_dir)
    else:
        out = Path.cwd()
    out.mkdir(parents=True, exist_ok=True)
    return out


def is_scalar(value: Any) -> bool:
    """True for values that fit one CSV cell: None, str, bool, int, float and numpy scalars / 0-d arrays."""
    if value is None or isinstance(value, (str, bool, int, float, np.generic)):
        return True
    return isinstance(value, np.ndarray) and value.ndim == 0


_HOOK_METHODS = ("collect_rollouts", "train")
_HOOKS_ATTR = "_sbagents_error_hooks"
_SHADOWED = (*_HOOK_METHODS, _HOOKS_ATTR, "_excluded_save_params")


def install_exception_hook(model: BaseAlgorithm, owner: object, on_error: Callable[[], None]) -> None:
    """Make ``on_error()`` run when an exception (including ``KeyboardInterrupt``) leaves ``model.learn``.

    SB3 does not call ``_on_training_end`` when ``learn`` raises. ``learn`` spends its time in
    ``collect_rollouts`` and ``train``; both are shadowed by instance attributes that wrap them in a
    ``try/except BaseException`` calling every registered ``on_error`` and re-raising. The shadowing
    attributes are excluded from ``model.save`` (so checkpoints taken during training stay clean) and
    removed by :func:`remove_exception_hook` (call it from ``_on_training_end``) or when they fire.
    Several owners (callbacks) can hook the same model.
    """
    hooks: dict[int, Callable[[], None]] = model.__dict__.setdefault(_HOOKS_ATTR, {})
    hooks[id(owner)] = on_error
    if "_excluded_save_params" not in model.__dict__:
        class_excluded = type(model)._excluded_save_params.__get__(model)

        def excluded() -> list[str]:
            return [*class_excluded(), *_SHADOWED]

        model.__dict__["_excluded_save_params"] = excluded
    for name in _HOOK_METHODS:
        if name in model.__dict__ or not hasattr(type(model), name):
            continue  # already hooked, or an algorithm with its own loop (tabular): episode-end flushes and exit
        original = getattr(type(model), name).__get__(model)

        def wrapper(*args: Any, _original: Callable[..., Any] = original, **kwargs: Any) -> Any:
            try:
                return _original(*args, **kwargs)
            except BaseException:
                _fire_hooks(model)
                raise

        model.__dict__[name] = functools.wraps(original)(wrapper)


def _unshadow(model: BaseAlgorithm) -> None:
    for name in _SHADOWED:
        model.__dict__.pop(name, None)


def _fire_hooks(model: BaseAlgorithm) -> None:
    hooks: dict[int, Callable[[], None]] = model.__dict__.get(_HOOKS_ATTR, {})
    _unshadow(model)
    for hook in list(hooks.values()):
        with contextlib.suppress(Exception):  # never mask the original exception
            hook()


def remove_exception_hook(model: BaseAlgorithm, owner: object) -> None:
    """Undo :func:`install_exception_hook` for ``owner`` (the wrappers go when no owner is left)."""
    hooks: dict[int, Callable[[], None]] = model.__dict__.get(_HOOKS_ATTR, {})
    hooks.pop(id(owner), None)
    if not hooks:
        _unshadow(model)


def split_keys(keys: str | Sequence[str]) -> list[str]:
    """``"a,b"`` or ``["a", "b"]`` -> ``["a", "b"]`` (blank entries dropped)."""
    items = keys.split(",") if isinstance(keys, str) else list(keys)
    return [k.strip() for k in items if k and k.strip()]


class PeriodicEvalCallback(BaseCallback):
    """Base of the evaluation callbacks: call :meth:`evaluate` every ``eval_freq`` calls and, with
    ``eval_at_end``, once more when training ends unless it just ran."""

    def __init__(self, eval_freq: int, eval_at_end: bool = True, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.eval_freq, self.eval_at_end = eval_freq, eval_at_end
        self._last_eval_step = -1

    def evaluate(self) -> Any:
        """Run one evaluation; subclasses set ``self._last_eval_step = self.num_timesteps``."""
        raise NotImplementedError

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        if self.eval_at_end and self._last_eval_step != self.num_timesteps:
            self.evaluate()
