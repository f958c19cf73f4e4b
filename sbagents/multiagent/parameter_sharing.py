"""Parameter sharing: PettingZoo ``ParallelEnv`` -> SB3 ``VecEnv`` (one policy drives every agent).

:class:`ParameterSharingVecEnv` replaces SuperSuit's ``pettingzoo_env_to_vec_env_v1`` +
``concat_vec_envs_v1`` and avoids its traps: time-outs carry ``TimeLimit.truncated`` (so SB3 bootstraps),
``seed()`` works, and episode statistics are team statistics counted once per team episode.
Any ``ParallelEnv`` whose agents share one observation and one action space and stay alive for the
whole episode works (wrap with SuperSuit's ``pad_*``/``black_death_v3`` otherwise).

Slot layout: ``num_envs = n_envs * n_agents``; slot ``k`` is agent ``possible_agents[k % n_agents]`` of
env ``k // n_agents``. The interface (constructor taking env factories,
:func:`make_parameter_sharing_vec_env`, :func:`evaluate_team`) is meant to stay when a batched
numpy implementation replaces the loop.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.pipeline.env_names import PETTINGZOO_ENVS  # noqa: F401  (re-exported: the CLI's multi-agent env names)


class ParameterSharingVecEnv(VecEnv):
    """All agents of ``len(env_fns)`` parallel envs as one SB3 ``VecEnv``.

    :param env_fns: zero-argument constructors of ``ParallelEnv`` instances (same agents and spaces).
    :param monitor_path: if given, an SB3 monitor CSV (``r`` team return, ``l`` length, ``t`` time,
        ``treasures``) is written there, one row per team episode.

    Observations have shape ``(n_envs * n_agents, *obs_shape)``; actions ``(n_envs * n_agents,)``.
    When an env's episode ends, every slot of that env gets ``terminal_observation`` and
    ``TimeLimit.truncated`` (True only for truncation) and the env is reset; the slot of agent 0 also
    gets ``episode = {"r": team return, "l": length, "t": seconds since start}`` and ``treasures``
    (the env's ``treasures_collected`` info when present).
    """

    def __init__(self, env_fns: Sequence[Callable[[], ParallelEnv]], monitor_path: str | None = None) -> None:
        if not env_fns:
            raise ValueError("env_fns must not be empty")
        self.envs: list[ParallelEnv] = [fn() for fn in env_fns]
        first = self.envs[0]
        self.possible_agents = list(first.possible_agents)
        self.n_agents = len(self.possible_agents)
        self.n_envs = len(self.envs)
        obs_space = first.observation_space(self.possible_agents[0])
        act_space = first.action_space(self.possible_agents[0])
        for env in self.envs:
            if list(env.possible_agents) != self.possible_agents:
                raise ValueError("all envs must have the same possible_agents")
            for agent in self.possible_agents:
                if env.observation_space(agent) != obs_space or env.action_space(agent) != act_space:
                    raise ValueError(
                        f"agent {agent} has spaces that differ from {self.possible_agents[0]}'s; "
                        "parameter sharing needs identical spaces (use supersuit pad_observations_v0)"
                    )
        super().__init__(self.n_envs * self.n_agents, obs_space, act_space)
        self._obs = np.zeros((self.num_envs, *obs_space.shape), dtype=obs_space.dtype)
        self._actions: np.ndarray = np.zeros(self.num_envs, dtype=np.int64)
        self._ep_return = np.zeros(self.n_envs, dtype=np.float64)
        self._ep_len = np.zeros(self.n_envs, dtype=np.int64)
        self._t_start = time.time()
        self._writer: ResultsWriter | None = None
        if monitor_path is not None:
            self._writer = ResultsWriter(
                monitor_path,
                header={
                    "t_start": self._t_start,
                    "env_id": str(first.metadata.get("name", type(first).__name__)),
                },
                extra_keys=("treasures",),
            )

    # ------------------------------------------------------------------ core API
    def _reset_env(self, i: int) -> list[dict[str, Any]]:
        seed, options = self._seeds[i * self.n_agents], self._options[i * self.n_agents]
        obs, infos = self.envs[i].reset(seed=seed, options=options or None)
        base = i * self.n_agents
        for j, agent in enumerate(self.possible_agents):
            self._obs[base + j] = obs[agent]
        for k in range(base, base + self.n_agents):
            self._seeds[k] = None
        self._ep_return[i] = 0.0
        self._ep_len[i] = 0
        return [dict(infos.get(agent, {})) for agent in self.possible_agents]

    def reset(self) -> VecEnvObs:
        """Reset every env (pending seeds/options are used once); returns ``(num_envs, *obs_shape)``."""
        for i in range(self.n_envs):
            infos = self._reset_env(i)
            self.reset_infos[i * self.n_agents : (i + 1) * self.n_agents] = infos
        self._reset_options()
        return self._obs.copy()

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Env ``i`` (all its agent slots) is reset with ``seed + i`` at the next :meth:`reset`."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + k // self.n_agents for k in range(self.num_envs)]
        return self._seeds

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        all_infos: list[dict[str, Any]] = []
        acts = self._actions.tolist()
        agents = self.possible_agents
        for i, env in enumerate(self.envs):
            base = i * self.n_agents
            obs, rew, term, trunc, infos = env.step({a: acts[base + j] for j, a in enumerate(agents)})
            team = 0.0
            for j, agent in enumerate(agents):
                self._obs[base + j] = obs[agent]
                rewards[base + j] = r = rew[agent]
                team += r
            self._ep_return[i] += team
            self._ep_len[i] += 1
            slot_infos = [dict(infos.get(agent, {})) for agent in agents]
            ended = [term[a] or trunc[a] for a in agents]
            if any(ended):
                if not all(ended):
                    raise RuntimeError(
                        "all agents must end together (wrap the env with supersuit black_death_v3)"
                    )
                self._finish_episode(i, slot_infos, term, trunc)
                dones[base : base + self.n_agents] = True
            all_infos.extend(slot_infos)
        return self._obs.copy(), rewards, dones, all_infos

    def _finish_episode(
        self, i: int, slot_infos: list[dict[str, Any]], term: dict[str, bool], trunc: dict[str, bool]
    ) -> None:
        base = i * self.n_agents
        for j, agent in enumerate(self.possible_agents):
            slot_infos[j]["terminal_observation"] = self._obs[base + j].copy()
            slot_infos[j]["TimeLimit.truncated"] = bool(trunc[agent] and not term[agent])
        ep: dict[str, Any] = {
            "r": round(float(self._ep_return[i]), 6),
            "l": int(self._ep_len[i]),
            "t": round(time.time() - self._t_start, 6),
        }
        slot_infos[0]["episode"] = ep
        treasures = slot_infos[0].get("treasures_collected")
        if treasures is not None:
            slot_infos[0]["treasures"] = treasures
        if self._writer is not None:
            row: dict[str, Any] = {**ep, "treasures": treasures if treasures is not None else ""}
            self._writer.write_row(row)
        self.reset_infos[base : base + self.n_agents] = self._reset_env(i)

    def close(self) -> None:
        for env in self.envs:
            env.close()
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    # ------------------------------------------------------------------ attribute access (per slot)
    def _env_indices(self, indices: VecEnvIndices) -> list[int]:
        if indices is None:
            slots: Sequence[int] = range(self.num_envs)
        elif isinstance(indices, int):
            slots = [indices]
        else:
            slots = list(indices)
        return [k // self.n_agents for k in slots]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Attribute of the env behind each slot (envs repeat once per agent)."""
        return [getattr(self.envs[i], attr_name) for i in self._env_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for i in sorted(set(self._env_indices(indices))):
            setattr(self.envs[i], attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method once per distinct env; the result is repeated for each of its slots."""
        results: dict[int, Any] = {}
        out = []
        for i in self._env_indices(indices):
            if i not in results:
                results[i] = getattr(self.envs[i], method_name)(*method_args, **method_kwargs)
            out.append(results[i])
        return out

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """Always False: the envs are PettingZoo envs, never Gymnasium wrappers (so no ``Monitor``)."""
        return [False for _ in self._env_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [env.render() if env.render_mode == "rgb_array" else None for env in self.envs]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """``human``/``ansi`` envs render themselves; ``rgb_array`` images of all envs are tiled."""
        if self.render_mode in ("human", "ansi"):
            for env in self.envs:
                env.render()
            return None
        return super().render(mode)


def make_parameter_sharing_vec_env(
    env_fn: Callable[..., ParallelEnv],
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    monitor_dir: str | None = None,
) -> VecEnv:
    """Build a :class:`ParameterSharingVecEnv` of ``n_envs`` copies of ``env_fn(**env_kwargs)``.

    :param env_fn: constructor of a ``ParallelEnv`` (e.g. ``treasure_hunt_v0.parallel_env``).
    :param n_envs: number of parallel envs (the VecEnv has ``n_envs * n_agents`` slots).
    :param seed: env ``k`` is reset with ``seed + k`` on the first reset (``None``: random).
    :param env_kwargs: keyword arguments for ``env_fn``.
    :param monitor_dir: if given, team episodes are logged to ``<monitor_dir>/0.monitor.csv``.
    """
    kwargs = dict(env_kwargs or {})
    fns = [lambda: env_fn(**kwargs) for _ in range(n_envs)]
    path = None if monitor_dir is None else os.path.join(monitor_dir, "0")
    vec = ParameterSharingVecEnv(fns, monitor_path=path)
    if seed is not None:
        vec.seed(seed)
    return vec
