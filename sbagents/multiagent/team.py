"""``n_envs`` copies of a PettingZoo ``ParallelEnv`` stepped together, as per-agent slot arrays: :class:`Team`.

Slot ``(i, agent)`` is ``agent`` in copy ``i``. A slot is *active* while its agent is in ``env.agents``. Each step
gives, per agent, arrays of shape ``(n_envs, ...)``:

- ``obs``: the observation after the step (zeros while the agent is absent); after an auto-reset, the new
  episode's first observation.
- ``rewards``, ``dones``: ``done`` when the agent's episode ended this step (terminated, truncated or left), and
  also when an absent agent appears (arrives, or is back after a reset): its next observation starts an episode.
- ``infos``: the env's info of the agent, plus ``terminal_observation`` and ``TimeLimit.truncated`` for done slots
  and ``sbagents_acted: False`` for slots whose action was not used (the agent was absent). Learning code drops
  those transitions (:mod:`sbagents.multiagent.masking`): an absent agent gets no fake learning signal.

:class:`Team` also writes the team monitor CSV (one row per team episode: ``r`` team return, ``l``, ``t`` and the
env's declared metrics) and keeps the per-episode statistics that views turn into SB3's ``episode`` infos.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3.common.monitor import ResultsWriter

from sbagents.callbacks.episodes import ACTED  # the info-key contract (re-exported)
from sbagents.multiagent.copies import LocalCopies, SubprocCopies
from sbagents.multiagent.env_copy import CopyStep, declared_metrics


@dataclass
class TeamStep:
    """One step of a :class:`Team`, by agent (arrays of shape ``(n_envs, ...)``).

    ``episodes[i]``: copy ``i``'s finished episode statistics (see :class:`~sbagents.multiagent.env_copy.CopyStep`)
    or None; ``states``: the state of the observations returned (after auto-resets); ``terminal_states``: the
    state right after the step, before an auto-reset (for terminal observations).
    """

    obs: dict[str, np.ndarray]
    rewards: dict[str, np.ndarray]
    dones: dict[str, np.ndarray]
    infos: dict[str, list[dict[str, Any]]]
    episodes: list[dict[str, Any] | None]
    states: np.ndarray | None = None
    terminal_states: np.ndarray | None = None


class Team:
    """The copies and their slot arrays.

    :param env_fns: one zero-argument ``ParallelEnv`` constructor per copy.
    :param monitor_path: if given, an SB3 monitor file (``<path>.monitor.csv``) with one row per team episode.
    :param subproc: run the copies in worker processes (the constructors must be picklable).
    :param with_state: also collect ``env.state()`` (shape ``(n_envs, *state_shape)``) for centralized critics.
    """

    def __init__(
        self, env_fns: Sequence[Callable[[], ParallelEnv]], monitor_path: str | None = None, subproc: bool = False,
        with_state: bool = False,
    ) -> None:
        if not env_fns:
            raise ValueError("env_fns must not be empty")
        probe = env_fns[0]()
        self.possible_agents = [str(a) for a in probe.possible_agents]
        self.observation_spaces = {a: probe.observation_space(a) for a in self.possible_agents}
        self.action_spaces = {a: probe.action_space(a) for a in self.possible_agents}
        self.metadata = dict(getattr(probe, "metadata", {}) or {})
        self.render_mode = getattr(probe, "render_mode", None)
        self.state_space: spaces.Space[Any] | None = None
        if with_state:
            state_space = getattr(probe, "state_space", None)
            probe.reset(seed=0)
            state = probe.state()  # raises NotImplementedError (or AttributeError) for an env without one
            self.state_space = state_space or spaces.Box(-np.inf, np.inf, np.shape(state), np.float32)
        probe.close()
        self.n_envs = len(env_fns)
        self.copies = SubprocCopies(env_fns, with_state) if subproc else LocalCopies(env_fns, with_state)
        self.metric_keys = list(declared_metrics(self.metadata))
        self._obs = {a: np.zeros((self.n_envs, *self._shape(a)), dtype=self._dtype(a)) for a in self.possible_agents}
        self._present = {a: np.zeros(self.n_envs, dtype=bool) for a in self.possible_agents}
        self._states = None if self.state_space is None else np.zeros((self.n_envs, *self.state_space.shape),
                                                                        dtype=np.float32)
        self._seeds: list[int | None] = [None] * self.n_envs
        self._options: list[Mapping[str, Any] | None] = [None] * self.n_envs
        self._t_start = time.time()
        self._writer: ResultsWriter | None = None
        if monitor_path is not None:
            header: dict[str, float | str] = {"t_start": self._t_start,
                                              "env_id": str(self.metadata.get("name", "team"))}
            self._writer = ResultsWriter(monitor_path, header=header, extra_keys=tuple(self.metric_keys))

    def _shape(self, agent: str) -> tuple[int, ...]:
        return tuple(self.observation_spaces[agent].shape or ())

    def _dtype(self, agent: str) -> Any:
        return self.observation_spaces[agent].dtype or np.float32

    # ------------------------------------------------------------------ seeding and reset
    def seed(self, seed: int | None) -> list[int | None]:
        """Copy ``i`` is reset with ``seed + i`` at the next :meth:`reset` (a random base seed when None)."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + i for i in range(self.n_envs)]
        return list(self._seeds)

    def set_options(self, options: Sequence[Mapping[str, Any] | None]) -> None:
        """Reset options per copy, used once at the next :meth:`reset`."""
        self._options = list(options)

    def reset(self) -> tuple[dict[str, np.ndarray], dict[str, list[dict[str, Any]]]]:
        """Reset every copy (pending seeds and options are used once); observations and infos by agent."""
        infos: dict[str, list[dict[str, Any]]] = {a: [{} for _ in range(self.n_envs)] for a in self.possible_agents}
        for i in range(self.n_envs):
            obs, env_infos, state = self.copies.reset(i, self._seeds[i], self._options[i])
            self._place(i, obs, state)
            for agent, info in env_infos.items():
                infos[agent][i] = info
        self._seeds = [None] * self.n_envs
        self._options = [None] * self.n_envs
        return {a: o.copy() for a, o in self._obs.items()}, infos

    def _place(self, i: int, obs: Mapping[str, Any], state: np.ndarray | None) -> None:
        for agent in self.possible_agents:
            present = agent in obs
            self._present[agent][i] = present
            if present:
                self._obs[agent][i] = obs[agent]
            else:
                self._obs[agent][i] = 0
        if self._states is not None and state is not None:
            self._states[i] = state

    # ------------------------------------------------------------------ stepping
    def step(self, actions: Mapping[str, np.ndarray]) -> TeamStep:
        """Step every copy with ``actions[agent][i]`` for the agents present; auto-reset finished copies."""
        per_copy = [{a: actions[a][i] for a in self.possible_agents if self._present[a][i]}
                    for i in range(self.n_envs)]
        results = self.copies.step(per_copy)
        rewards = {a: np.zeros(self.n_envs, dtype=np.float32) for a in self.possible_agents}
        dones = {a: np.zeros(self.n_envs, dtype=bool) for a in self.possible_agents}
        infos: dict[str, list[dict[str, Any]]] = {a: [] for a in self.possible_agents}
        episodes: list[dict[str, Any] | None] = []
        terminal_states = None if self._states is None else self._states.copy()
        for i, res in enumerate(results):
            for agent in self.possible_agents:
                infos[agent].append(self._slot_info(i, agent, res, rewards, dones))
            if terminal_states is not None and res.state is not None:
                terminal_states[i] = res.state
            self._place(i, res.obs, res.reset_state if res.episode is not None else res.state)
            if res.episode is not None:
                res.episode["t"] = round(time.time() - self._t_start, 6)  # the team's clock, as Monitor's
            episodes.append(res.episode)
            if res.episode is not None and self._writer is not None:
                self._writer.write_row({k: res.episode[k] for k in ("r", "l", "t", *self.metric_keys)})
        return TeamStep({a: o.copy() for a, o in self._obs.items()}, rewards, dones, infos, episodes, self.states,
                        terminal_states)

    def _slot_info(self, i: int, agent: str, res: CopyStep, rewards: dict[str, np.ndarray],
                   dones: dict[str, np.ndarray]) -> dict[str, Any]:
        acted = agent in res.acted
        info = dict(res.infos.get(agent, {}))
        if acted:
            rewards[agent][i] = res.rewards.get(agent, 0.0)
        else:
            info[ACTED] = False
        ended = agent in res.done if acted else agent in res.obs  # appears: starts an episode
        if ended:
            dones[agent][i] = True
            terminal = res.terminal_obs.get(agent) if acted else None
            info["terminal_observation"] = (np.asarray(terminal) if terminal is not None
                                            else np.zeros(self._shape(agent), dtype=self._dtype(agent)))
            info["TimeLimit.truncated"] = agent in res.truncated
        return info

    @property
    def present(self) -> dict[str, np.ndarray]:
        """Which agents are present in which copy, ``(n_envs,)`` bool per agent (after the last step/reset)."""
        return {a: p.copy() for a, p in self._present.items()}

    @property
    def states(self) -> np.ndarray | None:
        """The current ``env.state()`` of every copy, ``(n_envs, *state_shape)`` (None without ``with_state``)."""
        return None if self._states is None else self._states.copy()

    def call(self, index: int, name: str, *args: Any, **kwargs: Any) -> Any:
        """An attribute or method of copy ``index``'s env."""
        return self.copies.call(index, name, *args, **kwargs)

    def set_attr(self, index: int, name: str, value: Any) -> None:
        """Set an attribute of copy ``index``'s env."""
        self.copies.set(index, name, value)

    def close(self) -> None:
        """Close the copies and the monitor file."""
        self.copies.close()
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def monitor_path(monitor_dir: str | None, name: str = "0") -> str | None:
    """``<monitor_dir>/<name>`` (SB3 appends ``.monitor.csv``), or None."""
    return None if monitor_dir is None else os.path.join(monitor_dir, name)
