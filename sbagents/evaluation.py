"""Evaluating a trained model: mean/std return, success rate and env-specific episode metrics."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

from sbagents.env_factory import make_eval_vec, make_vec, render_modes
from sbagents.env_ids import EnvRef, resolve_env
from sbagents.errors import UsageError
from sbagents.hyperparams import Experiment
from sbagents.rllib import evaluate_rllib_run, is_rllib_run
from sbagents.run_dir import find_run_dir
from sbagents.run_loading import load_run
from sbagents.text_render import ParallelTextStepPrinter, TextStepPrinter, supports_text


def _episode_metrics_fn(venv: VecEnv) -> Any:
    """The env's ``episode_metrics(step_infos) -> dict`` hook, if it has one."""
    try:
        return venv.get_attr("episode_metrics", [0])[0]
    except AttributeError:
        return None


def summarize(
    env_id: str,
    algo: str,
    returns: list[float],
    lengths: list[int],
    successes: list[bool],
    metrics: dict[str, list[float]],
) -> dict[str, Any]:
    """The evaluation summary dict (the ``evaluate --json`` contract of DESIGN.md)."""
    return {
        "env": env_id,
        "algo": algo,
        "n_episodes": len(returns),
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_length": float(np.mean(lengths)),
        "success_rate": float(np.mean(successes)) if successes else None,
        "metrics": {k: float(np.mean(v)) for k, v in metrics.items()},
    }


def evaluate_model(
    model: BaseAlgorithm,
    exp: Experiment,
    ref: EnvRef,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
    stats_path: Path | None = None,
    render: bool = False,
) -> dict[str, Any]:
    """Run ``n_episodes`` with ``model`` on a fresh env wrapped exactly as in training.

    :param stats_path: saved ``VecNormalize`` statistics of the run (frozen during evaluation).
    :return: the summary of :func:`summarize`.
    """
    if n_episodes < 1:
        raise UsageError(f"the number of evaluation episodes must be >= 1, got {n_episodes}")
    text = render and supports_text(render_modes(exp, ref))  # labelled text states, else the env's own 'human'
    extra = {"render_mode": "ansi" if text else "human"} if render else {}
    if ref.multi_agent:
        from sbagents.team_eval import evaluate_team

        vec_normalize = None
        if stats_path is not None and stats_path.exists():
            from stable_baselines3.common.vec_env import VecNormalize

            vec_normalize = VecNormalize.load(str(stats_path), make_vec(exp, ref, 1, seed))
        module = ref.pettingzoo_module()

        def env_fn() -> Any:
            env = module.parallel_env(**{**exp.env_kwargs, **extra})
            return ParallelTextStepPrinter(env) if text else env

        result = evaluate_team(model, env_fn, n_episodes=n_episodes, deterministic=deterministic, seed=seed,
                               render=render and not text, vec_normalize=vec_normalize)
        return {"env": ref.env_id, "algo": exp.algo, **result}
    # the reference envs (not the batched ones) render every step
    venv = make_eval_vec(exp, ref, 1, seed, stats_path, vec_env="dummy", env_kwargs=extra,
                         wrapper=TextStepPrinter if text else None)
    metrics_fn = _episode_metrics_fn(venv)
    step_infos: list[dict[str, Any]] = []
    successes: list[bool] = []
    metrics: dict[str, list[float]] = defaultdict(list)

    def on_step(locals_: dict[str, Any], _globals: dict[str, Any]) -> None:
        info = locals_["info"]
        step_infos.append(info)
        if locals_["done"]:
            if "is_success" in info:
                successes.append(bool(info["is_success"]))
            if metrics_fn is not None:
                for key, value in metrics_fn(step_infos).items():
                    metrics[key].append(value)
            step_infos.clear()

    try:
        returns, lengths = evaluate_policy(
            model,
            venv,
            n_eval_episodes=n_episodes,
            deterministic=deterministic,
            return_episode_rewards=True,
            callback=on_step,
            warn=False,
        )
    finally:
        venv.close()
    return summarize(ref.env_id, exp.algo, list(returns), list(lengths), successes, metrics)  # type: ignore[arg-type]


def evaluate(
    algo: str,
    env: str,
    log_folder: str | Path = "logs",
    exp_id: int = 0,
    load_best: bool = False,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = 0,
    render: bool = False,
    gym_packages: tuple[str, ...] = (),
    attacks: str | None = None,
    fairness: str | None = None,
    bins: int = 3,
) -> dict[str, Any]:
    """Evaluate a finished run of ``python -m sbagents.train`` (RL Zoo's ``enjoy``).

    :param attacks: attack spec (``"gaussian:0.05 pgd:0.1"``): adds ``adversarial`` rows to the summary and writes
        ``adversarial.csv``/``.png`` into the run dir.
    :param fairness: info keys to bucket episodes by: adds ``fairness`` and writes ``fairness.csv``/``.png``.
    """
    from sbagents.trust import parse_attacks, trust_report

    parse_attacks(attacks, "--attack")
    ref = resolve_env(env, gym_packages)
    run_dir = find_run_dir(log_folder, algo, ref.env_id, exp_id)
    if is_rllib_run(run_dir):  # python -m sbagents.train --backend rllib
        return evaluate_rllib_run(run_dir, algo, ref.env_id, n_episodes, deterministic, seed, render,
                                  {"--load-best": load_best, "--attack": attacks, "--fairness": fairness})
    run = load_run(algo, ref.env_id, log_folder, exp_id, load_best)
    exp, stats = run.experiment, run.stats_path
    summary = evaluate_model(run.model, exp, ref, n_episodes, deterministic, seed, stats, render=render)
    if attacks or fairness:
        summary.update(trust_report(run.model, exp, ref, stats, run.run_dir, attacks, fairness, bins,
                                    n_episodes, seed or 0))
    return summary
