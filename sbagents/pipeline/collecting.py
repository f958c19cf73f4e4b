"""Recording episodes into a dataset (``python -m sbagents.collect``): a baseline (random, or the env's scripted
expert) or a finished run acts on one copy of the env, and :mod:`sbagents.datasets.writing` stores the episodes in
Minari's format.

What a dataset records is what the acting policy sees before normalization: the plain env's observations for a
baseline; for a run, its env as training wrapped it (env wrappers, frame stack), with the run's ``VecNormalize``
statistics applied to the policy's input only. Rewards are the env's own (never normalized).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.baselines.policies import slot
from sbagents.callbacks.episodes import Policy, model_actor
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.progress import ProgressReporter
from sbagents.core.run_dir import RunRef, load_run
from sbagents.datasets.writing import DatasetInfo, EpisodeRecorder, check_dataset_id, require_minari, write_dataset
from sbagents.env_factory import make_vec, normalize_for_eval
from sbagents.errors import UsageError
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

    Either ``policy`` (``random`` or ``scripted``, on ``env``) or ``run`` (a finished single-agent SB3 run, greedy)
    acts, or ``log`` (a transparency log of a run on ``env``) gives the episodes (:mod:`sbagents.datasets.logs`).

    :raises UsageError: (one line) not exactly one of ``policy``, ``run`` and ``log``, an env that is not a single
        Gymnasium agent (teams and games are not recorded yet), an env without a scripted expert, a log that does not
        fit the env, a dataset that exists, or Minari missing.
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
        venv, norm = _run_env(exp, ref, options.seed, loaded.stats_path, loaded.trust)
        actor = model_actor(loaded.model, exp.deterministic_eval)
        algorithm = f"{exp.algo} ({loaded.run_dir})"
    else:
        assert env is not None and policy is not None
        ref = env
        exp = baseline_experiment(ref, policy, env_kwargs)
        venv, norm = _check_one_agent(make_vec(exp, ref, 1, options.seed, vec_env="dummy"), ref), None
        actor = baseline_actor(policy, ref.env_id, venv, options.seed)
        algorithm = str(policy)
    try:
        episodes = _record(venv, norm, actor, options)
    finally:
        venv.close()
    info = DatasetInfo(algorithm, *_reference_scores(ref, options, env_kwargs),
                       description=f"{options.episodes} episodes of {ref.env_id} played by {algorithm}, recorded by "
                                   f"python -m sbagents.collect (reset seeds {options.seed}..."
                                   f"{options.seed + options.episodes - 1})")
    seeds = [options.seed + i for i in range(options.episodes)]
    return write_dataset(options.dataset, episodes, seeds, ref.env_id, info, venv.observation_space,
                         venv.action_space), len(episodes)


def _from_log(options: CollectOptions, ref: EnvRef, log: Path, env_kwargs: dict[str, Any] | None
              ) -> tuple[Path, int]:
    """The complete episodes of the transparency log ``log`` of a run on ``ref``'s plain env."""
    from sbagents.datasets.logs import episodes_from_log, log_description

    exp = baseline_experiment(ref, "random", env_kwargs)
    venv = _check_one_agent(make_vec(exp, ref, 1, options.seed, vec_env="dummy"), ref)
    obs_space, action_space = venv.observation_space, venv.action_space
    venv.close()
    episodes, dropped = episodes_from_log(log, obs_space, action_space, options.episodes)
    info = DatasetInfo(f"transparency log {log.name}", *_reference_scores(ref, options, env_kwargs),
                       description=log_description(log, len(episodes), dropped))
    return write_dataset(options.dataset, episodes, [None] * len(episodes), ref.env_id, info, obs_space,
                         action_space), len(episodes)


def _check_one_agent(venv: VecEnv, ref: EnvRef) -> VecEnv:
    """``venv`` if one copy of the env is one agent acting without action masks; else closed, and one line."""
    if venv.num_envs != 1 or venv.has_attr("action_masks"):
        venv.close()
        raise UsageError(f"collect records single Gymnasium agents for now; {ref.env_id} is a {ref.kind.name} env "
                         "(teams and turn-based games are not recorded yet)")
    return venv


def _run_env(exp: Experiment, ref: EnvRef, seed: int, stats: Path | None, trust: bool
             ) -> tuple[VecEnv, VecNormalize | None]:
    """The run's env as training wrapped it, and its frozen statistics (applied to the policy's input only)."""
    venv = _check_one_agent(make_vec(exp, ref, 1, seed, vec_env="dummy"), ref)
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
