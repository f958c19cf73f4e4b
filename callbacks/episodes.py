"""The episode record, the one episode runner and the one aggregation of episodes.

Every evaluation in sbagents plays its episodes here and reads its numbers from :class:`EpisodeRecord`:
periodic evaluation (``TeamEvalCallback``), ``evaluate`` (single-agent, teams, games), attacks, fairness, games'
matches, federated evaluation and the RLlib backend. :func:`summarize_records` turns records into the keys of the
``evaluate --json`` contract, so one key means one thing everywhere.

The info-key contract (docs/architecture.md) is read here and only here:

- ``info["is_success"]`` at an episode's last step: :attr:`EpisodeRecord.success` (None when absent);
- ``info["cost"]`` / ``info["violation"]`` at any step: :attr:`EpisodeRecord.cost` and ``violations``
  (:func:`step_violation`; the cost is None when no step of the episode had either key);
- :data:`ACTED` (a team slot whose agent did not act) is defined here for the callbacks and the team VecEnvs;
- SB3's ``info["episode"]`` (Monitor, or a team VecEnv's end of a team episode on a copy's first slot; its keys
  beyond ``r``, ``l``, ``t`` are the env's declared ``info_metrics``);
- the game keys of ``sbagents.games.selfplay.SelfPlayEnv``: :data:`SEAT_KEY`, :data:`RETURN_KEY`,
  :data:`ILLEGAL_KEY`, :data:`OUTCOME_KEY` at a game's last step and :data:`UNPLAYED_KEY` (games that ended
  before the player's seat moved) at a reset.

This module imports only numpy, Gymnasium and Stable-Baselines3 (it sits below the feature packages).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecMonitor, VecNormalize, is_vecenv_wrapped

from sbagents.core.info_keys import ILLEGAL_KEY, RETURN_KEY, SEAT_KEY, UNPLAYED_KEY

#: Keys of SB3's ``episode`` info that are not episode metrics.
EPISODE_STAT_KEYS = frozenset({"r", "l", "t"})

#: ``obs batch -> actions`` of one VecEnv (or ``obs -> action`` of one Gymnasium env): a stateless policy, made a
#: :class:`Policy` by :func:`stateless`.
Act = Callable[[Any], Any]


class Policy(Protocol):
    """The one policy protocol of every rollout in sbagents: ``(obs, state, episode_start) -> (actions, state)``.

    SB3's ``predict`` contract: ``obs`` is a VecEnv batch ``(n_envs, *obs_shape)`` (one Gymnasium observation for
    :func:`play_env_episodes`); ``state`` is what the previous call returned (None at the first call; a recurrent
    policy's hidden state, e.g. RecurrentPPO's ``(h, c)`` each ``(n_layers, n_envs, hidden)``; stateless policies
    return None); ``episode_start`` is a bool array ``(n_envs,)``, True where this observation is the first of an
    episode (for a team VecEnv: the first of that slot's agent), where a recurrent policy resets its state.
    """

    def __call__(self, obs: Any, state: Any, episode_start: np.ndarray) -> tuple[Any, Any]: ...


def stateless(act: Act) -> Policy:
    """The :class:`Policy` of an ``obs -> actions`` function (its state is always None)."""

    def policy(obs: Any, state: Any, episode_start: np.ndarray) -> tuple[Any, Any]:
        return act(obs), None

    return policy
#: ``step infos of one episode -> {metric: value}`` (an env's ``episode_metrics`` hook).
MetricsFn = Callable[[list[dict[str, Any]]], Mapping[str, float]]


def step_violation(info: Mapping[str, Any]) -> tuple[str | None, float]:
    """``(violation type or None, cost)`` of one step's ``info`` (the info-key contract in docs/architecture.md).

    A step violates when ``info["violation"]`` is truthy (its ``str`` is the type) or ``info["cost"] > 0``
    (type ``"cost"`` when no ``violation`` names it). The cost is ``info["cost"]``, or 1.0 for a named
    violation without a ``cost`` key (Safety-Gymnasium: 1.0 per violation step).
    """
    violation = info.get("violation")
    raw_cost = info.get("cost")
    cost = float(raw_cost) if raw_cost is not None else (1.0 if violation else 0.0)
    if violation:
        return str(violation), cost
    if cost > 0:
        return "cost", cost
    return None, cost


def reports_cost(info: Mapping[str, Any]) -> bool:
    """Whether a step's ``info`` carries a cost (``cost`` or ``violation`` key, whatever its value)."""
    return "cost" in info or "violation" in info


@dataclass(frozen=True)
class GameOutcome:
    """One game of a turn-based game from the player's side.

    :param seat: the player's seat index.
    :param result: the player's return (its sign is the outcome: win > 0, draw 0, loss < 0).
    :param illegal_moves: the player's illegal moves in this game.
    """

    seat: int
    result: float
    illegal_moves: int = 0


@dataclass(frozen=True)
class EpisodeRecord:
    """One evaluation episode.

    :param ret: the return; a team's return is the sum of its agents' returns, a game's the player's return.
    :param length: steps (team steps; the player's moves in a game).
    :param success: ``info["is_success"]`` of the last step, None when the env reports none.
    :param violations: steps that violated (:func:`step_violation`; every agent's for a team).
    :param cost: the episode cost (sum of step costs), None when no step reported ``cost`` or ``violation``.
    :param info: the last step's ``info`` (a team's first slot): the episode attributes fairness buckets by.
    :param agent_returns: agent -> its return, for teams (None otherwise).
    :param metrics: the env's declared episode metrics (``episode_metrics`` hook or team ``info_metrics``).
    :param game: the game's outcome, for turn-based games (None otherwise).
    """

    ret: float
    length: int
    success: bool | None = None
    violations: int = 0
    cost: float | None = None
    info: Mapping[str, Any] = field(default_factory=dict)
    agent_returns: Mapping[str, float] | None = None
    metrics: Mapping[str, float] = field(default_factory=dict)
    game: GameOutcome | None = None


class _Tally:
    """Totals of one episode in progress (one env copy); reads the info-key contract of each step."""

    def __init__(self, agents: Sequence[str] | None, keep_infos: bool) -> None:
        self.agents, self.keep_infos = agents, keep_infos
        self.reset()

    def reset(self) -> None:
        self.ret, self.length, self.violations, self.cost, self.costed, self.illegal = 0.0, 0, 0, 0.0, False, 0
        self.by_agent = dict.fromkeys(self.agents, 0.0) if self.agents else {}
        self.infos: list[dict[str, Any]] = []

    def add(self, rewards: Sequence[float] | np.ndarray, infos: Sequence[dict[str, Any]],
            names: Sequence[str] | None = None) -> None:
        """Rewards and infos of some slots of this copy at one step (call :meth:`tick` once per step)."""
        for i, (reward, info) in enumerate(zip(rewards, infos, strict=True)):
            if names is not None:
                self.by_agent[names[i]] += float(reward)
            else:
                self.ret += float(reward)
            kind, c = step_violation(info)
            self.violations += kind is not None
            self.cost += c
            self.costed = self.costed or reports_cost(info)
            self.illegal += int(info.get(ILLEGAL_KEY, 0))

    def tick(self, info: dict[str, Any]) -> None:
        """One step more (``info``: the step's info of the copy's first slot)."""
        self.length += 1
        if self.keep_infos:
            self.infos.append(info)

    def record(self, info: dict[str, Any], metrics_fn: MetricsFn | None = None, ret: float | None = None,
               length: int | None = None) -> EpisodeRecord:
        """The finished episode, ``info`` its last step's (a team's first slot); ``ret`` / ``length`` override
        the counted ones (Monitor's)."""
        success = bool(info["is_success"]) if "is_success" in info else None
        if metrics_fn is not None:
            metrics: dict[str, float] = dict(metrics_fn(self.infos))
        elif self.agents:  # a team's declared metrics ride in its episode info
            stats = info.get("episode", {})
            metrics = {k: float(v) for k, v in stats.items() if k not in EPISODE_STAT_KEYS}
        else:
            metrics = {}
        game = None
        if RETURN_KEY in info:
            ret = float(info[RETURN_KEY])
            game = GameOutcome(int(info[SEAT_KEY]), ret, self.illegal)
        if ret is None:
            ret = sum(self.by_agent.values()) if self.agents else self.ret
        return EpisodeRecord(ret, self.length if length is None else length, success, self.violations,
                             self.cost if self.costed else None, dict(info),
                             dict(self.by_agent) if self.agents else None, metrics, game)


def _find_vec_normalize(venv: VecEnv) -> VecNormalize | None:
    env: VecEnv = venv
    while not isinstance(env, VecNormalize):
        if not isinstance(env, VecEnvWrapper):
            return None
        env = env.venv
    return env


def slot_agents(venv: VecEnv) -> list[str] | None:
    """The agents behind the slots of one copy of a team VecEnv (slot ``k`` is agent ``k % n_agents`` of copy
    ``k // n_agents``), or None for a plain VecEnv."""
    agents = getattr(venv.unwrapped, "possible_agents", None)
    return [str(a) for a in agents] if agents else None


def is_recurrent(model: Any) -> bool:
    """Whether ``model`` (an SB3 algorithm or policy) keeps a hidden state between steps (sb3-contrib's recurrent
    policies: ``lstm_hidden_state_shape``)."""
    policy = getattr(model, "policy", model)
    return hasattr(policy, "lstm_hidden_state_shape")


def model_actor(model: Any, deterministic: bool = True,
                action_masks: Callable[[], np.ndarray] | None = None) -> Policy:
    """The :class:`Policy` of anything with SB3's ``predict`` (an SB3 policy is put in eval mode): the hidden state
    and episode starts go through ``predict(obs, state, episode_start)``, so a recurrent policy keeps its memory.

    :param action_masks: ``() -> masks`` of the current observations (MaskablePPO's ``action_masks`` argument).
    """
    policy = getattr(model, "policy", None)
    if policy is not None:
        policy.set_training_mode(False)

    def act(obs: Any, state: Any, episode_start: np.ndarray) -> tuple[Any, Any]:
        if action_masks is not None:
            return model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic,
                                 action_masks=action_masks())  # type: ignore[no-any-return]
        return model.predict(obs, state=state, episode_start=episode_start,  # type: ignore[no-any-return]
                             deterministic=deterministic)

    return act


def is_monitor_wrapped(venv: VecEnv) -> bool:
    """Whether SB3's ``Monitor`` (or ``VecMonitor``) reports ``info["episode"]`` in ``venv`` (as ``evaluate_policy``
    checks)."""
    return is_vecenv_wrapped(venv, VecMonitor) or bool(venv.env_is_wrapped(Monitor)[0])


def episode_metrics_of(venv: VecEnv) -> MetricsFn | None:
    """The env's ``episode_metrics(step_infos) -> dict`` hook (first copy), if it has one."""
    try:
        found = venv.get_attr("episode_metrics", [0])[0]
    except AttributeError:
        return None
    return found if callable(found) else None


def play_episodes(
    envs: VecEnv | Mapping[str, VecEnv],
    acts: Policy | Mapping[str, Policy],
    n_episodes: int,
    seed: int | None = None,
    monitor_episodes: bool = False,
    episode_metrics: MetricsFn | None = None,
    team: bool | None = None,
) -> list[EpisodeRecord]:
    """Play ``n_episodes`` episodes of a VecEnv (or of one team's group VecEnvs stepped together) and return
    their records in completion order.

    Episodes are spread over the env copies as in SB3's ``evaluate_policy`` (copy ``i`` runs
    ``(n_episodes + i) // n_copies`` of them) so short episodes do not dominate. Rewards are unnormalized
    (``VecNormalize.get_original_reward``); every ``VecNormalize`` is frozen (``training=False``) meanwhile.

    A plain VecEnv's episode ends at ``done``; a team VecEnv's (``possible_agents``: ``n_agents`` slots per copy)
    when the first group's copy reports SB3's ``episode`` info on its first slot (agents may end earlier). A team
    return is the sum of its agents' returns.

    :param envs: a VecEnv, or group -> VecEnv of one team (the same number of copies each, in the team's group
        order; only the first one is seeded).
    :param acts: the :class:`Policy` (group -> one, with ``envs`` a mapping); each group's state is carried from
        step to step and its ``episode_start`` is True at the first step and then where that slot was done.
    :param seed: ``seed(seed)`` before the reset (the same episodes for every call); None: as the env is.
    :param monitor_episodes: ``evaluate_policy``'s rule for a plain VecEnv wrapped in ``Monitor``: returns and
        lengths are Monitor's (``info["episode"]``: rewards below any outer wrapper, the return rounded to 1e-6)
        and only a ``done`` with that info ends an episode (an Atari life lost does not).
    :param episode_metrics: ``step infos -> metrics`` of each episode (the env's ``episode_metrics`` hook).
    :param team: play team episodes (None: when some VecEnv is a team VecEnv); a plain VecEnv in a team is one
        agent named after its group.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    venvs = dict(envs) if isinstance(envs, Mapping) else {"": envs}
    actors = dict(acts) if isinstance(acts, Mapping) else {"": acts}  # type: ignore[arg-type]
    order = list(venvs)
    found = {g: slot_agents(v) for g, v in venvs.items()}
    if team is None:
        team = any(n is not None for n in found.values())
    names = {g: found[g] or [g] for g in order} if team else found
    width = {g: len(names[g] or [g]) for g in order}
    n_copies = venvs[order[0]].num_envs // width[order[0]]
    if any(v.num_envs != n_copies * width[g] for g, v in venvs.items()):
        raise ValueError("the group VecEnvs of one team need the same number of copies")
    monitored = monitor_episodes and not team and is_monitor_wrapped(venvs[order[0]])
    targets = [(n_episodes + i) // n_copies for i in range(n_copies)]
    counts = [0] * n_copies
    agents = [a for g in order for a in names[g] or [g]] if team else None
    tallies = [_Tally(agents, episode_metrics is not None) for _ in range(n_copies)]
    norms = {g: _find_vec_normalize(v) for g, v in venvs.items()}
    frozen = {g: vn.training for g, vn in norms.items() if vn is not None}
    for g in frozen:
        norms[g].training = False  # type: ignore[union-attr]
    records: list[EpisodeRecord] = []
    try:
        if seed is not None:
            venvs[order[0]].seed(seed)
        obs = {g: venvs[g].reset() for g in order}
        states: dict[str, Any] = dict.fromkeys(order)
        starts = {g: np.ones(venvs[g].num_envs, dtype=bool) for g in order}
        while sum(counts) < sum(targets):
            for g in order:
                actions, states[g] = actors[g](obs[g], states[g], starts[g])
                venvs[g].step_async(actions)
            infos: dict[str, list[dict[str, Any]]] = {}
            dones: dict[str, np.ndarray] = {}
            raw: dict[str, np.ndarray] = {}
            for g in order:
                obs[g], rewards, dones[g], infos[g] = venvs[g].step_wait()
                starts[g] = np.asarray(dones[g], dtype=bool)
                vn = norms[g]
                raw[g] = vn.get_original_reward() if vn is not None else rewards
            for c in range(n_copies):
                tally = tallies[c]
                for g in order:
                    part = slice(c * width[g], (c + 1) * width[g])
                    tally.add(raw[g][part], infos[g][part], names[g] if team else None)
                head = infos[order[0]][c * width[order[0]]]
                tally.tick(head)
                if not (("episode" in head) if team else dones[order[0]][c]):
                    continue
                if monitored and "episode" not in head:
                    continue  # evaluate_policy: a done without Monitor's episode info (a life lost) ends nothing
                if counts[c] < targets[c]:
                    stats = head.get("episode") if monitored else None
                    records.append(tally.record(head, episode_metrics,
                                                None if stats is None else float(stats["r"]),
                                                None if stats is None else int(stats["l"])))
                    counts[c] += 1
                tally.reset()
    finally:
        for g, was in frozen.items():
            norms[g].training = was  # type: ignore[union-attr]
    return records


def play_env_episodes(
    env: gym.Env,
    act: Policy,
    n_episodes: int,
    seed: int | None = None,
    episode_metrics: MetricsFn | None = None,
) -> list[EpisodeRecord]:
    """Play ``n_episodes`` episodes of one Gymnasium env (no auto-reset: nothing is played or reset after the
    last episode) and return their records.

    Games: a reset whose info lists :data:`UNPLAYED_KEY` games (ended before the player's seat moved) adds one
    record per such game (length 0, ``game`` set) before the next episode; an episode whose last info has
    :data:`RETURN_KEY` gets that return and a :class:`GameOutcome`.

    :param act: the :class:`Policy` of one observation (``episode_start`` has shape ``(1,)``; the state is reset
        at every episode's first step).
    :param seed: seed of the first reset (then the env's generator continues).
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    records: list[EpisodeRecord] = []
    tally = _Tally(None, episode_metrics is not None)
    obs, info = env.reset(seed=seed)
    while True:
        for seat, result in info.get(UNPLAYED_KEY, ()):
            records.append(EpisodeRecord(float(result), 0, game=GameOutcome(int(seat), float(result))))
        if len(records) >= n_episodes:
            break
        tally.reset()
        done, state, start = False, None, np.ones(1, dtype=bool)
        while not done:
            action, state = act(obs, state, start)
            start = np.zeros(1, dtype=bool)
            obs, reward, terminated, truncated, info = env.step(action)
            tally.add([float(reward)], [info])
            tally.tick(info)
            done = terminated or truncated
        records.append(tally.record(info, episode_metrics))
        if len(records) >= n_episodes:
            break
        obs, info = env.reset()
    return records[:n_episodes]


def _mean(values: Sequence[float]) -> float:
    return float(np.mean(values))


def summarize_records(records: Sequence[EpisodeRecord], groups: Mapping[str, Sequence[str]] | None = None
                      ) -> dict[str, Any]:
    """The evaluation summary of episodes, one meaning per key wherever it appears.

    :param groups: group -> its agents (a team with several groups adds ``metrics.per_group_return``).
    :return: ``n_episodes``; ``mean_return`` / ``std_return`` (population std); ``mean_length``; ``success_rate``
        (share of the episodes that report ``is_success`` whose last step did; None when none does); ``metrics``:
        for teams ``episode_length`` (= mean_length), ``per_agent_return`` (agent -> mean return) and
        ``per_group_return``, then the mean of each declared episode metric; ``mean_cost`` (mean cost of the
        episodes that report one, EpCost) only when some episode does.
    """
    returns = [r.ret for r in records]
    successes = [bool(r.success) for r in records if r.success is not None]
    costs = [r.cost for r in records if r.cost is not None]
    metrics: dict[str, Any] = {}
    by_agent = [r.agent_returns for r in records if r.agent_returns is not None]
    if records and records[0].agent_returns is not None:
        metrics["episode_length"] = _mean([r.length for r in records])
        metrics["per_agent_return"] = {a: _mean([ret[a] for ret in by_agent]) for a in records[0].agent_returns}
        if groups is not None and len(groups) > 1:
            metrics["per_group_return"] = {g: _mean([sum(ret[a] for a in members) for ret in by_agent])
                                           for g, members in groups.items()}
    declared: dict[str, list[float]] = {}
    for r in records:
        for key, value in r.metrics.items():
            declared.setdefault(key, []).append(value)
    metrics.update({k: _mean(v) for k, v in declared.items()})
    return {
        "n_episodes": len(records),
        "mean_return": _mean(returns),
        "std_return": float(np.std(returns)),
        "mean_length": _mean([r.length for r in records]),
        "success_rate": _mean(successes) if successes else None,
        "metrics": metrics,
        **({"mean_cost": _mean(costs)} if costs else {}),
    }


def game_rates(records: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """``n_games``, ``win_rate``, ``draw_rate``, ``loss_rate`` and ``mean_reward`` of game records (by the sign of
    the player's result; None without games)."""
    results = np.array([r.game.result for r in records if r.game is not None], dtype=float)
    n = len(results)
    if n == 0:
        return {"n_games": 0, "win_rate": None, "draw_rate": None, "loss_rate": None, "mean_reward": None}
    return {"n_games": n, "win_rate": float(np.mean(results > 0)), "draw_rate": float(np.mean(results == 0)),
            "loss_rate": float(np.mean(results < 0)), "mean_reward": float(np.mean(results))}
