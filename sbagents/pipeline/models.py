"""The SB3 model of an experiment: checking the algorithm fits the env's spaces, then building (or loading) it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sbagents.algos import ALGOS, algos_for, algos_with
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.extensions import ActiveExtension
from sbagents.core.team_options import TeamOptions
from sbagents.env_factory import make_eval_vec, make_team_vecs, make_vec
from sbagents.errors import UsageError
from sbagents.multiagent.centralized import CentralizedCriticPolicy
from sbagents.multiagent.masking import MaskedDictRolloutBuffer, MaskedReplayBuffer, MaskedRolloutBuffer
from sbagents.safe_load import load_model, record_spaces


def check_spaces(exp: Experiment, ref: EnvRef) -> tuple[spaces.Space, spaces.Space]:
    """Build one env to read its spaces; raise :class:`UsageError` if the algorithm cannot handle them."""
    probe = make_vec(exp, ref, 1, seed=None)
    obs_space, act_space = probe.observation_space, probe.action_space
    masks = ref.kind.masked or probe.has_attr("action_masks")
    probe.close()
    if ALGOS[exp.algo].masked != masks:
        able = ", ".join(algos_for(obs_space, act_space, masks)) or "none"
        if masks:
            raise UsageError(f"{ref.env_id} is a turn-based game with action masks: it trains with {able} (masks "
                             f"drive every move), not {exp.algo}")
        raise UsageError(f"{exp.algo} acts with action masks and {ref.env_id} has none (turn-based PettingZoo "
                         f"games with {{observation, action_mask}} observations do); algos that fit: {able}")
    _check_supported(exp, ref.env_id, obs_space, act_space, masks)
    return obs_space, act_space


def check_group_spaces(exp: Experiment, ref: EnvRef) -> None:
    """:func:`check_spaces` for a run of one model per group: one team copy is built to read each group's spaces;
    :class:`UsageError` names the group whose spaces the algorithm cannot act in."""
    venvs = make_team_vecs(exp, ref, 1, None, vec_env="dummy")
    try:
        for group, venv in venvs.items():
            _check_supported(exp, f"group {group} of {exp.env_id}", venv.observation_space, venv.action_space)
    finally:
        next(iter(venvs.values())).close()


def _check_supported(exp: Experiment, what: str, obs_space: spaces.Space, act_space: spaces.Space,
                     masks: bool = False) -> None:
    """Raise :class:`UsageError` naming ``what`` and the algorithms that can, unless ``exp.algo`` acts in these
    spaces."""
    if not ALGOS[exp.algo].supports(obs_space, act_space):
        able = ", ".join(algos_for(obs_space, act_space, masks)) or "none"
        raise UsageError(f"{exp.algo} cannot learn {what} (observation {type(obs_space).__name__}, "
                         f"action {type(act_space).__name__}); algos that can: {able}")


@dataclass(frozen=True)
class Resume:
    """A model to continue training (``-i``).

    :param path: the model ``.zip``.
    :param trust: its file may hold pickles beyond plain data (``--trust-run``; :mod:`sbagents.safe_load`).
    :param stats: the ``VecNormalize`` statistics saved with it (the file may not exist: a model that does not
        normalize; None: none).
    """

    path: Path
    trust: bool = False
    stats: Path | None = None


def make_model(
    exp: Experiment, env: VecEnv, seed: int, device: str = "auto", *, tensorboard_log: str | None = None,
    verbose: int = 0, resume: Resume | None = None, extensions: Sequence[ActiveExtension] = (),
) -> BaseAlgorithm:
    """The SB3 model of ``exp`` on ``env`` (with its action noise), or the model ``resume`` names, loaded to continue.

    :param verbose: SB3's own verbosity (1 prints its log tables).
    :param extensions: the run's training extensions, whose contributions may pick the class, add keyword arguments
        and load the resumed model their own way (:class:`~sbagents.extensions.Contribution`).
    :raises UsageError: hyperparameters the algorithm rejects.
    """
    cls: Any = ALGOS[exp.algo].cls
    extra: dict[str, Any] = {}
    for contribution in (active.contribution for active in extensions):
        cls = contribution.model_class or cls
        extra.update(contribution.model_kwargs)
    kwargs = {**exp.algo_kwargs, **extra}
    if exp.noise_type is not None and isinstance(env.action_space, spaces.Box):
        kwargs["action_noise"] = exp.action_noise(int(np.prod(env.action_space.shape)))
    policy = model_policy(exp.env_kind, exp, kwargs, isinstance(env.observation_space, spaces.Dict))
    if resume is not None:
        common: dict[str, Any] = dict(env=env, device=device, trust=resume.trust, tensorboard_log=tensorboard_log,
                                      verbose=verbose, hyperparams={**kwargs, "policy": policy})
        load = next((a.contribution.load for a in extensions if a.contribution.load is not None), load_model)
        return load(cls, resume.path, **common, **extra)
    try:
        model = cls(policy, env, seed=seed, device=device, tensorboard_log=tensorboard_log, verbose=verbose, **kwargs)
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        raise UsageError(f"invalid hyperparameters for {exp.algo} on {exp.env_id}: {exc}") from None
    record_spaces(model)  # saved with it: loading rebuilds the spaces from plain data
    return model


@kind_operation(GameKind)
def model_policy(kind: EnvKind, exp: Experiment, kwargs: dict[str, Any], dict_obs: bool) -> Any:
    """The policy the model of ``exp`` is built with; may complete the model's keyword arguments ``kwargs``
    (default: the experiment's policy).

    :param dict_obs: the model's observations are a ``Dict`` space.
    """
    return exp.policy


@model_policy.register
def _team_model_policy(kind: TeamKind, exp: Experiment, kwargs: dict[str, Any], dict_obs: bool) -> Any:
    """A team: death masking (buffers that skip absent agents' transitions) and the centralized critic, for a PettingZoo
    experiment; returns the policy to use and completes ``kwargs``. A recurrent algorithm (``ppo_lstm``) keeps
    sb3-contrib's sequence buffer: an agent that leaves before its team's episode ends adds its padded steps.

    :raises UsageError: an off-policy algorithm on Dict observations (no masked Dict replay buffer yet).
    """
    team = TeamOptions.of(exp)
    on_policy = issubclass(ALGOS[exp.algo].cls, OnPolicyAlgorithm)
    centralized = team.critic == "centralized"
    if centralized and exp.algo not in algos_with("centralized_critic"):
        raise UsageError(f"critic: centralized is for {' and '.join(algos_with('centralized_critic'))} (a value "
                         f"function to centralize), not {exp.algo}")
    if on_policy and not ALGOS[exp.algo].recurrent:  # a recurrent algorithm keeps its own sequence buffer
        kwargs.setdefault("rollout_buffer_class", MaskedDictRolloutBuffer if dict_obs else MaskedRolloutBuffer)
    elif ALGOS[exp.algo].off_policy and dict_obs and "replay_buffer_class" not in kwargs:
        raise UsageError(f"{exp.algo} on a PettingZoo env with Dict observations is not supported (absent agents "
                         "would reach its replay buffer); use ppo or a2c")
    elif ALGOS[exp.algo].off_policy:
        kwargs.setdefault("replay_buffer_class", MaskedReplayBuffer)
    return CentralizedCriticPolicy if centralized else exp.policy


@dataclass
class RunContext:
    """What the callbacks of an SB3 run are built from (the :class:`~sbagents.extensions.TrainingContext` the
    training extensions see).

    :param eval_freq: env steps between periodic evaluations (resolved: <= 0 means none).
    :param eval_episodes: episodes per periodic evaluation.
    :param trained_agent: the model ``-i`` continues (None: a new one).
    :param trust_run: ``--trust-run``: files beside ``trained_agent`` may hold pickles.
    :param save_freq: env steps between checkpoints (<= 0: none).
    :param state: the extensions' per-run scratch space.
    :param group: the group of agents this model acts for in a run of one model per group (None: the run's one
        model); :meth:`file_name` suffixes the files it writes with it.
    :param steps_per_call: the run's timesteps per call of this model's callbacks, where that is not
        ``train_env.num_envs``: a group's model is called once per step of the whole team, whose agents in every
        group count (None: ``train_env.num_envs``).
    """

    exp: Experiment
    ref: EnvRef
    run_dir: Path
    train_env: VecEnv
    model: BaseAlgorithm
    seed: int
    eval_freq: int
    eval_episodes: int
    trained_agent: Path | None = None
    trust_run: bool = False
    save_freq: int = -1
    state: dict[str, Any] = field(default_factory=dict)
    group: str | None = None
    steps_per_call: int | None = None

    @property
    def timestep_scale(self) -> float:
        """The run's timesteps per timestep of this model (the team's agents per agent of a group's model; 1 for the
        run's one model)."""
        return (self.steps_per_call or self.train_env.num_envs) / self.train_env.num_envs

    def make_eval_env(self, n_envs: int, seed: int | None) -> VecEnv:
        """A fresh evaluation vec env of the run's env.

        :raises UsageError: a model of one group (its agents step only with the other groups' models).
        """
        if self.group is not None:
            raise UsageError(f"group {self.group}'s model acts only on a team with the other groups' models: an "
                             "evaluation env of its own needs policies: shared (one model)")
        return make_eval_vec(self.exp, self.ref, n_envs, seed)

    def file_name(self, name: str) -> str:
        """``name`` of a file this model's run writes: ``safety.json`` -> ``safety.<group>.json`` for a group's
        model (the suffix goes before the first extension), unchanged for the run's one model."""
        if self.group is None:
            return name
        stem, dot, ext = name.partition(".")
        return f"{stem}.{self.group}{dot}{ext}"

    def calls(self, env_steps: int) -> int:
        """An env-step period as callback calls (one call per vec step of ``train_env``: :attr:`steps_per_call`
        timesteps), at least 1."""
        return max(env_steps // (self.steps_per_call or self.train_env.num_envs), 1)

    def eval_calls(self) -> int:
        """The evaluation period as callback calls: :meth:`calls` of ``eval_freq``, and at least one rollout
        (``n_steps`` calls) for an on-policy model, whose policy changes only between rollouts (a small budget would
        otherwise evaluate the same policy many times per rollout)."""
        calls = self.calls(self.eval_freq)
        return max(calls, self.model.n_steps) if isinstance(self.model, OnPolicyAlgorithm) else calls
