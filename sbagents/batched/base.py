"""Shared machinery of the batched (numpy-array) vector envs: attribute access, rendering, monitor files.

A batched VecEnv keeps the state of all its env copies in arrays and steps them with array operations.
For everything that is not stepping (``get_attr``, ``env_method``, rendering) it keeps one *template*
instance of the reference environment and copies env ``i``'s state into it before the call
(:meth:`BatchedVecEnv._sync`), so attributes such as ``obs_names``, ``action_names``, methods such as
``grid_text()`` and the reference renderers behave as on the reference VecEnvs.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices

#: Methods that would change the template's state without writing it back to the arrays.
_STATEFUL_METHODS = frozenset({"reset", "step", "close"})


class BatchedVecEnv(VecEnv):
    """Base class: ``num_envs`` slots backed by ``n_envs`` array-stepped env copies.

    :param num_envs: number of VecEnv slots (``n_envs * slots_per_env``).
    :param slots_per_env: slots per env copy (1, or the number of agents for parameter sharing).
    :param template: a reference env instance (for attributes, methods and rendering).
    :param observation_space: per-slot observation space.
    :param action_space: per-slot action space.
    """

    def __init__(
        self,
        num_envs: int,
        slots_per_env: int,
        template: Any,
        observation_space: spaces.Space,
        action_space: spaces.Space,
    ) -> None:
        self.template = template
        self.slots_per_env = slots_per_env
        self.n_envs = num_envs // slots_per_env
        self._t_start = time.time()
        self._actions: np.ndarray = np.zeros(num_envs, dtype=np.int64)
        self._action_shape = (num_envs,)
        super().__init__(num_envs, observation_space, action_space)

    # ------------------------------------------------------------------ to implement
    def _sync(self, env_index: int) -> None:
        """Copy env ``env_index``'s state from the arrays into :attr:`template`."""
        raise NotImplementedError

    # ------------------------------------------------------------------ VecEnv API
    def step_async(self, actions: np.ndarray) -> None:
        """Store the actions, shape ``(num_envs,)`` (any integer array of that size)."""
        acts = actions if type(actions) is np.ndarray else np.asarray(actions)
        if acts.dtype != np.int64 or acts.shape != self._action_shape:
            acts = acts.reshape(self.num_envs).astype(np.int64)  # reshape checks the size
        self._actions = acts

    def _raise_invalid_action(self, slot: int, n_actions: int) -> None:
        raise ValueError(
            f"actions must be ints in 0..{n_actions - 1}, got {self._actions[slot]} in slot {slot}"
        )

    def _checked_actions(self, started: bool, n_actions: int) -> np.ndarray:
        """The stored actions, after checking that the VecEnv was reset and every action is in ``0..n_actions-1``.

        :raises RuntimeError: not reset yet. :raises ValueError: an action out of range (naming its slot).
        """
        acts = self._actions
        if not started:
            raise RuntimeError("reset() the VecEnv before stepping it")
        if acts.min() < 0 or acts.max() >= n_actions:
            self._raise_invalid_action(int(np.flatnonzero((acts < 0) | (acts >= n_actions))[0]), n_actions)
        return acts

    def _monitor_seconds(self) -> float:
        """SB3 Monitor's ``episode["t"]``: seconds since creation, rounded as Monitor rounds them."""
        return round(time.time() - self._t_start, 6)

    def _env_indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            slots: Sequence[int] = range(self.num_envs)
        elif isinstance(indices, (int, np.integer)):
            slots = [int(indices)]
        else:
            slots = list(indices)
        return [int(k) // self.slots_per_env for k in slots]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attribute of the env behind each slot (its state is copied into the template first)."""
        out = []
        for i in self._env_indices(indices):
            self._sync(i)
            out.append(getattr(self.template, attr_name))
        return out

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Not supported: the env copies live in shared arrays, not in per-env objects."""
        raise NotImplementedError(
            f"{type(self).__name__} cannot set {attr_name!r}: env copies are stored as arrays; "
            "pass settings as env kwargs instead"
        )

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a read-only method on (a copy of) the env behind each slot; changes are not kept.

        ``reset``, ``step`` and ``close`` are refused (use the VecEnv's own methods).
        """
        if method_name in _STATEFUL_METHODS:
            raise NotImplementedError(
                f"env_method({method_name!r}) is not supported by {type(self).__name__}; "
                "use the VecEnv's own methods"
            )
        results: dict[int, Any] = {}
        out = []
        for i in self._env_indices(indices):
            if i not in results:
                self._sync(i)
                results[i] = getattr(self.template, method_name)(*method_args, **method_kwargs)
            out.append(results[i])
        return out

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One ``rgb_array`` frame per env copy (None unless ``render_mode="rgb_array"``)."""
        images: list[np.ndarray | None] = []
        for i in range(self.n_envs):
            if self.render_mode != "rgb_array":
                images.append(None)
                continue
            self._sync(i)
            images.append(self.template.render())
        return images


class BatchedTeamVecEnv(BatchedVecEnv):
    """Base class of the parameter-sharing team VecEnvs: ``n_envs`` copies of a PettingZoo env, slot ``k`` is agent
    ``k % slots_per_env`` of copy ``k // slots_per_env``, team episodes go to one SB3 monitor file, as on the
    reference team VecEnv.

    :param monitor_path: the monitor file (``<path>.monitor.csv``; None: none), its header naming ``env_name``
        and its columns ``r, l, t`` plus ``extra_keys``.
    """

    def __init__(
        self,
        num_envs: int,
        slots_per_env: int,
        template: Any,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        monitor_path: str | None,
        env_name: str,
        extra_keys: tuple[str, ...] = (),
    ) -> None:
        super().__init__(num_envs, slots_per_env, template, observation_space, action_space)
        self._writer: ResultsWriter | None = None
        if monitor_path is not None:
            header: dict[str, float | str] = {"t_start": self._t_start, "env_id": env_name}
            self._writer = ResultsWriter(monitor_path, header=header, extra_keys=extra_keys)

    def seed(self, seed: int | None = None) -> list[int | None]:  # type: ignore[override]
        """Copy ``i`` (all its slots) is reset with ``seed + i`` at the next reset (a random base seed when None,
        drawn as the reference draws it)."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + k // self.slots_per_env for k in range(self.num_envs)]
        return list(self._seeds)

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """Always False, as the reference (PettingZoo envs are never Gymnasium wrappers)."""
        return [False for _ in self._env_indices(indices)]

    def close(self) -> None:
        """Close the monitor file and the template env."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self.template.close()


def unreproduced_kwargs(env_kwargs: Mapping[str, Any], reproduced: Mapping[str, Callable[[Any], bool]]
                        ) -> list[str]:
    """The env kwargs whose values a batched env does not reproduce, as ``key=value`` (empty: batchable).

    :param reproduced: kwarg -> whether the batched env reproduces a value of it; kwargs not listed take any value.
        Unknown keys and invalid values are left to the env's constructor (it raises as the reference does).
    """
    return [f"{key}={value!r}" for key, value in env_kwargs.items()
            if key in reproduced and not reproduced[key](value)]


def check_batchable(n_envs: int, problems: list[str], env_id: str, support: str) -> None:
    """Refuse ``n_envs < 1`` and kwargs a batched env does not reproduce (``problems``, naming what it supports).

    :raises ValueError: either.
    """
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if problems:
        raise ValueError(f"no batched {env_id} for {', '.join(problems)}; supported: {support}")


def monitor_writer(monitor_dir: str | None, index: int, env_id: str, t_start: float,
                   extra_keys: tuple[str, ...] = ()) -> ResultsWriter | None:
    """SB3 monitor file ``<monitor_dir>/<index>.monitor.csv`` (None when ``monitor_dir`` is None)."""
    if monitor_dir is None:
        return None
    os.makedirs(monitor_dir, exist_ok=True)
    return ResultsWriter(
        os.path.join(monitor_dir, str(index)),
        header={"t_start": t_start, "env_id": env_id},
        extra_keys=extra_keys,
    )
