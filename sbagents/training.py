"""The ``train`` library function behind ``python -m sbagents.train``.

Flow (DESIGN.md): arguments + zoo config -> :class:`Experiment` -> env factory -> SB3 model + callbacks ->
run directory. Everything that can be checked is checked before the run dir is created; a setup failure
removes the half-made run dir; an interrupted run (Ctrl-C, SIGTERM) still saves its model and logs.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback, EvalCallback
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.algos import ALGOS, algos_for
from sbagents.config import default_config_path, lookup_entry
from sbagents.console import EvalReportCallback, ProgressCallback, ProgressReporter
from sbagents.env_factory import make_eval_vec, make_vec, normalize_for_training
from sbagents.env_ids import EnvRef, resolve_env
from sbagents.errors import UsageError
from sbagents.evaluation import evaluate_model
from sbagents.hyperparams import Experiment, resolve
from sbagents.run_dir import SUMMARY_FILE, VECNORMALIZE_FILE, create_run_dir, env_stem
from sbagents.run_loading import check_model_file, save_experiment
from sbagents.trust import TrustOptions, trust_callbacks, trust_results


@dataclass
class TrainResult:
    """What :func:`train` produced."""

    run_dir: Path
    model: BaseAlgorithm
    experiment: Experiment
    summary: dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False
    trust: dict[str, Any] = field(default_factory=dict)


def build_experiment(
    algo: str,
    ref: EnvRef,
    conf_file: str | Path | None = None,
    hyperparams: dict[str, Any] | None = None,
    n_timesteps: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> Experiment:
    """Look up the zoo entry for ``ref`` and apply the CLI overrides (``-params``, ``-n``, ``--env-kwargs``)."""
    if algo not in ALGOS:
        raise UsageError(f"unknown algo {algo!r}; available: {', '.join(ALGOS)}")
    if n_timesteps is not None and n_timesteps < 1:
        raise UsageError(f"-n/--n-timesteps must be a positive integer, got {n_timesteps}")
    path = Path(conf_file) if conf_file is not None else default_config_path(algo)
    if conf_file is not None and not path.exists():
        raise UsageError(f"config file {path} does not exist")
    entry = lookup_entry(path, ref.env_id, ref.is_atari)
    entry.update(hyperparams or {})
    if n_timesteps is not None:
        entry["n_timesteps"] = n_timesteps
    if env_kwargs:
        entry["env_kwargs"] = {**(entry.get("env_kwargs") or {}), **env_kwargs}
    return resolve(algo, ref.env_id, entry, f"{path}, entry for {ref.env_id}")


#: The smallest value each numeric run argument accepts (``log_interval`` also takes -1: automatic).
_MINIMUM = {"eval_episodes": 1, "n_eval_envs": 1, "final_eval_episodes": 0, "log_interval": 1}


def check_run_numbers(**values: int) -> None:
    """Raise :class:`UsageError` naming the CLI flag when a value is below its minimum in :data:`_MINIMUM`."""
    for name, value in values.items():
        low = _MINIMUM[name]
        if value < low and not (name == "log_interval" and value == -1):
            also = " or -1 (automatic)" if name == "log_interval" else ""
            raise UsageError(f"--{name.replace('_', '-')} must be >= {low}{also}, got {value}")


def check_device(device: str) -> None:
    """Raise :class:`UsageError` unless ``device`` is ``auto`` or a torch device name (``cpu``, ``cuda:0``)."""
    if device == "auto":
        return
    try:
        torch.device(device)
    except (RuntimeError, TypeError):
        raise UsageError(f"--device {device!r} is not a torch device; use auto, cpu, cuda or cuda:N") from None


def check_spaces(exp: Experiment, ref: EnvRef) -> tuple[spaces.Space, spaces.Space]:
    """Build one env to read its spaces; raise :class:`UsageError` if the algorithm cannot handle them."""
    probe = make_vec(exp, ref, 1, seed=None)
    obs_space, act_space = probe.observation_space, probe.action_space
    probe.close()
    if not ALGOS[exp.algo].supports(obs_space, act_space):
        able = ", ".join(algos_for(obs_space, act_space)) or "none"
        raise UsageError(
            f"{exp.algo} cannot learn {ref.env_id} (observation {type(obs_space).__name__}, "
            f"action {type(act_space).__name__}); algos that can: {able}"
        )
    return obs_space, act_space


def make_model(
    exp: Experiment, env: VecEnv, seed: int, device: str, tensorboard_log: str | None, verbose: int,
    trained_agent: Path | None = None,
) -> BaseAlgorithm:
    """The SB3 model of ``exp`` on ``env`` (with its action noise), or ``trained_agent`` loaded to continue.

    Hyperparameters the algorithm rejects raise :class:`UsageError`.
    """
    cls = ALGOS[exp.algo].cls
    if trained_agent is not None:
        return cls.load(str(trained_agent), env=env, device=device, tensorboard_log=tensorboard_log, verbose=verbose)
    kwargs = dict(exp.algo_kwargs)
    if exp.noise_type is not None and isinstance(env.action_space, spaces.Box):
        kwargs["action_noise"] = exp.action_noise(int(np.prod(env.action_space.shape)))
    try:
        return cls(exp.policy, env, seed=seed, device=device, tensorboard_log=tensorboard_log, verbose=verbose,
                   **kwargs)
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        raise UsageError(f"invalid hyperparameters for {exp.algo} on {exp.env_id}: {exc}") from None


def _callbacks(
    exp: Experiment, ref: EnvRef, run_dir: Path, train_env: VecEnv, seed: int, eval_freq: int,
    eval_episodes: int, n_eval_envs: int, save_freq: int, reporter: ProgressReporter,
) -> list[BaseCallback]:
    callbacks: list[BaseCallback] = [ProgressCallback(reporter)]
    n_vec = train_env.num_envs
    if eval_freq > 0:
        freq = max(eval_freq // n_vec, 1)
        if ref.multi_agent:
            from sbagents.team_eval import TeamEvalCallback

            callbacks.append(
                TeamEvalCallback(
                    lambda: ref.pettingzoo_module().parallel_env(**exp.env_kwargs),
                    n_eval_episodes=eval_episodes, eval_freq=freq, seed=seed + 10_000,
                    best_model_save_path=str(run_dir), log_path=str(run_dir), verbose=0,
                    callback_after_eval=EvalReportCallback(reporter),
                )
            )
        else:
            callbacks.append(
                EvalCallback(make_eval_vec(exp, ref, n_eval_envs, seed + 10_000), n_eval_episodes=eval_episodes,
                             eval_freq=freq, log_path=str(run_dir), best_model_save_path=str(run_dir),
                             deterministic=True, verbose=0, callback_after_eval=EvalReportCallback(reporter))
            )
    if save_freq > 0:
        callbacks.append(
            CheckpointCallback(max(save_freq // n_vec, 1), str(run_dir), name_prefix="rl_model",
                               save_vecnormalize=True)
        )
    callbacks.extend(cb(**kw) for cb, kw in exp.callbacks)
    return callbacks


def train(
    algo: str,
    env: str,
    *,
    n_timesteps: int | None = None,
    log_folder: str | Path = "logs",
    seed: int = -1,
    hyperparams: dict[str, Any] | None = None,
    conf_file: str | Path | None = None,
    env_kwargs: dict[str, Any] | None = None,
    eval_freq: int | None = None,
    eval_episodes: int = 5,
    n_eval_envs: int = 1,
    final_eval_episodes: int = 10,
    save_freq: int = -1,
    vec_env: str = "auto",
    device: str = "auto",
    progress: bool | None = None,
    tensorboard_log: str | None = None,
    trained_agent: str | Path | None = None,
    verbose: int = 1,
    num_threads: int = 1,
    log_interval: int = -1,
    gym_packages: Sequence[str] = (),
    callbacks: Sequence[BaseCallback] = (),
    trust: TrustOptions | None = None,
    command: str = "",
) -> TrainResult:
    """Train ``algo`` on ``env`` with its zoo config and write a run directory.

    :param eval_freq: env steps between evaluations (default: a tenth of the budget, at most 25,000;
        <= 0 disables periodic evaluation).
    :param final_eval_episodes: episodes of the final evaluation stored in ``summary.json`` (0 skips it).
    :param progress: show a progress bar (None: when stderr is a terminal).
    :param verbose: 0 prints nothing, 1 a progress bar and one line per evaluation, 2 also SB3's log tables.
    :param num_threads: torch threads (1 is far faster for small networks on few cores).
    :param trust: transparency log, safety counting, adversarial and fairness evaluation to add.
    :param log_interval: episodes (off-policy/tabular) or rollouts (on-policy) between log dumps;
        -1 picks 100 episodes or 1 rollout.
    :return: the run dir, the model and the summary; ``interrupted`` is True after Ctrl-C/SIGTERM.
    """
    check_run_numbers(eval_episodes=eval_episodes, n_eval_envs=n_eval_envs,
                      final_eval_episodes=final_eval_episodes, log_interval=log_interval)
    check_device(device)
    if num_threads > 0:
        torch.set_num_threads(num_threads)
    ref = resolve_env(env, tuple(gym_packages))
    exp = build_experiment(algo, ref, conf_file, hyperparams, n_timesteps, env_kwargs)
    check_spaces(exp, ref)
    if exp.n_timesteps == 0:
        raise UsageError(f"no n_timesteps for {algo} on {ref.env_id} in its config; pass -n N")
    agent_path = check_model_file(trained_agent) if trained_agent is not None else None
    trust = trust or TrustOptions()
    trust.validate()
    if seed < 0:
        seed = int(np.random.default_rng().integers(2**31 - 1))
    if eval_freq is None:
        eval_freq = min(25_000, max(exp.n_timesteps // 10, 1))
    run_dir = create_run_dir(log_folder, algo, ref.env_id)
    try:
        set_random_seed(seed)
        args = {"algo": algo, "env": ref.env_id, "seed": seed, "n_timesteps": exp.n_timesteps,
                "log_folder": str(log_folder), "eval_freq": eval_freq, "eval_episodes": eval_episodes,
                "vec_env": vec_env, "device": device, "trained_agent": str(agent_path) if agent_path else None}
        save_experiment(run_dir, exp, args, command or f"python -m sbagents.train --algo {algo} --env {env}")
        stats = agent_path.parent / VECNORMALIZE_FILE if agent_path is not None else None
        train_env = normalize_for_training(make_vec(exp, ref, exp.n_envs, seed, run_dir, vec_env), exp, stats)
        model = make_model(exp, train_env, seed, device, tensorboard_log, max(verbose - 1, 0), agent_path)
        reporter = ProgressReporter(exp.n_timesteps, bar=progress, quiet=verbose <= 0)
        cbs = _callbacks(exp, ref, run_dir, train_env, seed, eval_freq, eval_episodes, n_eval_envs, save_freq,
                         reporter)
        trust_cbs = trust_callbacks(trust, exp, ref, run_dir, train_env, seed, eval_freq, eval_episodes, model)
    except BaseException:
        shutil.rmtree(run_dir, ignore_errors=True)
        raise
    if log_interval < 0:
        log_interval = 1 if hasattr(model, "n_steps") else 100
    try:
        result = _learn_and_save(model, exp, ref, run_dir, train_env, [*cbs, *trust_cbs, *callbacks], seed,
                                 agent_path is not None, final_eval_episodes, log_interval)
    finally:
        reporter.close()
    result.trust = trust_results(trust_cbs)
    return result


def _learn_and_save(
    model: BaseAlgorithm, exp: Experiment, ref: EnvRef, run_dir: Path, train_env: VecEnv,
    callbacks: list[BaseCallback], seed: int, resume: bool, final_eval_episodes: int, log_interval: int,
) -> TrainResult:
    interrupted = False
    start, cpu_start = time.perf_counter(), time.process_time()
    steps_before = model.num_timesteps if resume else 0
    try:
        model.learn(exp.n_timesteps, callback=callbacks, reset_num_timesteps=not resume, log_interval=log_interval)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
        model.save(str(run_dir / f"{env_stem(ref.env_id)}.zip"))
        if isinstance(train_env, VecNormalize):
            train_env.save(str(run_dir / VECNORMALIZE_FILE))
        with contextlib.suppress(EOFError, BrokenPipeError, ConnectionResetError):
            train_env.close()  # SubprocVecEnv workers may already be gone after Ctrl-C
    steps = model.num_timesteps - steps_before
    summary: dict[str, Any] = {
        "algo": exp.algo, "env": ref.env_id, "seed": seed, "n_timesteps": int(model.num_timesteps),
        "train_seconds": round(seconds, 3), "train_cpu_seconds": round(cpu_seconds, 3),
        "fps": round(steps / max(seconds, 1e-9), 1),
        "interrupted": interrupted, "eval": None,
    }
    (run_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    if not interrupted and final_eval_episodes > 0:
        summary["eval"] = evaluate_model(
            model, exp, ref, final_eval_episodes, True, seed, run_dir / VECNORMALIZE_FILE
        )
        (run_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    return TrainResult(run_dir, model, exp, summary, interrupted)
