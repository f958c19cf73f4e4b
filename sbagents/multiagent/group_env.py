"""One group of a team's agents as an SB3 ``VecEnv``: :class:`GroupVecEnv`, and how the group's observations are
laid out (:class:`ObsLayout`).

Slot layout: ``num_envs = n_envs * n_agents``; slot ``k`` is agent ``agents[k % n_agents]`` of copy
``k // n_agents``. At the end of a team episode the group's first slot of that copy gets SB3's
``episode = {"r": group return, "l": length, "t": seconds, **declared metrics}`` (once per team episode, however
many agents the group has).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sbagents.errors import UsageError
from sbagents.multiagent.joint import JointStepper
from sbagents.multiagent.team import TeamStep


class LayoutError(UsageError):
    """A group whose agents' spaces cannot share one policy in the asked layout (the message names the fix)."""


@dataclass
class ObsLayout:
    """How the observations of a group's agents become one observation space.

    :param agents: the group's agents.
    :param spaces_by_agent: each agent's observation space.
    :param agent_id: append a one-hot of the agent's index in the group (parameter sharing that tells agents
        apart).
    :param state_space: when given, the observation is ``Dict(obs=..., state=Box)``: the env's global state plus the
        agent one-hot, for a centralized critic (:mod:`sbagents.multiagent.centralized`).

    Agents with different Box observation spaces are flattened, zero-padded to the longest and marked with a
    one-hot of their space ("agent type"); any other difference is a :class:`LayoutError`.
    """

    agents: list[str]
    spaces_by_agent: dict[str, spaces.Space[Any]]
    agent_id: bool = False
    state_space: spaces.Space[Any] | None = None

    def __post_init__(self) -> None:
        first = self.spaces_by_agent[self.agents[0]]
        distinct: list[spaces.Space[Any]] = []
        for agent in self.agents:
            if not any(self.spaces_by_agent[agent] == s for s in distinct):
                distinct.append(self.spaces_by_agent[agent])
        self.types = [next(i for i, s in enumerate(distinct) if s == self.spaces_by_agent[a]) for a in self.agents]
        self.padded = len(distinct) > 1
        flat = self.padded or self.agent_id
        if flat and not all(isinstance(s, spaces.Box) and len(s.shape) <= 2 for s in distinct):
            why = "differ" if self.padded else "are not vectors, so an agent id cannot be appended"
            raise LayoutError(f"the observation spaces of {', '.join(self.agents)} {why}; use policies: per_group "
                              "or per_agent (one model per kind of agent)" + ("" if self.padded else
                                                                               ", or agent_id: false"))
        self.width = max(int(np.prod(s.shape or ())) for s in distinct) if flat else 0
        self.extra = (len(distinct) if self.padded else 0) + (len(self.agents) if self.agent_id else 0)
        self.agent_space: spaces.Space[Any] = first
        if flat:
            self.agent_space = spaces.Box(-np.inf, np.inf, (self.width + self.extra,), np.float32)
        self.space: spaces.Space[Any] = self.agent_space
        if self.state_space is not None:
            state_dim = int(np.prod(self.state_space.shape or ())) + len(self.agents)
            self.space = spaces.Dict({"obs": self.agent_space,
                                      "state": spaces.Box(-np.inf, np.inf, (state_dim,), np.float32)})

    def agent_obs(self, j: int, obs: np.ndarray) -> np.ndarray:
        """Agent ``agents[j]``'s observations ``(n_envs, ...)`` in the layout's agent space."""
        if not self.width:
            return obs
        n = len(obs)
        out = np.zeros((n, self.width + self.extra), dtype=np.float32)
        flat = obs.reshape(n, -1)
        out[:, : flat.shape[1]] = flat
        if self.padded:
            out[:, self.width + self.types[j]] = 1.0
        if self.agent_id:
            out[:, self.width + self.extra - len(self.agents) + j] = 1.0
        return out

    def state_obs(self, j: int, states: np.ndarray) -> np.ndarray:
        """The critic's input for agent ``agents[j]``: the flat states ``(n_envs, state_dim)`` plus its one-hot."""
        n = len(states)
        onehot = np.zeros((n, len(self.agents)), dtype=np.float32)
        onehot[:, j] = 1.0
        return np.concatenate([states.reshape(n, -1).astype(np.float32), onehot], axis=1)


class GroupVecEnv(VecEnv):
    """The slots of one group of a :class:`~sbagents.multiagent.joint.JointStepper`'s team.

    :param joint: the team's coordinator.
    :param group: this group's name in ``joint.groups``.
    :param layout: the observation layout of the group.
    :raises LayoutError: the group's agents act in different action spaces.
    """

    def __init__(self, joint: JointStepper, group: str, layout: ObsLayout) -> None:
        self.joint, self.group, self.layout = joint, group, layout
        team = joint.team
        self.possible_agents = list(joint.groups[group])
        self.n_agents = len(self.possible_agents)
        self.n_envs = team.n_envs
        act_space = team.action_spaces[self.possible_agents[0]]
        if any(team.action_spaces[a] != act_space for a in self.possible_agents):
            raise LayoutError(f"the action spaces of {', '.join(self.possible_agents)} differ; use policies: "
                              "per_group or per_agent (one model per kind of agent)")
        self.render_mode = team.render_mode
        self.metadata = team.metadata
        super().__init__(self.n_envs * self.n_agents, layout.space, act_space)
        self._actions = np.zeros(self.num_envs)

    # ------------------------------------------------------------------ assembling slot arrays
    def _slots(self, by_agent: dict[str, np.ndarray], states: np.ndarray | None) -> VecEnvObs:
        obs = self._stack([self.layout.agent_obs(j, by_agent[a]) for j, a in enumerate(self.possible_agents)])
        if states is None or self.layout.state_space is None:
            return obs
        state = self._stack([self.layout.state_obs(j, states) for j in range(self.n_agents)])
        return {"obs": obs, "state": state}

    def _stack(self, per_agent: list[np.ndarray]) -> np.ndarray:
        """``[agent j: (n_envs, ...)]`` -> slot array ``(n_envs * n_agents, ...)`` in the slot layout."""
        stacked = np.stack(per_agent, axis=1)
        return stacked.reshape((self.num_envs, *stacked.shape[2:]))

    def _terminal(self, j: int, i: int, obs: np.ndarray, states: np.ndarray | None) -> Any:
        single = self.layout.agent_obs(j, np.asarray(obs)[None])[0]
        if states is None or self.layout.state_space is None:
            return single
        return {"obs": single, "state": self.layout.state_obs(j, states[i:i + 1])[0]}

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        """The observations of the group's slots after the team's reset (all groups reset together)."""
        self.joint.team.set_options([self._options[i * self.n_agents] or None for i in range(self.n_envs)])
        obs, infos = self.joint.reset(self.group)
        self._reset_options()
        self.reset_infos = [infos[a][i] for i in range(self.n_envs) for a in self.possible_agents]
        return self._slots(obs, self.joint.team.states)

    def step_async(self, actions: np.ndarray) -> None:
        acts = np.asarray(actions).reshape((self.n_envs, self.n_agents, *np.shape(actions)[1:]))
        self.joint.submit(self.group, {a: acts[:, j] for j, a in enumerate(self.possible_agents)})

    def step_wait(self) -> VecEnvStepReturn:
        step = self.joint.step_result(self.group)
        agents = self.possible_agents
        rewards = self._stack([step.rewards[a] for a in agents]).astype(np.float32)
        dones = self._stack([step.dones[a] for a in agents])
        infos = [dict(step.infos[a][i]) for i in range(self.n_envs) for a in agents]
        self._finish_infos(step, infos)
        return self._slots(step.obs, step.states), rewards, dones, infos

    def _finish_infos(self, step: TeamStep, infos: list[dict[str, Any]]) -> None:
        for k, info in enumerate(infos):
            if "terminal_observation" in info:
                i, j = divmod(k, self.n_agents)
                info["terminal_observation"] = self._terminal(j, i, info["terminal_observation"],
                                                              step.terminal_states)
        for i, episode in enumerate(step.episodes):
            if episode is not None:
                returns = episode["returns"]
                group = {"r": round(sum(returns[a] for a in self.possible_agents), 6), "l": episode["l"],
                         "t": episode["t"]}
                group.update({k: v for k, v in episode.items() if k not in ("r", "l", "t", "returns")})
                infos[i * self.n_agents]["episode"] = group

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the team's next reset (copy ``i`` with ``seed + i``); every slot of a copy shares its seed."""
        seeds = self.joint.seed(seed)
        return [seeds[k // self.n_agents] for k in range(self.num_envs)]

    def close(self) -> None:
        self.joint.close()

    def _copies(self, indices: VecEnvIndices) -> list[int]:
        slots: Sequence[int] = range(self.num_envs) if indices is None else (
            [indices] if isinstance(indices, int) else list(indices))
        return [k // self.n_agents for k in slots]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of the env copy behind each slot (``render_mode``: the team's, also for envs without one)."""
        if attr_name == "render_mode":
            return [self.render_mode for _ in self._copies(indices)]
        return [self.joint.team.call(i, attr_name) for i in self._copies(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the attribute on each distinct env copy behind the slots."""
        for i in sorted(set(self._copies(indices))):
            self.joint.team.set_attr(i, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        """Call a method once per distinct copy; the result is repeated for each of its slots."""
        results: dict[int, Any] = {}
        out = []
        for i in self._copies(indices):
            if i not in results:
                results[i] = self.joint.team.call(i, method_name, *method_args, **method_kwargs)
            out.append(results[i])
        return out

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """Always False: the copies are PettingZoo envs, never Gymnasium wrappers (so no ``Monitor``)."""
        return [False for _ in self._copies(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [self.joint.team.call(i, "render") if self.render_mode == "rgb_array" else None
                for i in range(self.n_envs)]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """``human``/``ansi`` copies render themselves; ``rgb_array`` images of all copies are tiled."""
        if self.render_mode in ("human", "ansi"):
            for i in range(self.n_envs):
                self.joint.team.call(i, "render")
            return None
        return super().render(mode)
