"""Training a Gymnasium env or a PettingZoo team with Ray RLlib: :func:`train_rllib` (``python -m sbagents.train
--backend rllib``).

Flow: :class:`TrainSpec` + ``zoo_configs/rllib_<algo>.yml`` -> :class:`~sbagents.rllib.experiment.RllibExperiment`
-> RLlib ``AlgorithmConfig`` -> Ray (a local instance sized for this machine, or the cluster at ``address``) -> run
dir with ``rllib_checkpoint/``, ``progress.csv``, ``summary.json`` and, with ``--save-freq N``, a module checkpoint
``checkpoint_<env steps>/`` every N env steps (:func:`save_module_checkpoint`), through the same run life as SB3
runs (:mod:`sbagents.core.lifecycle`). Every checkpoint is written to a hidden folder and renamed into place, with
its modules as plain data (:mod:`sbagents.rllib.checkpoints`). Ctrl-C / SIGTERM stop training but still leave a
checkpoint and ``summary.json`` (``interrupted: true``); Ray is shut down in every case.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import logging
import math
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import ray
import torch

from sbagents.core.env_kinds import EnvKind, TeamKind
from sbagents.core.env_names import EnvRef, resolve_env
from sbagents.core.lifecycle import (
    LearningClock,
    TrainResult,
    base_summary,
    default_command,
    draw_seed,
    finish_run,
    new_run_dir,
)
from sbagents.core.options import EvalOptions, EvaluateOptions, ExecOptions, OutputOptions, RllibOptions, TrainSpec
from sbagents.core.progress import ProgressReporter
from sbagents.errors import UsageError
from sbagents.multiagent.env_copy import declared_metrics
from sbagents.rllib import CHECKPOINT_DIR, CHECKPOINT_PREFIX, PROGRESS_FILE, check_address
from sbagents.rllib.checkpoints import save_checkpoint
from sbagents.rllib.evaluation import evaluate_checkpoint
from sbagents.rllib.experiment import RllibExperiment, build_config, build_experiment

_OBJECT_STORE_BYTES = 256 * 1024**2  # the rollouts here are small; Ray's default takes 30% of the RAM


@contextlib.contextmanager
def ray_session(address: str | None, num_env_runners: int, num_threads: int = 1, verbose: int = 1) -> Iterator[None]:
    """Connect to the Ray cluster at ``address`` or start a local instance; shut it down on exit.

    The local instance has ``num_env_runners + 1`` logical CPUs (one per env runner, one for the driver's
    learner), no dashboard and a 256 MB object store. An already initialized Ray is reused and left running.
    Ray's SIGTERM handler is replaced by the caller's again (so SIGTERM still means "stop and save").
    """
    if ray.is_initialized():
        yield
        return
    kwargs: dict[str, Any] = {"log_to_driver": verbose >= 2, "logging_level": logging.INFO if verbose > 1 else 40}
    if num_threads > 0:
        kwargs["runtime_env"] = {"env_vars": {"OMP_NUM_THREADS": str(num_threads)}}
    if address is None:
        kwargs.update(num_cpus=num_env_runners + 1, include_dashboard=False, object_store_memory=_OBJECT_STORE_BYTES)
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main else None
    try:
        ray.init(address=address or "local", **kwargs)  # "local": a new instance even if `ray start` ran here
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise UsageError(f"cannot connect to the Ray cluster at {address}: {exc}".splitlines()[0]) from None
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)
    try:
        yield
    finally:
        ray.shutdown()


def train_rllib(
    spec: TrainSpec,
    output: OutputOptions | None = None,
    evaluation: EvalOptions | None = None,
    execution: ExecOptions | None = None,
    rllib: RllibOptions | None = None,
) -> TrainResult:
    """Train ``spec.algo`` on the Gymnasium env or PettingZoo team ``spec.env`` with RLlib and write a run
    directory.

    ``rllib.num_env_runners`` (default: the config's; 0 samples in the driver) and ``rllib.address``
    (``auto``, ``host:6379`` or ``ray://host:10001``; None starts a local Ray) size the Ray side;
    ``execution.num_threads`` is the torch thread count of the learner and of every env runner. Periodic greedy team
    evaluations go to ``progress.csv``; ``output.save_freq > 0`` saves a module checkpoint every that many env steps.

    :return: run dir, experiment and summary (``model`` is None: the policy is in ``rllib_checkpoint/``);
        ``interrupted`` after Ctrl-C/SIGTERM (the checkpoint is still saved).
    """
    output, evaluation, execution = output or OutputOptions(), evaluation or EvalOptions(), execution or ExecOptions()
    rllib = rllib or RllibOptions()
    for group in (spec, evaluation, execution, rllib):
        group.validate()
    for name in ("ray.rllib", "ray._common.deprecation") if execution.verbose < 2 else ():  # API-stack notices
        logging.getLogger(name).setLevel(logging.ERROR)
    check_address(rllib.address)
    ref = resolve_env(spec.env, spec.gym_packages)
    exp = build_experiment(spec, ref, rllib.num_env_runners)
    if execution.num_threads > 0:
        torch.set_num_threads(execution.num_threads)
    seed = draw_seed(execution.seed)
    config, groups = build_config(exp, ref, seed, execution.num_threads)
    args = {"algo": spec.algo, "env": ref.env_id, "backend": "rllib", "seed": seed, "n_timesteps": exp.n_timesteps,
            "log_folder": str(output.log_folder), "eval_freq": evaluation.frequency(exp.n_timesteps),
            "eval_episodes": evaluation.eval_episodes, "num_env_runners": exp.num_env_runners,
            "address": rllib.address, "num_threads": execution.num_threads, "groups": groups}
    command = output.command or default_command(spec, execution)
    done: dict[str, Any] = {"env_steps": 0, "agent_steps": 0, "iterations": 0}  # updated every iteration
    clock = LearningClock()
    with contextlib.ExitStack() as ray_scope:
        with new_run_dir(output.log_folder, spec.algo, ref.env_id, exp.hyperparams, args, command) as run_dir:
            ray_scope.enter_context(ray_session(rllib.address, exp.num_env_runners, execution.num_threads,
                                                execution.verbose))
            try:
                algo_obj = config.build_algo()
            except (ValueError, TypeError) as exc:
                raise UsageError(f"invalid RLlib settings for {spec.algo} on {ref.env_id}: {exc}") from None
            ray_scope.callback(algo_obj.stop)
        try:
            with clock:
                _train_loop(algo_obj, (exp, ref, groups), run_dir, done, seed, evaluation, execution,
                            output.save_freq)
        finally:
            save_checkpoint(algo_obj, run_dir / CHECKPOINT_DIR, spec.algo, exp.model, groups)
    steps = int(done["env_steps"])
    summary = {**base_summary(spec.algo, ref.env_id, seed, steps, steps, clock), "backend": "rllib",
               "n_agent_steps": int(done["agent_steps"]), "iterations": int(done["iterations"]),
               "policies": exp.policies, "num_env_runners": exp.num_env_runners, "address": rllib.address,
               "num_threads": execution.num_threads, "ray_version": ray.__version__, "checkpoint": CHECKPOINT_DIR}

    def final_eval() -> dict[str, Any]:
        return evaluate_checkpoint(run_dir / CHECKPOINT_DIR, ref, spec.algo, exp.env_kwargs, groups,
                                   EvaluateOptions(n_episodes=evaluation.final_eval_episodes, seed=seed))

    finish_run(run_dir, summary, final_eval if evaluation.final_eval_episodes > 0 else None)
    return TrainResult(run_dir, None, exp, summary, clock.interrupted)


#: Learner statistics of each module written to ``progress.csv``, by algorithm (the keys RLlib's learners log).
_LEARNER_STATS: dict[str, tuple[str, ...]] = {
    "ppo": ("policy_loss", "vf_loss", "entropy", "mean_kl_loss", "vf_explained_var"),
    "appo": ("policy_loss", "vf_loss", "entropy", "mean_kl_loss"),
    "impala": ("policy_loss", "vf_loss", "entropy"),
    "dqn": ("qf_loss", "qf_mean"),
    "sac": ("qf_loss", "policy_loss", "alpha_loss", "alpha_value"),
}


@functools.singledispatch
def _declared_metrics(kind: EnvKind, ref: EnvRef, env_kwargs: dict[str, Any]) -> list[str]:
    """The episode metrics an env of ``kind`` declares for ``progress.csv``'s columns: none (a Gymnasium env's
    come with each evaluation's summary)."""
    return []


@_declared_metrics.register
def _team_metrics(kind: TeamKind, ref: EnvRef, env_kwargs: dict[str, Any]) -> list[str]:
    """A PettingZoo env's (its ``metadata``)."""
    probe = ref.parallel_env(**env_kwargs)
    try:
        return list(declared_metrics(getattr(probe, "metadata", None)))
    finally:
        probe.close()


def save_module_checkpoint(algo: Any, path: Path, exp: RllibExperiment, groups: dict[str, list[str]]) -> Path:
    """Save the learner's RLModule(s) (and optimizer state) of ``algo`` under ``path`` in the layout of a full
    checkpoint (``learner_group/learner/rl_module``), with the plain-data module files that
    :func:`~sbagents.rllib.evaluation.evaluate_checkpoint` reads, atomically
    (:func:`~sbagents.rllib.checkpoints.save_checkpoint`); the env runners' state is left out, which keeps a
    periodic save short."""
    return save_checkpoint(algo, path, exp.algo, exp.model, groups, learner_only=True)


def _train_loop(algo: Any, run: tuple[RllibExperiment, EnvRef, dict[str, list[str]]], run_dir: Path,
                state: dict[str, Any], seed: int, evaluation: EvalOptions, execution: ExecOptions,
                save_freq: int = -1) -> None:
    """``algo.train()`` until ``exp.n_timesteps`` env steps; one ``progress.csv`` row per iteration.

    With ``save_freq > 0``, the first iteration that reaches every multiple of ``save_freq`` env steps saves
    ``checkpoint_<env steps>/`` (:func:`save_module_checkpoint`); its row names it in ``checkpoint``. The row's
    ``train_seconds`` is the time since the loop started (milliseconds after the clock of ``summary.json``'s
    ``train_seconds``), at the end of the iteration, saves and evaluations included.

    ``state`` (``env_steps``, ``agent_steps``, ``iterations``) is updated after every iteration, so it is
    current when a KeyboardInterrupt ends the loop.
    """
    exp, ref, groups = run
    modules = sorted(groups)
    metric_keys = _declared_metrics(ref.kind, ref, exp.env_kwargs)
    stats = _LEARNER_STATS[exp.algo]
    fields = ["iteration", "env_steps", "agent_steps", "episodes", "episode_return_mean", "episode_len_mean",
              "iter_seconds", "time_total_s", "train_seconds", "env_steps_per_s", "checkpoint", "eval_mean_return",
              *(f"eval_{k}" for k in metric_keys)]
    fields += [f"{m}/{k}" for m in modules for k in stats]
    eval_freq = evaluation.frequency(exp.n_timesteps)
    next_eval = eval_freq if eval_freq > 0 else math.inf
    next_save = save_freq if save_freq > 0 else math.inf
    start = time.perf_counter()
    reporter = ProgressReporter(exp.n_timesteps, bar=execution.progress, quiet=execution.verbose <= 0)
    with (run_dir / PROGRESS_FILE).open("w", newline="") as f, contextlib.closing(reporter):
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        while state["env_steps"] < exp.n_timesteps:
            result = algo.train()
            runners = result.get("env_runners", {})
            steps = int(runners.get("num_env_steps_sampled_lifetime", state["env_steps"]))
            reporter.update(steps)
            state.update(env_steps=steps, iterations=int(result["training_iteration"]),
                         agent_steps=int(sum(runners.get("num_agent_steps_sampled_lifetime", {}).values())))
            row: dict[str, Any] = {
                "iteration": state["iterations"], "env_steps": steps, "agent_steps": state["agent_steps"],
                "episodes": runners.get("num_episodes_lifetime", ""),
                "episode_return_mean": runners.get("episode_return_mean", ""),
                "episode_len_mean": runners.get("episode_len_mean", ""),
                "iter_seconds": round(float(result.get("time_this_iter_s", 0.0)), 4),
                "time_total_s": round(float(result.get("time_total_s", 0.0)), 3),
                "env_steps_per_s": round(float(runners.get("num_env_steps_sampled", 0))
                                         / max(float(result.get("time_this_iter_s", 0.0)), 1e-9), 1),
            }
            learners = result.get("learners", {})
            row.update({f"{m}/{k}": learners.get(m, {}).get(k, "") for m in modules for k in stats})
            if steps >= next_eval and steps < exp.n_timesteps:
                next_eval = steps - steps % eval_freq + eval_freq
                ckpt = save_checkpoint(algo, run_dir / CHECKPOINT_DIR, exp.algo, exp.model, groups)
                ev = evaluate_checkpoint(ckpt, ref, exp.algo, exp.env_kwargs, groups,
                                         EvaluateOptions(n_episodes=evaluation.eval_episodes, seed=seed))
                declared = {k: ev["metrics"][k] for k in metric_keys}
                row.update(eval_mean_return=ev["mean_return"], **{f"eval_{k}": v for k, v in declared.items()})
                reporter.evaluation(steps, ev["mean_return"], ev["std_return"], ev["success_rate"], declared)
            if steps >= next_save and steps < exp.n_timesteps:
                next_save = steps - steps % save_freq + save_freq
                row["checkpoint"] = save_module_checkpoint(algo, run_dir / f"{CHECKPOINT_PREFIX}_{steps}", exp,
                                                           groups).name
            row["train_seconds"] = round(time.perf_counter() - start, 3)
            writer.writerow(row)
            f.flush()
