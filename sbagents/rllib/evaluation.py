"""Evaluating an RLlib run: greedy team episodes with the checkpoint's RLModule(s), without starting Ray and without
unpickling the checkpoint (:mod:`sbagents.rllib.checkpoints`); a run on a Gymnasium env plays its episodes with
:func:`sbagents.rllib.single_agent.evaluate_single`.

The episodes are played by the same runner and summarized as the SB3 team evaluation
(:func:`sbagents.multiagent.team_eval.run_team_episodes`, :func:`~sbagents.multiagent.team_eval.team_summary`):
``mean_return`` is the team return (the sum of all agents' rewards), ``metrics`` has the per-agent and per-module
returns and the env's declared metrics.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from ray.rllib.core import Columns
from ray.rllib.core.rl_module.rl_module import RLModule
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.episodes import Policy, stateless
from sbagents.core.env_kinds import EnvKind, SingleAgentKind
from sbagents.core.env_names import EnvRef
from sbagents.core.options import EvaluateOptions
from sbagents.core.run_dir import load_run_config, run_groups
from sbagents.core.team_options import TeamOptions
from sbagents.errors import UsageError
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs
from sbagents.multiagent.team_eval import run_team_episodes, team_summary
from sbagents.rllib import CHECKPOINT_DIR, SHARED_MODULE
from sbagents.rllib.checkpoints import action_settings, load_modules
from sbagents.rllib.single_agent import SINGLE_MODULE, evaluate_single, module_policy, single_vec_env
from sbagents.visualize.text_render import ParallelTextStepPrinter, supports_text
from sbagents.visualize.video import record_policies


def module_groups(modules: Mapping[str, RLModule], agents: list[str], recorded: Mapping[str, list[str]] | None
                  ) -> dict[str, list[str]]:
    """Module id -> the agents it acts for: the run's recorded mapping, else (runs that recorded none) the shared
    module for every agent or one module per agent."""
    if recorded:
        return {str(m): list(a) for m, a in recorded.items()}
    if SHARED_MODULE in modules:
        return {SHARED_MODULE: list(agents)}
    missing = [a for a in agents if a not in modules]
    if missing:
        raise UsageError(f"the checkpoint has no module for {', '.join(missing)} (modules: {', '.join(modules)})")
    return {a: [a] for a in agents}


def module_actor(module: RLModule, deterministic: bool = True, rng: np.random.Generator | None = None
                 ) -> Callable[[np.ndarray], np.ndarray]:
    """``obs -> actions`` of an RLModule with Discrete actions, for a group's slots: observations
    ``(n_slots, obs_dim)`` in one forward pass -> actions ``(n_slots,)`` (greedy, or sampled from its logits)."""
    gen = rng if rng is not None else np.random.default_rng()

    def act(obs: np.ndarray) -> np.ndarray:
        batch = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        with torch.no_grad():
            logits = module.forward_inference({Columns.OBS: batch})[Columns.ACTION_DIST_INPUTS]
        if deterministic:
            return torch.argmax(logits, dim=-1).numpy()
        probs = torch.softmax(logits.double(), dim=-1).numpy()
        return np.array([gen.choice(len(p), p=p / p.sum()) for p in probs])

    return act


def evaluate_modules(
    modules: Mapping[str, RLModule], ref: EnvRef, env_kwargs: Mapping[str, Any], algo: str,
    groups: Mapping[str, list[str]] | None = None, options: EvaluateOptions | None = None,
) -> dict[str, Any]:
    """Play ``options.n_episodes`` team episodes (one team copy) with the modules and summarize them.

    :param groups: module id -> its agents (the run's ``args.yml``; None: shared or one module per agent).
    :return: the evaluation summary (team return, per-agent returns, the env's declared metrics).
    """
    options = options or EvaluateOptions()
    options.validate()
    text = False
    kwargs = dict(env_kwargs)
    if options.render:
        probe = ref.parallel_env(**kwargs)
        text = supports_text(probe.metadata.get("render_modes"))
        probe.close()
        kwargs["render_mode"] = "ansi" if text else "human"
    wrappers: list[tuple[Any, dict[str, Any]]] = [(ParallelTextStepPrinter, {})] if text else []
    factory = ParallelEnvFactory(ref.source, ref.modules, kwargs, wrappers)
    agents = [str(a) for a in factory().possible_agents]
    mapping = module_groups(modules, agents, groups)
    venvs = team_vec_envs(factory, 1, TeamOptions("per_group", mapping))
    try:
        for module_id, venv in venvs.items():
            if not isinstance(venv.action_space, spaces.Discrete):
                raise UsageError(f"RLlib evaluation supports Discrete actions; module {module_id} acts in "
                                 f"{venv.action_space}")
        rng = np.random.default_rng(options.seed)
        actors = {m: stateless(module_actor(modules[m], options.greedy(), rng)) for m in venvs}
        episodes = run_team_episodes(venvs, actors, options.n_episodes, options.seed)
    finally:
        for venv in venvs.values():
            venv.close()
    return {"env": ref.env_id, "algo": algo, **team_summary(episodes, mapping)}


def evaluate_checkpoint(
    checkpoint: str | Path, ref: EnvRef, algo: str, env_kwargs: Mapping[str, Any],
    groups: Mapping[str, list[str]] | None = None, options: EvaluateOptions | None = None, trust: bool = False,
) -> dict[str, Any]:
    """Evaluate the modules of an RLlib checkpoint on a fresh env ``ref`` built with ``env_kwargs``.

    The modules are rebuilt from the checkpoint's plain data (:func:`~sbagents.rllib.checkpoints.load_modules`);
    ``trust`` (``--trust-run``) lets an older checkpoint without it be unpickled by RLlib.
    """
    modules = load_modules(checkpoint, ref, env_kwargs, trust)
    return _evaluate_kind(ref.kind, modules, Path(checkpoint), ref, env_kwargs, algo, groups,
                          options or EvaluateOptions())


@functools.singledispatch
def _evaluate_kind(kind: EnvKind, modules: Mapping[str, RLModule], checkpoint: Path, ref: EnvRef,
                   env_kwargs: Mapping[str, Any], algo: str, groups: Mapping[str, list[str]] | None,
                   options: EvaluateOptions) -> dict[str, Any]:
    """A checkpoint's episodes on an env of ``kind``: greedy team episodes (:func:`evaluate_modules`)."""
    return evaluate_modules(modules, ref, env_kwargs, algo, groups, options)


@_evaluate_kind.register
def _evaluate_single_agent(kind: SingleAgentKind, modules: Mapping[str, RLModule], checkpoint: Path, ref: EnvRef,
                           env_kwargs: Mapping[str, Any], algo: str, groups: Mapping[str, list[str]] | None,
                           options: EvaluateOptions) -> dict[str, Any]:
    if SINGLE_MODULE not in modules:
        raise UsageError(f"{checkpoint} has no module {SINGLE_MODULE} (modules: {', '.join(modules)})")
    options.validate()
    return evaluate_single(modules[SINGLE_MODULE], ref, env_kwargs, algo, options, action_settings(checkpoint))


def evaluate_run(run_dir: str | Path, algo: str, ref: EnvRef, options: EvaluateOptions, trust: bool = False
                 ) -> dict[str, Any]:
    """Evaluate a finished (or interrupted) RLlib run dir of ``python -m sbagents.train --backend rllib``.

    :param trust: ``--trust-run``: a checkpoint of an older sbagents (no plain-data module files) may be unpickled.
    """
    run_dir = Path(run_dir)
    entry = load_run_config(run_dir, ref.env_id)
    return evaluate_checkpoint(run_dir / CHECKPOINT_DIR, ref, algo, entry.get("env_kwargs") or {},
                               run_groups(run_dir, ref.env_id), options, trust)


def record_run(run_dir: str | Path, algo: str, ref: EnvRef, n_steps: int, output_dir: str | Path | None, seed: int,
               deterministic: bool = True, fps: float | None = None, trust: bool = False) -> Path:
    """``record_video`` of an RLlib run: its modules (rebuilt from the checkpoint's plain data) act in one env copy
    rendering ``rgb_array`` frames (a Gymnasium env as its env runners built it; a team with every module acting),
    recorded by :func:`sbagents.visualize.video.record_policies`; the mp4's path."""
    run_dir = Path(run_dir)
    kwargs = dict(load_run_config(run_dir, ref.env_id).get("env_kwargs") or {})
    modules = load_modules(run_dir / CHECKPOINT_DIR, ref, kwargs, trust)
    venvs, policies = _recording_kind(ref.kind, modules, run_dir, ref, {**kwargs, "render_mode": "rgb_array"},
                                      deterministic)
    venvs[next(iter(venvs))].seed(seed)
    return record_policies(venvs, policies, ref, run_dir, algo, n_steps, output_dir, fps)


@functools.singledispatch
def _recording_kind(kind: EnvKind, modules: Mapping[str, RLModule], run_dir: Path, ref: EnvRef,
                    kwargs: dict[str, Any], deterministic: bool) -> tuple[dict[str, VecEnv], dict[str, Policy]]:
    """The VecEnvs (group -> one team copy's VecEnv) and policies of a recording: a team's modules."""
    factory = ParallelEnvFactory(ref.source, ref.modules, kwargs)
    mapping = module_groups(modules, [str(a) for a in factory().possible_agents], run_groups(run_dir, ref.env_id))
    venvs: dict[str, VecEnv] = dict(team_vec_envs(factory, 1, TeamOptions("per_group", mapping)))
    return venvs, {m: stateless(module_actor(modules[m], deterministic)) for m in venvs}


@_recording_kind.register
def _single_agent_recording(kind: SingleAgentKind, modules: Mapping[str, RLModule], run_dir: Path, ref: EnvRef,
                            kwargs: dict[str, Any], deterministic: bool
                            ) -> tuple[dict[str, VecEnv], dict[str, Policy]]:
    venv = single_vec_env(ref, kwargs)
    actor = module_policy(modules[SINGLE_MODULE], venv.action_space, deterministic,
                          action_settings(run_dir / CHECKPOINT_DIR))
    return {SINGLE_MODULE: venv}, {SINGLE_MODULE: stateless(actor)}
