"""Evaluating an RLlib run: greedy team episodes with the checkpoint's RLModule(s), without starting Ray.

The summary has the shape of :func:`sbagents.evaluation.summarize` / the SB3 team evaluation (``env``,
``algo``, ``n_episodes``, ``mean_return``, ``std_return``, ``mean_length``, ``success_rate`` and
``metrics = {"treasures_per_episode", "team_return"}``); team return = the sum of all agents' rewards.
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

from sbagents.env_ids import PETTINGZOO_ENVS
from sbagents.errors import UsageError
from sbagents.evaluation import summarize
from sbagents.rllib import CHECKPOINT_DIR, MODULE_SUBDIR, SHARED_MODULE
from sbagents.run_loading import load_run_config


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


def evaluate_modules(
    modules: Mapping[str, RLModule],
    env_fn: Callable[[], ParallelEnv],
    env_id: str,
    algo: str,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
) -> dict[str, Any]:
    """Run ``n_episodes`` team episodes (one env, sequentially) and summarize them.

    :param seed: seed of the first reset (later resets continue the env's RNG) -> reproducible returns.
    """
    if n_episodes < 1:
        raise UsageError(f"the number of evaluation episodes must be >= 1, got {n_episodes}")
    env = env_fn()
    for agent in env.possible_agents:
        if not isinstance(env.action_space(agent), spaces.Discrete):
            raise UsageError(f"RLlib evaluation supports Discrete actions; {agent} has {env.action_space(agent)}")
    rng = np.random.default_rng(seed)
    returns: list[float] = []
    lengths: list[int] = []
    successes: list[bool] = []
    treasures: list[float] = []
    try:
        for episode in range(n_episodes):
            obs, _ = env.reset(seed=seed if episode == 0 else None)
            total, length = 0.0, 0
            info: dict[str, Any] = {}
            while env.agents:
                obs, rewards, _, _, infos = env.step(act(modules, obs, deterministic, rng))
                total += float(sum(rewards.values()))
                length += 1
                info = next(iter(infos.values()), {})
            returns.append(total)
            lengths.append(length)
            successes.append(bool(info.get("is_success", False)))
            treasures.append(float(info.get("treasures_collected", np.nan)))
    finally:
        env.close()
    return summarize(env_id, algo, returns, lengths, successes,
                     {"treasures_per_episode": treasures, "team_return": returns})


def _env_fn(env_id: str, env_kwargs: Mapping[str, Any], render: bool = False) -> Callable[[], ParallelEnv]:
    if env_id not in PETTINGZOO_ENVS:
        raise UsageError(f"RLlib runs are PettingZoo envs ({', '.join(PETTINGZOO_ENVS)}); got {env_id}")
    module = importlib.import_module(PETTINGZOO_ENVS[env_id])
    kwargs = {**env_kwargs, **({"render_mode": "human"} if render else {})}
    return lambda: module.parallel_env(**kwargs)


def evaluate_checkpoint(
    checkpoint: str | Path,
    env_id: str,
    algo: str,
    env_kwargs: Mapping[str, Any],
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
    render: bool = False,
) -> dict[str, Any]:
    """Evaluate the modules of an RLlib checkpoint on a fresh ``env_id`` built with ``env_kwargs``."""
    modules = load_modules(checkpoint)
    return evaluate_modules(modules, _env_fn(env_id, env_kwargs, render), env_id, algo, n_episodes,
                            deterministic, seed)


def evaluate_run(
    run_dir: str | Path,
    algo: str,
    env_id: str,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
    render: bool = False,
) -> dict[str, Any]:
    """Evaluate a finished (or interrupted) RLlib run dir of ``python -m sbagents.train --backend rllib``."""
    run_dir = Path(run_dir)
    entry = load_run_config(run_dir, env_id)
    return evaluate_checkpoint(run_dir / CHECKPOINT_DIR, env_id, algo, entry.get("env_kwargs") or {}, n_episodes,
                               deterministic, seed, render)
