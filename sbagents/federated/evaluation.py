"""Evaluating a policy on homes: the comfort criterion share, success and energy use per home, and their means."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from sbagents.callbacks.episodes import model_actor, play_episodes
from sbagents.core.experiment import Experiment
from sbagents.envs.smart_home import SmartHomeEnv
from sbagents.federated.homes import Home
from sbagents.federated.local import make_env


def for_home(exp: Experiment, home: Home) -> Experiment:
    """``exp`` with ``home``'s user fixed in the env kwargs."""
    return replace(exp, env_kwargs={**exp.env_kwargs, **home.env_kwargs()})


def evaluate_home(model: BaseAlgorithm, exp: Experiment, home: Home, episodes: int, seed: int,
                  stats_path: Path | None = None) -> dict[str, float]:
    """``episodes`` greedy episodes of ``model`` in ``home`` (the env of ``exp``, bounds-normalized as in
    training): ``criterion_share`` (comfortable share of the steps after the warm-up), ``success_rate`` (episodes
    with share >= 0.97), ``mean_return`` and ``mean_energy``."""
    env = make_env(for_home(exp, home), seed, stats_path=stats_path)
    try:
        records = play_episodes(env, model_actor(model, deterministic=True), episodes, monitor_episodes=True,
                                episode_metrics=SmartHomeEnv.episode_metrics)
    finally:
        env.close()
    return {"criterion_share": float(np.mean([r.metrics["criterion_share"] for r in records])),
            "success_rate": float(np.mean([bool(r.success) for r in records])),
            "mean_return": float(np.mean([r.ret for r in records])),
            "mean_energy": float(np.mean([r.metrics.get("mean_energy", float("nan")) for r in records]))}


def evaluate_homes(model: BaseAlgorithm, exp: Experiment, homes: Sequence[Home], episodes: int, seed: int
                   ) -> dict[str, Any]:
    """:func:`evaluate_home` on each home, and the means over homes (``per_home`` keeps each)."""
    per_home = [{"home": h.index, "taste": h.taste, "preferred_temp": h.preferred_temp,
                 "preferred_light": h.preferred_light, **evaluate_home(model, exp, h, episodes, seed + h.index)}
                for h in homes]
    keys = ("criterion_share", "success_rate", "mean_return", "mean_energy")
    return {**{k: float(np.mean([r[k] for r in per_home])) for k in keys}, "per_home": per_home}
