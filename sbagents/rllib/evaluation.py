"""Evaluating an RLlib run: greedy team episodes with the checkpoint's RLModule(s), without starting Ray.

The episodes are played by the same runner and summarized as the SB3 team evaluation
(:func:`sbagents.multiagent.team_eval.evaluate_team`): ``env``, ``algo``, ``n_episodes``, ``mean_return``,
``std_return``, ``mean_length``, ``success_rate`` and ``metrics = {"treasures_per_episode", "team_return"}``;
team return = the sum of all agents' rewards.
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from pettingzoo import ParallelEnv
from ray.rllib.core import Columns
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModule
from ray.rllib.core.rl_module.rl_module import RLModule

from sbagents.errors import UsageError
from sbagents.multiagent.parameter_sharing import ParameterSharingVecEnv
from sbagents.multiagent.team_eval import evaluate_team
from sbagents.pipeline.env_names import PETTINGZOO_ENVS
from sbagents.pipeline.options import EvaluateOptions
from sbagents.pipeline.run_dir import load_run_config
from sbagents.rllib import CHECKPOINT_DIR, MODULE_SUBDIR, SHARED_MODULE
from sbagents.visualize.text_render import ParallelTextStepPrinter, supports_text


def load_modules(checkpoint: str | Path) -> dict[str, RLModule]:
    """The learner's RLModules of an RLlib checkpoint (``Algorithm.save_to_path``), by module id.

    Only reads files (``RLModule.from_checkpoint``): no Ray instance is started.
    """
    path = Path(checkpoint).joinpath(*MODULE_SUBDIR)
    if not path.is_dir():
        raise UsageError(f"{checkpoint} is not an RLlib checkpoint with a learner module ({path} is missing)")
    logger = logging.getLogger("ray._common.deprecation")  # RLlib's notice about its own RLModule constructor
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        multi = RLModule.from_checkpoint(str(path.resolve()))
    finally:
        logger.setLevel(level)
    if not isinstance(multi, MultiRLModule):
        raise UsageError(f"{path} holds a single-agent RLModule; sbagents RLlib runs save a MultiRLModule")
    modules = dict(multi.items())
    for module in modules.values():
        if isinstance(module, torch.nn.Module):  # TorchRLModule: inference mode for dropout/batch-norm layers
            module.eval()
    return modules


def module_for(agent: str, modules: Mapping[str, RLModule]) -> RLModule:
    """The module acting for ``agent``: its own (``policies: per_agent``) or the shared one."""
    if agent in modules:
        return modules[agent]
    if SHARED_MODULE in modules:
        return modules[SHARED_MODULE]
    raise UsageError(f"the checkpoint has no module for {agent} (modules: {', '.join(modules)})")


def act(
    modules: Mapping[str, RLModule],
    obs: Mapping[str, np.ndarray],
    deterministic: bool = True,
    rng: np.random.Generator | None = None,
) -> dict[str, int]:
    """Discrete actions for every agent in ``obs`` (one forward pass per module, agents batched).

    :param obs: agent id -> observation of shape ``(obs_dim,)``.
    :param deterministic: greedy (argmax of the logits) or sampled from the policy's distribution.
    :return: agent id -> action.
    """
    groups: dict[int, list[str]] = {}
    by_id: dict[int, RLModule] = {}
    for agent in obs:
        module = module_for(agent, modules)
        groups.setdefault(id(module), []).append(agent)
        by_id[id(module)] = module
    actions: dict[str, int] = {}
    for key, agents in groups.items():
        batch = torch.as_tensor(np.stack([obs[a] for a in agents]), dtype=torch.float32)
        with torch.no_grad():
            logits = by_id[key].forward_inference({Columns.OBS: batch})[Columns.ACTION_DIST_INPUTS]
        if deterministic:
            chosen = torch.argmax(logits, dim=-1).numpy()
        else:
            probs = torch.softmax(logits.double(), dim=-1).numpy()
            gen = rng if rng is not None else np.random.default_rng()
            chosen = np.array([gen.choice(len(p), p=p / p.sum()) for p in probs])
        actions.update({a: int(x) for a, x in zip(agents, chosen, strict=True)})
    return actions


def slot_actor(
    modules: Mapping[str, RLModule], agents: list[str], deterministic: bool = True,
    rng: np.random.Generator | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """An ``act`` for :func:`sbagents.callbacks.rollout.run_episodes` on a parameter-sharing VecEnv: observations
    ``(n_envs * n_agents, obs_dim)`` (slot ``k`` is ``agents[k % n_agents]``) -> actions ``(n_envs * n_agents,)``."""
    n = len(agents)

    def act_slots(obs: np.ndarray) -> np.ndarray:
        out = np.zeros(len(obs), dtype=np.int64)
        for base in range(0, len(obs), n):
            actions = act(modules, {a: obs[base + j] for j, a in enumerate(agents)}, deterministic, rng)
            out[base:base + n] = [actions[a] for a in agents]
        return out

    return act_slots


def evaluate_modules(
    modules: Mapping[str, RLModule],
    env_fn: Callable[[], ParallelEnv],
    env_id: str,
    algo: str,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
) -> dict[str, Any]:
    """Play ``n_episodes`` team episodes (one env, sequentially) with the modules and summarize them.

    :param seed: seed of the first reset (later resets continue the env's RNG) -> reproducible returns.
    """
    if n_episodes < 1:
        raise UsageError(f"the number of evaluation episodes must be >= 1, got {n_episodes}")
    venv = ParameterSharingVecEnv([env_fn])
    try:
        for agent in venv.possible_agents:
            space = venv.envs[0].action_space(agent)
            if not isinstance(space, spaces.Discrete):
                raise UsageError(f"RLlib evaluation supports Discrete actions; {agent} has {space}")
        actor = slot_actor(modules, list(venv.possible_agents), deterministic, np.random.default_rng(seed))
        result = evaluate_team(None, venv, n_episodes, deterministic, seed, act=actor)
    finally:
        venv.close()
    return {"env": env_id, "algo": algo, **result}


def _env_fn(env_id: str, env_kwargs: Mapping[str, Any], render: bool = False) -> Callable[[], ParallelEnv]:
    if env_id not in PETTINGZOO_ENVS:
        raise UsageError(f"RLlib runs are PettingZoo envs ({', '.join(PETTINGZOO_ENVS)}); got {env_id}")
    module = importlib.import_module(PETTINGZOO_ENVS[env_id])
    if not render:
        return lambda: module.parallel_env(**env_kwargs)
    text = supports_text(module.parallel_env(**env_kwargs).metadata.get("render_modes"))
    kwargs = {**env_kwargs, "render_mode": "ansi" if text else "human"}
    return lambda: ParallelTextStepPrinter(module.parallel_env(**kwargs)) if text else module.parallel_env(**kwargs)


def evaluate_checkpoint(
    checkpoint: str | Path, env_id: str, algo: str, env_kwargs: Mapping[str, Any],
    options: EvaluateOptions | None = None,
) -> dict[str, Any]:
    """Evaluate the modules of an RLlib checkpoint on a fresh ``env_id`` built with ``env_kwargs``."""
    options = options or EvaluateOptions()
    modules = load_modules(checkpoint)
    return evaluate_modules(modules, _env_fn(env_id, env_kwargs, options.render), env_id, algo, options.n_episodes,
                            options.deterministic, options.seed)


def evaluate_run(run_dir: str | Path, algo: str, env_id: str, options: EvaluateOptions) -> dict[str, Any]:
    """Evaluate a finished (or interrupted) RLlib run dir of ``python -m sbagents.train --backend rllib``."""
    run_dir = Path(run_dir)
    entry = load_run_config(run_dir, env_id)
    return evaluate_checkpoint(run_dir / CHECKPOINT_DIR, env_id, algo, entry.get("env_kwargs") or {}, options)
