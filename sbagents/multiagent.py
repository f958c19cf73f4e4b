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
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.env_ids import PETTINGZOO_ENVS  # noqa: F401  (re-exported: the CLI's multi-agent env names)


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


def evaluate_team(
    model: Any,
    env_fn: Callable[[], ParallelEnv],
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = None,
    render: bool = False,
    vec_normalize: VecNormalize | None = None,
) -> dict[str, Any]:
    """Run ``n_episodes`` team episodes (one env, sequentially) with a parameter-shared policy.

    :param model: anything with SB3's ``predict(obs, deterministic=...)``.
    :param env_fn: zero-argument constructor of the ``ParallelEnv``.
    :param seed: seed of the first reset (then the env's RNG continues) -> reproducible returns.
    :param render: call the env's ``render()`` every step (create it with a ``render_mode``).
    :param vec_normalize: if given, observations are normalized with its (frozen) statistics.
    :return: ``n_episodes``, ``mean_return``/``std_return`` (team return = sum over agents),
        ``mean_length``, ``success_rate`` (share of episodes with ``is_success``) and
        ``metrics`` = ``{"treasures_per_episode", "team_return"}`` (NaN treasures if the env reports none).
    """
    ep = _run_team_episodes(model, env_fn, n_episodes, deterministic, seed, render, vec_normalize)
    return _summary(ep)


def _run_team_episodes(
    model: Any,
    env_fn: Callable[[], ParallelEnv],
    n_episodes: int,
    deterministic: bool,
    seed: int | None,
    render: bool,
    vec_normalize: VecNormalize | None,
) -> dict[str, list[Any]]:
    """Per-episode ``returns``, ``lengths``, ``successes``, ``treasures`` (see :func:`evaluate_team`)."""
    vec = ParameterSharingVecEnv([env_fn])
    if seed is not None:
        vec.seed(seed)
    ep: dict[str, list[Any]] = {"returns": [], "lengths": [], "successes": [], "treasures": []}
    obs: Any = vec.reset()
    try:
        while len(ep["returns"]) < n_episodes:
            if vec_normalize is not None:
                obs = vec_normalize.normalize_obs(obs)
            actions, _ = model.predict(obs, deterministic=deterministic)
            obs, _, dones, infos = vec.step(actions)
            if render:
                vec.envs[0].render()
            if dones[0]:
                info = infos[0]
                ep["returns"].append(float(info["episode"]["r"]))
                ep["lengths"].append(int(info["episode"]["l"]))
                ep["successes"].append(bool(info.get("is_success", False)))
                ep["treasures"].append(float(info.get("treasures", np.nan)))
    finally:
        vec.close()
    return ep


def _summary(ep: dict[str, list[Any]]) -> dict[str, Any]:
    returns = ep["returns"]
    return {
        "n_episodes": len(returns),
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(ep["lengths"])),
        "success_rate": float(np.mean(ep["successes"])),
        "metrics": {
            "treasures_per_episode": float(np.mean(ep["treasures"])),
            "team_return": float(np.mean(returns)),
        },
    }


class TeamEvalCallback(EvalCallback):
    """``EvalCallback`` that scores the team with :func:`evaluate_team` every ``eval_freq`` calls.

    Keeps ``best_model.zip`` (highest mean team return) in ``best_model_save_path`` and writes
    ``evaluations.npz`` in EvalCallback's format (``timesteps``, ``results`` team returns of shape
    ``(n_evals, n_eval_episodes)``, ``ep_lengths``, ``successes``) to ``log_path``. Logs ``eval/mean_reward``,
    ``eval/mean_ep_length``, ``eval/success_rate`` and ``eval/treasures_per_episode``.

    :param env_fn: zero-argument constructor of the evaluation ``ParallelEnv``.
    :param eval_freq: evaluate every ``eval_freq`` calls of ``_on_step`` (i.e. vec steps, not env steps).
    :param seed: seed of each evaluation (the same episodes every time; ``None``: fresh ones).
    """

    def __init__(
        self,
        env_fn: Callable[[], ParallelEnv],
        n_eval_episodes: int = 5,
        eval_freq: int = 10000,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        deterministic: bool = True,
        seed: int | None = None,
        callback_on_new_best: Any = None,
        callback_after_eval: Any = None,
        verbose: int = 1,
    ) -> None:
        super().__init__(
            ParameterSharingVecEnv([env_fn]),
            callback_on_new_best=callback_on_new_best,
            callback_after_eval=callback_after_eval,
            n_eval_episodes=n_eval_episodes,
            eval_freq=eval_freq,
            log_path=log_path,
            best_model_save_path=best_model_save_path,
            deterministic=deterministic,
            verbose=verbose,
            warn=False,
        )
        self.env_fn = env_fn
        self.eval_seed = seed
        self.last_result: dict[str, Any] = {}
        self._returns: list[list[float]] = []

    def _init_callback(self) -> None:
        with warnings.catch_warnings():  # the eval env is the reference VecEnv; the training one may be batched
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
            super()._init_callback()

    def _on_step(self) -> bool:
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        vec_norm = self.model.get_vec_normalize_env()
        result = _run_team_episodes(
            self.model, self.env_fn, self.n_eval_episodes, self.deterministic, self.eval_seed, False, vec_norm
        )
        self.last_result = _summary(result)
        self.evaluations_timesteps.append(self.num_timesteps)
        self.evaluations_results.append(result["returns"])
        self.evaluations_length.append(result["lengths"])
        self._is_success_buffer = list(result["successes"])
        self.evaluations_successes.append(self._is_success_buffer)
        if self.log_path is not None:
            np.savez(
                self.log_path,
                timesteps=self.evaluations_timesteps,
                results=self.evaluations_results,
                ep_lengths=self.evaluations_length,
                successes=self.evaluations_successes,
            )
        mean_reward = float(self.last_result["mean_return"])
        self.last_mean_reward = mean_reward
        self.logger.record("eval/mean_reward", mean_reward)
        self.logger.record("eval/mean_ep_length", float(self.last_result["mean_length"]))
        self.logger.record("eval/success_rate", float(self.last_result["success_rate"]))
        self.logger.record("eval/treasures_per_episode", self.last_result["metrics"]["treasures_per_episode"])
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(self.num_timesteps)
        if self.verbose >= 1:
            print(
                f"Eval num_timesteps={self.num_timesteps}, team return={mean_reward:.2f}, "
                f"treasures={self.last_result['metrics']['treasures_per_episode']:.2f}"
            )
        continue_training = True
        if mean_reward > self.best_mean_reward:
            self.best_mean_reward = mean_reward
            if self.best_model_save_path is not None:
                self.model.save(os.path.join(self.best_model_save_path, "best_model"))
            if self.callback_on_new_best is not None:
                continue_training = self.callback_on_new_best.on_step()
        if self.callback is not None:
            continue_training = continue_training and self._on_event()
        return continue_training
