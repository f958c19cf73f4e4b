"""Recording episodes into a dataset (``python -m sbagents.collect``): a baseline (random, or the env's scripted
expert) or a finished run acts on one copy of the env, and :mod:`sbagents.datasets.writing` stores the episodes in
Minari's format.

What a dataset records is what the acting policy sees before normalization: the plain env's observations for a
baseline; for a run, its env as training wrapped it (env wrappers, frame stack), with the run's ``VecNormalize``
statistics applied to the policy's input only. Rewards are the env's own (never normalized).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.baselines.policies import slot
from sbagents.callbacks.common import acted_slots
from sbagents.callbacks.episodes import Policy, model_actor
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.progress import ProgressReporter
from sbagents.core.run_dir import SHARED_GROUP as SHARED
from sbagents.core.run_dir import RunRef, load_run
from sbagents.datasets.writing import DatasetInfo, EpisodeRecorder, check_dataset_id, require_minari, write_dataset
from sbagents.env_factory import make_team_vecs, make_vec, normalize_for_eval
from sbagents.errors import UsageError
from sbagents.multiagent.team_eval import slot_agents
from sbagents.pipeline.evaluation import baseline_actor, baseline_experiment, evaluate_baseline, game_operations


@dataclass(frozen=True)
class CollectOptions:
    """What ``collect`` records.

    :param episodes: episodes to record (from a log: at most this many, None: all).
    :param dataset: the dataset id (``namespace/name-vN``).
    :param seed: the first episode's reset seed (episode ``i`` resets with ``seed + i``).
    :param ref_episodes: episodes of random play and of the scripted expert that give the dataset's reference scores
        (0: none; only for envs with an expert).
    :param progress: show a progress bar (None: on a terminal).
    :param group: the group of a team of several groups whose agents are recorded (every group acts; a baseline then
        plays the team with one policy per group, so that each group keeps its own spaces).
    :param opponent: who plays a turn-based game's other seats (a player spec as ``evaluate --opponent`` takes; None:
        random).
    """

    episodes: int | None
    dataset: str
    seed: int = 0
    ref_episodes: int = 10
    progress: bool | None = None
    group: str | None = None
    opponent: str | None = None

    def validate(self) -> None:
        """One line for what does not fit."""
        if self.episodes is not None and self.episodes < 1:
            raise UsageError(f"--episodes must be >= 1, got {self.episodes}")
        if self.ref_episodes < 0:
            raise UsageError(f"--ref-episodes must be >= 0, got {self.ref_episodes}")
        check_dataset_id(self.dataset)


def collect(options: CollectOptions, *, env: EnvRef | None = None, policy: str | None = None,
            run: RunRef | None = None, log: Path | None = None, env_kwargs: dict[str, Any] | None = None
            ) -> tuple[Path, int]:
    """Record episodes into the dataset ``options.dataset``; its folder and how many episodes it holds.

    Either ``policy`` (``random`` or ``scripted``, on ``env``) or ``run`` (a finished SB3 run, greedy) acts, or ``log``
    (a transparency log of a run on ``env``) gives the episodes (:mod:`sbagents.datasets.logs`). A team is recorded
    in the layout :func:`_team_collect_kind` describes, a turn-based game in :func:`_game_collect_kind`'s.

    :raises UsageError: (one line) not exactly one of ``policy``, ``run`` and ``log``, a team of several groups without
        ``options.group``, an env without a scripted expert, a log that does not fit the env, a dataset that exists,
        or Minari missing.
    """
    options.validate()
    require_minari()
    if sum(source is not None for source in (policy, run, log)) != 1:
        raise UsageError("collect records --policy random|scripted, a run (--algo ALGO -f LOGS) or --from-log PATH: "
                         "give one of them")
    if log is not None:
        assert env is not None
        return _from_log(options, env, log, env_kwargs)
    if options.episodes is None:
        raise UsageError("--episodes N: how many episodes to record")
    if run is not None:
        loaded = load_run(run)
        ref, exp = loaded.env, loaded.experiment
        algorithm, trust = f"{exp.algo} ({loaded.run_dir})", loaded.trust
        acting = Acting(exp.deterministic_eval, models=loaded.models or {SHARED: loaded.model},
                        stats={g: p for g, p in loaded.stats_paths.items() if p is not None})
    else:
        assert env is not None and policy is not None
        entry = {"policies": "per_group"} if options.group is not None and isinstance(env.kind, TeamKind) else {}
        ref, exp = env, baseline_experiment(env, policy, env_kwargs, entry)
        algorithm, trust = policy, False
        acting = Acting(True, policy=policy, seed=options.seed)
    recorded = _collect_kind(ref.kind, exp, ref, acting, options, trust)
    assert options.episodes is not None
    scores = _reference_scores(ref, options, env_kwargs) if recorded.env is not None else (None, None)
    info = DatasetInfo(algorithm, *scores,
                       description=f"{options.episodes} episodes of {ref.env_id} played by {algorithm}, recorded by "
                                   f"python -m sbagents.collect ({_seeds_note(recorded.seeds)}){recorded.layout}")
    return write_dataset(options.dataset, recorded.episodes, recorded.seeds, recorded.env, info,
                         recorded.observation_space, recorded.action_space), len(recorded.episodes)


def _seeds_note(seeds: list[int | None]) -> str:
    """``reset seeds 0...9``, or where only the first reset was seeded, ``reset seed 0, then unseeded``."""
    given = [s for s in seeds if s is not None]
    if not given:
        return "unseeded resets"
    if len(given) < len(seeds):
        return f"reset seed {given[0]}, then unseeded resets"
    return f"reset seeds {min(given)}...{max(given)}"


@dataclass(frozen=True)
class Acting:
    """Who acts while ``collect`` records: a baseline ``policy`` (``random``/``scripted``), or a run's ``models`` (group
    -> model; one model: ``shared``) with their ``VecNormalize`` statistics files (group -> path, applied to the
    policies' input only)."""

    deterministic: bool
    policy: str | None = None
    seed: int = 0
    models: Mapping[str, Any] = field(default_factory=dict)
    stats: Mapping[str, Path] = field(default_factory=dict)

    def actor(self, env_id: str, group: str, venv: VecEnv) -> Policy:
        """The policy of ``group``'s agents (one model: every group's) on ``venv``."""
        if self.policy is not None:
            return baseline_actor(self.policy, env_id, venv, self.seed)
        model = self.models.get(group, next(iter(self.models.values())))
        return model_actor(model, self.deterministic)

    def stats_of(self, group: str) -> Path | None:
        """The statistics file of ``group``'s model (None: none)."""
        if len(self.models) > 1:  # one model per group: each its own statistics
            return self.stats.get(group)
        return next(iter(self.stats.values()), None)


@dataclass(frozen=True)
class Recorded:
    """What a kind recorded: the episodes and each one's reset seed, their spaces, the env Minari records (its id; None
    where Gymnasium cannot make it: a team, whose dataset then has no reference scores, which Minari keeps only with an
    env spec) and a note on the layout for the dataset's description."""

    episodes: list[EpisodeRecorder]
    seeds: list[int | None]
    observation_space: Any
    action_space: Any
    env: str | None
    layout: str = ""


@kind_operation()
def _collect_kind(kind: EnvKind, exp: Experiment, ref: EnvRef, acting: Acting, options: CollectOptions, trust: bool
                  ) -> Recorded:
    """One Gymnasium agent: one copy of the env as ``exp`` wraps it, the run's statistics applied to the policy's
    input only."""
    _no_team_options(ref, options)
    venv, norm = _env(make_vec(exp, ref, 1, options.seed, vec_env="dummy"), exp, ref, acting.stats_of(SHARED), trust)
    try:
        episodes = _record(venv, norm, acting.actor(ref.env_id, SHARED, venv), options)
    finally:
        venv.close()
    seeds: list[int | None] = [options.seed + i for i in range(len(episodes))]
    return Recorded(episodes, seeds, venv.observation_space, venv.action_space, ref.env_id)


@_collect_kind.register
def _team_collect_kind(kind: TeamKind, exp: Experiment, ref: EnvRef, acting: Acting, options: CollectOptions,
                       trust: bool) -> Recorded:
    """A team: each team episode becomes one dataset episode per recorded agent, consecutive, in the order of the
    team's agents (an agent's steps while it is present; :func:`_record_team`), with one agent's spaces. A team of one
    shared group records every agent; of several groups, the agents of ``options.group`` while every group acts."""
    if options.opponent is not None:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is a team")
    venvs = make_team_vecs(exp, ref, 1, options.seed, vec_env="dummy")
    group = options.group if options.group is not None else next(iter(venvs))
    if group not in venvs or (options.group is None and len(venvs) > 1):
        for venv in venvs.values():
            venv.close()
        if len(venvs) == 1:
            raise UsageError(f"--group applies to teams of several groups; this {ref.env_id} "
                             f"{'run' if acting.policy is None else 'env'} has one shared group")
        raise UsageError(f"{ref.env_id} has the groups {', '.join(venvs)}: --group NAME records one of them (every "
                         "group acts)" + (f", not {options.group!r}" if options.group is not None else ""))
    norms = {g: normalize_for_eval(v, exp, acting.stats_of(g), trust) for g, v in venvs.items()}
    try:
        agents = slot_agents(venvs[group], group)
        actors = {g: acting.actor(ref.env_id, g, v) for g, v in venvs.items()}
        episodes, seeds = _record_team(venvs, {g: n if isinstance(n, VecNormalize) else None for g, n in norms.items()},
                                       actors, group, options)
        space = venvs[group].observation_space, venvs[group].action_space
    finally:
        for venv in venvs.values():
            venv.close()
    others = [g for g in venvs if g != group]
    layout = (f"; multi-agent layout: each team episode is {len(agents)} consecutive episodes, one per agent"
              + (f" of group {group}" if others else "") + f" in the order {', '.join(agents)}"
              + (f", while the groups {', '.join(others)} acted too (not recorded)" if others else ""))
    return Recorded(episodes, seeds, *space, None, layout)


@_collect_kind.register
def _game_collect_kind(kind: GameKind, exp: Experiment, ref: EnvRef, acting: Acting, options: CollectOptions,
                       trust: bool) -> Recorded:
    """A turn-based game from the recorded player's seat, as training sees it
    (:func:`sbagents.games.recording.record_games`): the other seats' replies (``options.opponent``, default random)
    inside each step, the outcome as the last reward, each observation's legal moves in the infos (``action_mask``)."""
    _no_team_options(ref, options, turns=True)
    if acting.policy is None and len(acting.models) != 1:
        raise UsageError("collect records a run of one model of a turn-based game")
    turns = game_operations()
    player = turns.game_player(acting.policy or next(iter(acting.models.values())), ref, options.seed,
                               acting.deterministic)
    opponent = options.opponent or "random"
    assert options.episodes is not None
    episodes, obs_space, action_space = turns.record_games(player, exp, ref, options.episodes, options.seed, opponent,
                                                           EpisodeRecorder, options.progress)
    seeds: list[int | None] = [options.seed] + [None] * (len(episodes) - 1)
    layout = (f"; turn-based game: one episode per game from the recorded player's seat (seats alternate from game "
              f"to game), {opponent} in the other seats (their moves inside each step); infos: action_mask")
    return Recorded(episodes, seeds, obs_space, action_space, None, layout)


def _no_team_options(ref: EnvRef, options: CollectOptions, turns: bool = False) -> None:
    """One line for ``--group`` (or ``--opponent``, but in a turn-based game: ``turns``) where they do not apply."""
    if options.group is not None:
        raise UsageError(f"--group applies to teams of several groups; {ref.env_id} is not a team")
    if options.opponent is not None and not turns:
        raise UsageError(f"--opponent applies to turn-based games; {ref.env_id} is not one")


def _from_log(options: CollectOptions, ref: EnvRef, log: Path, env_kwargs: dict[str, Any] | None
              ) -> tuple[Path, int]:
    """The complete episodes of the transparency log ``log`` of a run on ``ref``'s plain env."""
    from sbagents.datasets.logs import episodes_from_log, log_description

    exp = baseline_experiment(ref, "random", env_kwargs)
    venv, _ = _env(make_vec(exp, ref, 1, options.seed, vec_env="dummy"), exp, ref, None, False)
    obs_space, action_space = venv.observation_space, venv.action_space
    venv.close()
    episodes, dropped = episodes_from_log(log, obs_space, action_space, options.episodes)
    info = DatasetInfo(f"transparency log {log.name}", *_reference_scores(ref, options, env_kwargs),
                       description=log_description(log, len(episodes), dropped))
    return write_dataset(options.dataset, episodes, [None] * len(episodes), ref.env_id, info, obs_space,
                         action_space), len(episodes)


def _env(venv: VecEnv, exp: Experiment, ref: EnvRef, stats: Path | None, trust: bool
         ) -> tuple[VecEnv, VecNormalize | None]:
    """``venv`` if one copy of the env is one agent acting without action masks (else closed, and one line), and the
    frozen statistics ``stats`` (None: none)."""
    if venv.num_envs != 1 or venv.has_attr("action_masks"):
        venv.close()
        raise UsageError(f"collect records single Gymnasium agents and teams; {ref.env_id} acts with action masks")
    norm = normalize_for_eval(venv, exp, stats, trust)
    return venv, norm if isinstance(norm, VecNormalize) else None


def _record(venv: VecEnv, norm: VecNormalize | None, actor: Policy, options: CollectOptions
            ) -> list[EpisodeRecorder]:
    """Play the episodes on ``venv`` (one copy; episode ``i`` reset with ``options.seed + i``)."""
    assert options.episodes is not None
    reporter = ProgressReporter(options.episodes, bar=options.progress)
    episodes = []
    try:
        for i in range(options.episodes):
            venv.seed(options.seed + i)
            obs = venv.reset()
            recorder = EpisodeRecorder()
            recorder.start(slot(obs, 0))
            state, start = None, np.ones(1, dtype=bool)
            while True:
                seen: Any = obs
                actions, state = actor(norm.normalize_obs(seen) if norm is not None else seen, state, start)
                start = np.zeros(1, dtype=bool)
                obs, rewards, dones, infos = venv.step(actions)
                info = infos[0]
                truncated = bool(info.get("TimeLimit.truncated", False))
                last = info["terminal_observation"] if dones[0] else slot(obs, 0)
                recorder.step(np.asarray(actions)[0], last, float(rewards[0]), bool(dones[0]) and not truncated,
                              truncated, info)
                if dones[0]:
                    break
            episodes.append(recorder)
            reporter.update(i + 1)
    finally:
        reporter.close()
    return episodes


def _record_team(venvs: Mapping[str, VecEnv], norms: Mapping[str, VecNormalize | None], actors: Mapping[str, Policy],
                 group: str, options: CollectOptions) -> tuple[list[EpisodeRecorder], list[int | None]]:
    """Play team episodes on the group VecEnvs ``venvs`` of one copy of a team, stepped together, each group acting
    with its actor (team episode ``i`` reset with ``options.seed + i``): per team episode, each of ``group``'s slots'
    agent's steps while it acted (``ACTED``), its own episode ending at its ``done`` (an agent still present when the
    team's episode ends is truncated there); the episodes and each one's reset seed."""
    assert options.episodes is not None
    reporter = ProgressReporter(options.episodes, bar=options.progress)
    episodes: list[EpisodeRecorder] = []
    seeds: list[int | None] = []
    order = list(venvs)
    n = venvs[group].num_envs
    try:
        for i in range(options.episodes):
            venvs[order[0]].seed(options.seed + i)
            obs = {g: venvs[g].reset() for g in order}
            recorders = [EpisodeRecorder() for _ in range(n)]
            for k, recorder in enumerate(recorders):
                recorder.start(slot(obs[group], k))
            ended = np.zeros(n, dtype=bool)
            states: dict[str, Any] = dict.fromkeys(order)
            starts = {g: np.ones(venvs[g].num_envs, dtype=bool) for g in order}
            while True:
                moves = {}
                for g in order:
                    norm = norms.get(g)
                    seen: Any = obs[g]
                    moves[g], states[g] = actors[g](norm.normalize_obs(seen) if norm is not None else seen, states[g],
                                                    starts[g])
                    starts[g] = np.zeros(venvs[g].num_envs, dtype=bool)
                    venvs[g].step_async(moves[g])
                results = {g: venvs[g].step_wait() for g in order}
                obs = {g: r[0] for g, r in results.items()}
                _, rewards, dones, infos = results[group]
                for j in np.flatnonzero(~ended & acted_slots(infos)).tolist():
                    info = infos[j]
                    truncated = bool(info.get("TimeLimit.truncated", False))
                    last = info["terminal_observation"] if dones[j] else slot(obs[group], j)
                    recorders[j].step(np.asarray(moves[group])[j], last, float(rewards[j]),
                                      bool(dones[j]) and not truncated, truncated, info)
                    ended[j] |= bool(dones[j])
                if "episode" in results[order[0]][3][0] or ended.all():  # the team's episode is over
                    break
            for k, recorder in enumerate(recorders):
                if recorder.actions and not ended[k]:
                    recorder.truncations[-1] = True
            played = [recorder for recorder in recorders if recorder.actions]
            episodes += played
            seeds += [options.seed + i] * len(played)
            reporter.update(i + 1)
    finally:
        reporter.close()
    return episodes, seeds


def _reference_scores(ref: EnvRef, options: CollectOptions, env_kwargs: dict[str, Any] | None
                      ) -> tuple[float | None, float | None]:
    """Random play's and the scripted expert's mean returns (None, None for an env without an expert)."""
    from sbagents.registration import SCRIPTED_POLICIES

    if options.ref_episodes == 0 or ref.env_id not in SCRIPTED_POLICIES:
        return None, None
    from sbagents.core.options import EvaluateOptions

    evaluation = EvaluateOptions(n_episodes=options.ref_episodes, seed=options.seed)
    scores = [float(evaluate_baseline(ref, name, evaluation, env_kwargs)["mean_return"])
              for name in ("random", "scripted")]
    return scores[0], scores[1]
