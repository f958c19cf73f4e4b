"""An RLlib experiment: the zoo entry of ``zoo_configs/rllib_<algo>.yml`` split into RLlib's settings, and the
algorithm config (``PPOConfig``, ``APPOConfig``, ``IMPALAConfig``, ``DQNConfig``, ``SACConfig``; RLlib's new API
stack: RLModule / Learner / EnvRunner) built from it, for a PettingZoo team or a Gymnasium env
(:mod:`sbagents.rllib.single_agent`).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import torch
from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
from ray.rllib.env.multi_agent_env import MultiAgentEnv
from ray.tune.registry import register_env

from sbagents.core.env_kinds import EnvKind, SingleAgentKind, TeamKind
from sbagents.core.env_names import EnvRef, make_parallel_env
from sbagents.core.options import TrainSpec
from sbagents.core.team_options import TeamOptions
from sbagents.core.zoo_config import spec_entry
from sbagents.errors import UsageError
from sbagents.multiagent.groups import team_groups
from sbagents.rllib import SHARED_MODULE, check_kind_algo, rllib_algos
from sbagents.rllib.checkpoints import ALLOWED_MODULES
from sbagents.rllib.env_runner import LeanMultiAgentEnvRunner
from sbagents.rllib.single_agent import build_single_config
from sbagents.rllib.truncation import PettingZooEnv, keep_truncation

#: Zoo-entry keys that describe the experiment (the rest go to RLlib).
EXPERIMENT_KEYS = ("n_timesteps", "env_kwargs", "policies", "groups", "model")
#: Zoo-entry keys passed to ``AlgorithmConfig.env_runners``.
ENV_RUNNER_KEYS = ("num_env_runners", "num_envs_per_env_runner", "rollout_fragment_length", "batch_mode",
                   "gym_env_vectorize_mode")
#: Zoo-entry keys passed to ``AlgorithmConfig.environment`` (Gymnasium envs).
ENVIRONMENT_KEYS = ("clip_rewards", "normalize_actions", "clip_actions")
#: ``training()`` arguments of RLlib's configs that take code (classes, callables, connectors) or are deprecated:
#: never read from a config file.
CODE_TRAINING_KEYS = frozenset({"model", "optimizer", "learner_class", "learner_connector",
                                "add_default_connectors_to_learner_pipeline", "learner_config_dict",
                                "before_learn_on_batch", "num_sgd_iter", "train_batch_size",
                                "max_requests_in_flight_per_sampler_worker"})
#: Replay buffers a ``replay_buffer_config``'s ``type`` may name (RLlib's episode buffers of the new API stack).
REPLAY_BUFFERS = ("EpisodeReplayBuffer", "PrioritizedEpisodeReplayBuffer", "MultiAgentEpisodeReplayBuffer",
                  "MultiAgentPrioritizedEpisodeReplayBuffer")
POLICY_MODES = ("shared", "per_agent", "per_group")


def training_keys(algo: str) -> tuple[str, ...]:
    """Zoo-entry keys passed to the algorithm config's ``training()`` (``lr`` may be ``lin_<x>``: linear decay to
    0): the arguments of ``training()`` along its class hierarchy, less :data:`CODE_TRAINING_KEYS`."""
    names: dict[str, None] = {}
    for cls in ALLOWED_MODULES[algo][0].__mro__:
        if "training" in vars(cls):
            names.update(dict.fromkeys(p for p in inspect.signature(vars(cls)["training"]).parameters
                                       if p not in ("self", "kwargs")))
    return tuple(k for k in names if k not in CODE_TRAINING_KEYS)


@dataclass
class RllibExperiment:
    """A resolved RLlib experiment; ``hyperparams`` is the plain entry as written to ``config.yml``.

    :param n_timesteps: env steps to sample (one step of the parallel env = one step for every agent).
    :param policies: ``"shared"`` (one module for every agent), ``"per_agent"`` (one module per agent id) or
        ``"per_group"`` (one module per group: agent-name prefix, or the explicit ``groups`` mapping).
    """

    algo: str
    env_id: str
    n_timesteps: int
    env_kwargs: dict[str, Any]
    policies: str
    env_runners: dict[str, Any]
    training: dict[str, Any]
    model: dict[str, Any]
    hyperparams: dict[str, Any] = field(default_factory=dict)
    groups: dict[str, list[str]] | None = None
    environment: dict[str, Any] = field(default_factory=dict)

    @property
    def num_env_runners(self) -> int:
        """Env runner actors (0: sample in the driver process)."""
        return int(self.env_runners.get("num_env_runners", 2))


def resolve_entry(algo: str, env_id: str, entry: Mapping[str, Any], where: str) -> RllibExperiment:
    """Validate a zoo entry and split it into env runner, training and model settings.

    :param where: file and entry named in errors.
    """
    train_keys = training_keys(algo)
    accepted = (*EXPERIMENT_KEYS, *ENV_RUNNER_KEYS, *ENVIRONMENT_KEYS, *train_keys)
    unknown = sorted(set(entry) - set(accepted))
    if unknown:
        raise UsageError(f"{where}: unknown key(s) {', '.join(unknown)}; accepted: {', '.join(accepted)}")
    buffer = entry.get("replay_buffer_config")
    if buffer is not None and (not isinstance(buffer, dict) or buffer.get("type", REPLAY_BUFFERS[0])
                               not in REPLAY_BUFFERS):
        raise UsageError(f"{where}: replay_buffer_config is a mapping whose type (if given) is one of "
                         f"{', '.join(REPLAY_BUFFERS)}")
    policies = entry.get("policies", "shared")
    if policies not in POLICY_MODES:
        raise UsageError(f"{where}: policies must be one of {', '.join(POLICY_MODES)}, got {policies!r}")
    model = dict(entry.get("model") or {})
    model_fields = {f.name for f in dataclasses.fields(DefaultModelConfig)}
    if set(model) - model_fields:
        bad = ", ".join(sorted(set(model) - model_fields))
        raise UsageError(f"{where}: unknown model key(s) {bad}; accepted: {', '.join(sorted(model_fields))}")
    n_timesteps = int(entry.get("n_timesteps", 0))
    training = {k: entry[k] for k in train_keys if k in entry}
    lr = training.get("lr")
    if isinstance(lr, str):
        if not lr.startswith("lin_"):
            raise UsageError(f"{where}: lr must be a number or lin_<x>, got {lr!r}")
        try:
            start = float(lr[4:])
        except ValueError:
            raise UsageError(f"{where}: lr {lr!r} is not lin_<number>") from None
        training["lr"] = [[0, start], [max(n_timesteps, 1), 0.0]]
    runners = {k: entry[k] for k in ENV_RUNNER_KEYS if k in entry}
    if int(runners.get("num_env_runners", 2)) < 0:
        raise UsageError(f"{where}: num_env_runners must be >= 0")
    groups = entry.get("groups")
    if groups is not None and (policies != "per_group" or not isinstance(groups, dict)):
        raise UsageError(f"{where}: groups maps group names to agents, with policies: per_group")
    environment = {k: entry[k] for k in ENVIRONMENT_KEYS if k in entry}
    return RllibExperiment(algo, env_id, n_timesteps, dict(entry.get("env_kwargs") or {}), policies, runners,
                           training, model, dict(entry), groups, environment)


def build_experiment(spec: TrainSpec, ref: EnvRef, num_env_runners: int | None = None) -> RllibExperiment:
    """The entry for ``ref`` in ``zoo_configs/rllib_<algo>.yml`` (or ``spec.conf_file``) with the overrides.

    :param num_env_runners: overrides the entry's ``num_env_runners`` (``--num-env-runners``).
    """
    if spec.algo not in rllib_algos():
        raise UsageError(f"--backend rllib supports --algo {', '.join(rllib_algos())}; got {spec.algo!r}")
    ref.kind.refuse_backend(ref, "rllib")
    check_kind_algo(ref.kind, spec.algo)
    entry, where = spec_entry(spec, f"rllib_{spec.algo}", ref)
    if num_env_runners is not None:
        entry["num_env_runners"] = num_env_runners
    exp = resolve_entry(spec.algo, ref.env_id, entry, where)
    _check_kind_entry(ref.kind, exp, ref, where)
    if exp.n_timesteps < 1:
        raise UsageError(f"no n_timesteps for {spec.algo} on {ref.env_id} ({where}); pass -n N")
    return exp


def make_env(config: Mapping[str, Any]) -> MultiAgentEnv:
    """RLlib env creator (runs in every env runner): the PettingZoo env as a ``MultiAgentEnv``
    (:class:`~sbagents.rllib.truncation.PettingZooEnv`).

    :param config: ``source`` (``pkg.module`` or ``pkg.module:callable``), ``modules`` (to import first),
        ``env_kwargs`` and ``num_threads`` (torch threads of the env runner process; <= 0 keeps torch's default).
    """
    threads = int(config.get("num_threads", 1))
    if threads > 0 and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    env = make_parallel_env(config["source"], tuple(config.get("modules", ())), **config.get("env_kwargs", {}))
    return PettingZooEnv(env)


def _to_module(mapping: dict[str, str], agent_id: Any, episode: Any = None, **kwargs: Any) -> str:
    """``policy_mapping_fn``: the module of an agent (the mapping is bound with ``functools.partial``)."""
    return mapping[str(agent_id)]


def agent_modules(exp: RllibExperiment, agents: list[str]) -> dict[str, list[str]]:
    """Module id -> the agents it acts for (``shared``: one module; ``per_agent``: agent ids; ``per_group``:
    groups)."""
    if exp.policies == "shared":
        return {SHARED_MODULE: list(agents)}
    return team_groups(TeamOptions(exp.policies, exp.groups), agents)


def build_config(exp: RllibExperiment, ref: EnvRef, seed: int, num_threads: int = 1
                 ) -> tuple[AlgorithmConfig, dict[str, list[str]]]:
    """The RLlib algorithm config of ``exp`` on ``ref`` and its module -> agents mapping.

    A Gymnasium env: :func:`~sbagents.rllib.single_agent.build_single_config`. A PettingZoo team: one local learner
    in the driver, ``num_env_runners`` samplers of class :class:`~sbagents.rllib.env_runner.LeanMultiAgentEnvRunner`,
    one RLModule per module id of :func:`agent_modules`; with Discrete actions only, the env runners skip RLlib's
    action normalization (a copy of the integer actions on every step)."""
    try:
        return _kind_config(ref.kind, exp, ref, seed, num_threads)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid RLlib settings for {exp.algo} on {exp.env_id}: {exc}") from None


@functools.singledispatch
def _check_kind_entry(kind: EnvKind, exp: RllibExperiment, ref: EnvRef, where: str) -> None:
    """Refuse (one line) entry keys that do not apply to envs of ``kind``."""


@_check_kind_entry.register
def _check_single_entry(kind: SingleAgentKind, exp: RllibExperiment, ref: EnvRef, where: str) -> None:
    if exp.policies != "shared" or exp.groups:
        raise UsageError(f"{where}: policies and groups apply to PettingZoo teams; {ref.env_id} has one agent")


@_check_kind_entry.register
def _check_team_entry(kind: TeamKind, exp: RllibExperiment, ref: EnvRef, where: str) -> None:
    if exp.environment:
        raise UsageError(f"{where}: {', '.join(exp.environment)} apply to Gymnasium envs here")


@functools.singledispatch
def _kind_config(kind: EnvKind, exp: RllibExperiment, ref: EnvRef, seed: int, num_threads: int
                 ) -> tuple[AlgorithmConfig, dict[str, list[str]]]:
    raise UsageError(f"--backend rllib does not train {kind.name} envs ({ref.env_id})")


@_kind_config.register
def _single_config(kind: SingleAgentKind, exp: RllibExperiment, ref: EnvRef, seed: int, num_threads: int
                   ) -> tuple[AlgorithmConfig, dict[str, list[str]]]:
    return build_single_config(ALLOWED_MODULES[exp.algo][0], exp, ref, seed, num_threads)


@_kind_config.register
def _team_config(kind: TeamKind, exp: RllibExperiment, ref: EnvRef, seed: int, num_threads: int
                 ) -> tuple[AlgorithmConfig, dict[str, list[str]]]:
    """A PettingZoo team's config (see :func:`build_config`)."""
    try:
        probe = ref.parallel_env(**exp.env_kwargs)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid env_kwargs for {exp.env_id}: {exc}") from None
    agents = [str(a) for a in probe.possible_agents]
    modules = agent_modules(exp, agents)
    for module, members in modules.items():
        obs, act = probe.observation_space(members[0]), probe.action_space(members[0])
        if any(probe.observation_space(a) != obs or probe.action_space(a) != act for a in members):
            probe.close()
            raise UsageError(f"the agents of RLlib module {module} ({', '.join(members)}) have different spaces; "
                             "use policies: per_group or per_agent")
    discrete = all(isinstance(probe.action_space(a), gym.spaces.Discrete) for a in agents)
    probe.close()
    env_name = f"sbagents_{exp.env_id}"
    register_env(env_name, make_env)
    mapping = {a: m for m, members in modules.items() for a in members}
    env_config = {"source": ref.source, "modules": list(ref.modules), "env_kwargs": exp.env_kwargs,
                  "num_threads": num_threads}
    try:
        return (
            ALLOWED_MODULES[exp.algo][0]()
            # normalize_actions only copies Discrete actions (a deepcopy per step); the env gets the same ints
            .environment(env_name, env_config=env_config, normalize_actions=not discrete)
            .env_runners(**{"num_env_runners": 2, **exp.env_runners}, env_runner_cls=LeanMultiAgentEnvRunner)
            .learners(num_learners=0)
            .multi_agent(policies=set(modules), policy_mapping_fn=functools.partial(_to_module, mapping))
            .training(**exp.training)
            .callbacks(on_sample_end=keep_truncation)  # truncated agents stay truncated (sbagents.rllib.truncation)
            .rl_module(model_config=DefaultModelConfig(**exp.model))
            .debugging(seed=seed, log_level="ERROR")
        ), modules
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid RLlib settings for {exp.algo} on {exp.env_id}: {exc}") from None
