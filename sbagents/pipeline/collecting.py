"""Recording episodes into a dataset (``python -m sbagents.collect``): a baseline (random, or the env's scripted
expert) or a finished run acts on one copy of the env, and :mod:`sbagents.datasets.writing` stores the episodes in
Minari's format.

What a dataset records is what the acting policy sees before normalization: the plain env's observations for a
baseline; for a run, its env as training wrapped it (env wrappers, frame stack), with the run's ``VecNormalize``
statistics applied to the policy's input only. Rewards are the env's own (never normalized).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
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
from sbagents.core.run_dir import RunRef, load_run
from sbagents.datasets.writing import DatasetInfo, EpisodeRecorder, check_dataset_id, require_minari, write_dataset
from sbagents.env_factory import make_team_vecs, make_vec, normalize_for_eval
from sbagents.errors import UsageError
from sbagents.multiagent.team_eval import slot_agents
from sbagents.pipeline.evaluation import baseline_actor, baseline_experiment, evaluate_baseline


@dataclass(frozen=True)
class CollectOptions:
    """What ``collect`` records.

    :param episodes: episodes to record (from a log: at most this many, None: all).
    :param dataset: the dataset id (``namespace/name-vN``).
    :param seed: the first episode's reset seed (episode ``i`` resets with ``seed + i``).
    :param ref_episodes: episodes of random play and of the scripted expert that give the dataset's reference scores
        (0: none; only for envs with an expert).
    :param progress: show a progress bar (None: on a terminal).
    """

    episodes: int | None
    dataset: str
    seed: int = 0
    ref_episodes: int = 10
    progress: bool | None = None

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

    Either ``policy`` (``random`` or ``scripted``, on ``env``) or ``run`` (a finished SB3 run of one model, greedy)
    acts, or ``log`` (a transparency log of a run on ``env``) gives the episodes (:mod:`sbagents.datasets.logs`). A
    team (one shared group) is recorded in the layout :func:`_team_collect_kind` describes.

    :raises UsageError: (one line) not exactly one of ``policy``, ``run`` and ``log``, a turn-based game, a team of
        several groups, an env without a scripted expert, a log that does not fit the env, a dataset that exists, or
        Minari missing.
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
        if len(loaded.models) > 1:
            raise UsageError("collect records runs of one model; this run has one per group")
        ref, exp = loaded.env, loaded.experiment
        algorithm, stats, trust = f"{exp.algo} ({loaded.run_dir})", loaded.stats_path, loaded.trust
        model = loaded.model

        def actor_for(venv: VecEnv) -> Policy:
            return model_actor(model, exp.deterministic_eval)
    else:
        assert env is not None and policy is not None
        ref, exp = env, baseline_experiment(env, policy, env_kwargs)
        algorithm, stats, trust = policy, None, False

        def actor_for(venv: VecEnv) -> Policy:
            return baseline_actor(policy, ref.env_id, venv, options.seed)
    recorded = _collect_kind(ref.kind, exp, ref, actor_for, options, stats, trust)
    assert options.episodes is not None
    scores = _reference_scores(ref, options, env_kwargs) if recorded.env is not None else (None, None)
    info = DatasetInfo(algorithm, *scores,
                       description=f"{options.episodes} episodes of {ref.env_id} played by {algorithm}, recorded by "
                                   f"python -m sbagents.collect (reset seeds {options.seed}..."
                                   f"{options.seed + options.episodes - 1}){recorded.layout}")
    return write_dataset(options.dataset, recorded.episodes, recorded.seeds, recorded.env, info,
                         recorded.observation_space, recorded.action_space), len(recorded.episodes)


@dataclass(frozen=True)
class Recorded:
    """What a kind recorded: the episodes and each one's reset seed, their spaces, the env Minari records (its id; None
    where Gymnasium cannot make it: a team, whose dataset then has no reference scores, which Minari keeps only with an
    env spec) and a note on the layout for the dataset's description."""

    episodes: list[EpisodeRecorder]
    seeds: list[int]
    observation_space: Any
    action_space: Any
    env: str | None
    layout: str = ""


@kind_operation()
def _collect_kind(kind: EnvKind, exp: Experiment, ref: EnvRef, actor_for: Callable[[VecEnv], Policy],
                  options: CollectOptions, stats: Path | None, trust: bool) -> Recorded:
    """One Gymnasium agent: one copy of the env as ``exp`` wraps it, the statistics ``stats`` applied to the policy's
    input only."""
    venv, norm = _env(make_vec(exp, ref, 1, options.seed, vec_env="dummy"), exp, ref, stats, trust)
    try:
        episodes = _record(venv, norm, actor_for(venv), options)
    finally:
        venv.close()
    seeds = [options.seed + i for i in range(len(episodes))]
    return Recorded(episodes, seeds, venv.observation_space, venv.action_space, ref.env_id)


@_collect_kind.register
def _team_collect_kind(kind: TeamKind, exp: Experiment, ref: EnvRef, actor_for: Callable[[VecEnv], Policy],
                       options: CollectOptions, stats: Path | None, trust: bool) -> Recorded:
    """A team of one shared group: each team episode becomes one dataset episode per agent, consecutive, in the order
    of the team's agents (an agent's steps while it is present; :func:`_record_team`); the spaces are one agent's."""
    venvs = make_team_vecs(exp, ref, 1, options.seed, vec_env="dummy")
    if len(venvs) != 1:
        for venv in venvs.values():
            venv.close()
        raise UsageError(f"collect records teams of one shared group; {ref.env_id} trains groups {sorted(venvs)}")
    ((group, venv),) = venvs.items()
    norm = normalize_for_eval(venv, exp, stats, trust)
    try:
        agents = slot_agents(venv, group)
        episodes, seeds = _record_team(venv, norm if isinstance(norm, VecNormalize) else None, actor_for(venv),
                                       options)
    finally:
        venv.close()
    layout = (f"; multi-agent layout: each team episode is {len(agents)} consecutive episodes, one per agent in the "
              f"order {', '.join(agents)}")
    return Recorded(episodes, seeds, venv.observation_space, venv.action_space, None, layout)


@_collect_kind.register
def _game_collect_kind(kind: GameKind, exp: Experiment, ref: EnvRef, actor_for: Callable[[VecEnv], Policy],
                       options: CollectOptions, stats: Path | None, trust: bool) -> Recorded:
    """Turn-based games are not recorded yet."""
    raise UsageError(f"collect records single agents and teams; {ref.env_id} is a turn-based game (not recorded yet)")


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


def _record_team(venv: VecEnv, norm: VecNormalize | None, actor: Policy, options: CollectOptions
                 ) -> tuple[list[EpisodeRecorder], list[int]]:
    """Play team episodes on ``venv`` (one copy of a team of one group; team episode ``i`` reset with
    ``options.seed + i``): per team episode, every slot's agent's steps while it acted (``ACTED``), its own episode
    ending at its ``done`` (an agent still present when the team's episode ends is truncated there); the episodes
    and each one's reset seed."""
    assert options.episodes is not None
    reporter = ProgressReporter(options.episodes, bar=options.progress)
    episodes: list[EpisodeRecorder] = []
    seeds: list[int] = []
    n = venv.num_envs
    try:
        for i in range(options.episodes):
            venv.seed(options.seed + i)
            obs = venv.reset()
            recorders = [EpisodeRecorder() for _ in range(n)]
            for k, recorder in enumerate(recorders):
                recorder.start(slot(obs, k))
            ended = np.zeros(n, dtype=bool)
            state, start = None, np.ones(n, dtype=bool)
            while True:
                seen: Any = obs
                actions, state = actor(norm.normalize_obs(seen) if norm is not None else seen, state, start)
                start = np.zeros(n, dtype=bool)
                obs, rewards, dones, infos = venv.step(actions)
                for j in np.flatnonzero(~ended & acted_slots(infos)).tolist():
                    info = infos[j]
                    truncated = bool(info.get("TimeLimit.truncated", False))
                    last = info["terminal_observation"] if dones[j] else slot(obs, j)
                    recorders[j].step(np.asarray(actions)[j], last, float(rewards[j]),
                                      bool(dones[j]) and not truncated, truncated, info)
                    ended[j] |= bool(dones[j])
                if "episode" in infos[0] or ended.all():  # the team's episode is over
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
