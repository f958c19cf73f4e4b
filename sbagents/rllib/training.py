"""Training a PettingZoo env with Ray RLlib PPO: :func:`train_rllib` (``python -m sbagents.train --backend rllib``).

Flow: zoo entry (``zoo_configs/rllib_<algo>.yml``) + CLI overrides -> :class:`RllibExperiment` -> RLlib
``AlgorithmConfig`` (new API stack: RLModule / Learner / EnvRunner) -> Ray (a local instance sized for this
machine, or the cluster at ``address``) -> run dir with ``rllib_checkpoint/``, ``progress.csv`` and
``summary.json``. Ctrl-C / SIGTERM stop training but still leave a checkpoint and ``summary.json``
(``interrupted: true``); Ray is shut down in every case.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import importlib
import json
import logging
import math
import shutil
import signal
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import ray
import torch
from ray.rllib.algorithms.algorithm_config import AlgorithmConfig
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
from ray.rllib.env.multi_agent_env import MultiAgentEnv
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

from sbagents.config import default_config_path, lookup_entry
from sbagents.console import ProgressReporter
from sbagents.env_ids import PETTINGZOO_ENVS, EnvRef, resolve_env
from sbagents.errors import UsageError
from sbagents.rllib import CHECKPOINT_DIR, PROGRESS_FILE, RLLIB_ALGOS, SHARED_MODULE, check_address
from sbagents.rllib.evaluation import evaluate_checkpoint
from sbagents.run_dir import SUMMARY_FILE, create_run_dir
from sbagents.run_loading import save_run_config

#: Zoo-entry keys that describe the experiment (the rest go to RLlib).
EXPERIMENT_KEYS = ("n_timesteps", "env_kwargs", "policies", "model")
#: Zoo-entry keys passed to ``AlgorithmConfig.env_runners``.
ENV_RUNNER_KEYS = ("num_env_runners", "num_envs_per_env_runner", "rollout_fragment_length")
#: Zoo-entry keys passed to ``PPOConfig.training`` (``lr`` may be ``lin_<x>``: linear decay to 0).
TRAINING_KEYS = ("lr", "gamma", "lambda_", "train_batch_size_per_learner", "minibatch_size", "num_epochs",
                 "entropy_coeff", "clip_param", "vf_clip_param", "vf_loss_coeff", "grad_clip", "grad_clip_by",
                 "use_kl_loss", "kl_coeff", "kl_target", "shuffle_batch_per_epoch")
POLICY_MODES = ("shared", "per_agent")
_OBJECT_STORE_BYTES = 256 * 1024**2  # the rollouts here are small; Ray's default takes 30% of the RAM


@dataclass
class RllibExperiment:
    """A resolved RLlib experiment; ``hyperparams`` is the plain entry as written to ``config.yml``.

    :param n_timesteps: env steps to sample (one step of the parallel env = one step for every agent).
    :param policies: ``"shared"`` (one module for every agent) or ``"per_agent"`` (one module per agent id).
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

    @property
    def num_env_runners(self) -> int:
        """Env runner actors (0: sample in the driver process)."""
        return int(self.env_runners.get("num_env_runners", 2))


@dataclass
class RllibTrainResult:
    """What :func:`train_rllib` produced."""

    run_dir: Path
    experiment: RllibExperiment
    summary: dict[str, Any]
    interrupted: bool = False


def resolve_entry(algo: str, env_id: str, entry: Mapping[str, Any], where: str) -> RllibExperiment:
    """Validate a zoo entry and split it into env runner, training and model settings.

    :param where: file and entry named in errors.
    """
    accepted = (*EXPERIMENT_KEYS, *ENV_RUNNER_KEYS, *TRAINING_KEYS)
    unknown = sorted(set(entry) - set(accepted))
    if unknown:
        raise UsageError(f"{where}: unknown key(s) {', '.join(unknown)}; accepted: {', '.join(accepted)}")
    policies = entry.get("policies", "shared")
    if policies not in POLICY_MODES:
        raise UsageError(f"{where}: policies must be one of {', '.join(POLICY_MODES)}, got {policies!r}")
    model = dict(entry.get("model") or {})
    model_fields = {f.name for f in dataclasses.fields(DefaultModelConfig)}
    if set(model) - model_fields:
        bad = ", ".join(sorted(set(model) - model_fields))
        raise UsageError(f"{where}: unknown model key(s) {bad}; accepted: {', '.join(sorted(model_fields))}")
    n_timesteps = int(entry.get("n_timesteps", 0))
    training = {k: entry[k] for k in TRAINING_KEYS if k in entry}
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
    return RllibExperiment(algo, env_id, n_timesteps, dict(entry.get("env_kwargs") or {}), policies, runners,
                           training, model, dict(entry))


def build_experiment(
    algo: str,
    ref: EnvRef,
    conf_file: str | Path | None = None,
    hyperparams: Mapping[str, Any] | None = None,
    n_timesteps: int | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    num_env_runners: int | None = None,
) -> RllibExperiment:
    """The zoo entry for ``ref`` in ``zoo_configs/rllib_<algo>.yml`` (or ``conf_file``) with the CLI overrides."""
    if algo not in RLLIB_ALGOS:
        raise UsageError(f"--backend rllib supports --algo {', '.join(RLLIB_ALGOS)}; got {algo!r}")
    if not ref.multi_agent:
        raise UsageError(f"--backend rllib trains PettingZoo envs ({', '.join(PETTINGZOO_ENVS)}); got {ref.env_id}")
    if n_timesteps is not None and n_timesteps < 1:
        raise UsageError(f"-n/--n-timesteps must be a positive integer, got {n_timesteps}")
    path = Path(conf_file) if conf_file is not None else default_config_path(f"rllib_{algo}")
    if conf_file is not None and not path.exists():
        raise UsageError(f"config file {path} does not exist")
    entry = lookup_entry(path, ref.env_id)
    entry.update(hyperparams or {})
    if n_timesteps is not None:
        entry["n_timesteps"] = n_timesteps
    if num_env_runners is not None:
        entry["num_env_runners"] = num_env_runners
    if env_kwargs:
        entry["env_kwargs"] = {**(entry.get("env_kwargs") or {}), **env_kwargs}
    exp = resolve_entry(algo, ref.env_id, entry, f"{path}, entry for {ref.env_id}")
    if exp.n_timesteps < 1:
        raise UsageError(f"no n_timesteps for {algo} on {ref.env_id} in {path}; pass -n N")
    return exp


def make_env(config: Mapping[str, Any]) -> MultiAgentEnv:
    """RLlib env creator (runs in every env runner): the PettingZoo ``parallel_env`` as a ``MultiAgentEnv``.

    :param config: ``module`` (PettingZoo module path), ``env_kwargs`` and ``num_threads`` (torch threads of
        the env runner process; <= 0 keeps torch's default).
    """
    threads = int(config.get("num_threads", 1))
    if threads > 0 and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    module = importlib.import_module(config["module"])
    return ParallelPettingZooEnv(module.parallel_env(**config.get("env_kwargs", {})))


def _to_shared(agent_id: Any, episode: Any = None, **kwargs: Any) -> str:  # policies: shared
    return SHARED_MODULE


def _to_own(agent_id: Any, episode: Any = None, **kwargs: Any) -> str:  # policies: per_agent
    return str(agent_id)


def build_config(exp: RllibExperiment, seed: int, num_threads: int = 1) -> AlgorithmConfig:
    """The RLlib ``PPOConfig`` of ``exp`` (one local learner in the driver, ``num_env_runners`` samplers)."""
    module_name = PETTINGZOO_ENVS[exp.env_id]
    try:
        probe = importlib.import_module(module_name).parallel_env(**exp.env_kwargs)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid env_kwargs for {exp.env_id}: {exc}") from None
    agents = list(probe.possible_agents)
    probe.close()
    env_name = f"sbagents_{exp.env_id}"
    register_env(env_name, make_env)
    if exp.policies == "shared":
        policies, mapping = {SHARED_MODULE}, _to_shared
    else:
        policies, mapping = set(agents), _to_own
    env_config = {"module": module_name, "env_kwargs": exp.env_kwargs, "num_threads": num_threads}
    try:
        return (
            PPOConfig()
            .environment(env_name, env_config=env_config)
            .env_runners(**{"num_env_runners": 2, **exp.env_runners})
            .learners(num_learners=0)
            .multi_agent(policies=policies, policy_mapping_fn=mapping)
            .training(**exp.training)
            .rl_module(model_config=DefaultModelConfig(**exp.model))
            .debugging(seed=seed, log_level="ERROR")
        )
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid RLlib settings for {exp.algo} on {exp.env_id}: {exc}") from None


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
    algo: str,
    env: str,
    *,
    n_timesteps: int | None = None,
    log_folder: str | Path = "logs",
    seed: int = -1,
    hyperparams: Mapping[str, Any] | None = None,
    conf_file: str | Path | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
    num_env_runners: int | None = None,
    address: str | None = None,
    num_threads: int = 1,
    eval_freq: int | None = None,
    eval_episodes: int = 5,
    final_eval_episodes: int = 10,
    progress: bool | None = None,
    verbose: int = 1,
    command: str = "",
) -> RllibTrainResult:
    """Train ``algo`` on the PettingZoo env ``env`` with RLlib and write a run directory.

    :param n_timesteps: env steps to sample (default: the config's).
    :param num_env_runners: RLlib env runner actors (default: the config's; 0 samples in the driver).
    :param address: Ray cluster to join (``auto``, ``host:6379`` or ``ray://host:10001``); None starts a local
        Ray instance.
    :param num_threads: torch threads of the learner and of every env runner (<= 0 keeps torch's default).
    :param eval_freq: env steps between greedy team evaluations (written to ``progress.csv``; default a tenth
        of the budget, at most 25,000; <= 0 disables).
    :param final_eval_episodes: greedy team episodes evaluated after training into ``summary["eval"]``.
    :return: run dir, experiment and summary; ``interrupted`` after Ctrl-C/SIGTERM (checkpoint still saved).
    """
    for name in ("ray.rllib", "ray._common.deprecation") if verbose < 2 else ():  # RLlib's API-stack notices
        logging.getLogger(name).setLevel(logging.ERROR)
    check_address(address)
    ref = resolve_env(env)
    exp = build_experiment(algo, ref, conf_file, hyperparams, n_timesteps, env_kwargs, num_env_runners)
    if num_threads > 0:
        torch.set_num_threads(num_threads)
    if seed < 0:
        seed = int(np.random.default_rng().integers(2**31 - 1))
    if eval_freq is None:
        eval_freq = min(25_000, max(exp.n_timesteps // 10, 1))
    config = build_config(exp, seed, num_threads)
    run_dir = create_run_dir(log_folder, algo, ref.env_id)
    args = {"algo": algo, "env": ref.env_id, "backend": "rllib", "seed": seed, "n_timesteps": exp.n_timesteps,
            "log_folder": str(log_folder), "eval_freq": eval_freq, "eval_episodes": eval_episodes,
            "num_env_runners": exp.num_env_runners, "address": address, "num_threads": num_threads}
    save_run_config(run_dir, exp.env_id, exp.hyperparams, args,  # RL Zoo layout, as the SB3 runs
                    command or f"python -m sbagents.train --backend rllib --env {env}")
    interrupted = False
    done: dict[str, Any] = {"env_steps": 0, "agent_steps": 0, "iterations": 0}  # updated every iteration
    try:
        with ray_session(address, exp.num_env_runners, num_threads, verbose):
            try:
                algo_obj = config.build_algo()
            except (ValueError, TypeError) as exc:
                raise UsageError(f"invalid RLlib settings for {algo} on {ref.env_id}: {exc}") from None
            start, cpu_start = time.perf_counter(), time.process_time()
            try:
                _train_loop(algo_obj, exp, run_dir, done, seed, eval_freq, eval_episodes, progress, verbose)
            except KeyboardInterrupt:  # Ctrl-C / SIGTERM: keep what was learned
                interrupted = True
            except BaseException:
                algo_obj.stop()
                raise
            seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
            try:
                algo_obj.save_to_path(str((run_dir / CHECKPOINT_DIR).resolve()))
            finally:
                algo_obj.stop()
    except BaseException:
        if not (run_dir / CHECKPOINT_DIR).is_dir():
            shutil.rmtree(run_dir, ignore_errors=True)  # nothing trained: do not leave a half-made run dir
        raise
    steps = int(done["env_steps"])
    summary: dict[str, Any] = {
        "algo": algo, "env": ref.env_id, "backend": "rllib", "seed": seed, "n_timesteps": steps,
        "n_agent_steps": int(done["agent_steps"]), "iterations": int(done["iterations"]),
        "train_seconds": round(seconds, 3), "train_cpu_seconds": round(cpu_seconds, 3),
        "fps": round(steps / max(seconds, 1e-9), 1), "policies": exp.policies,
        "num_env_runners": exp.num_env_runners, "address": address, "num_threads": num_threads,
        "ray_version": ray.__version__, "checkpoint": CHECKPOINT_DIR, "interrupted": interrupted, "eval": None,
    }
    (run_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    if not interrupted and final_eval_episodes > 0:
        summary["eval"] = evaluate_checkpoint(run_dir / CHECKPOINT_DIR, ref.env_id, algo, exp.env_kwargs,
                                              n_episodes=final_eval_episodes, seed=seed)
        (run_dir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    return RllibTrainResult(run_dir, exp, summary, interrupted)


_LEARNER_STATS = ("policy_loss", "vf_loss", "entropy", "mean_kl_loss", "vf_explained_var")


def _train_loop(
    algo: Any, exp: RllibExperiment, run_dir: Path, state: dict[str, Any], seed: int, eval_freq: int,
    eval_episodes: int, progress: bool | None, verbose: int,
) -> None:
    """``algo.train()`` until ``exp.n_timesteps`` env steps; one ``progress.csv`` row per iteration.

    ``state`` (``env_steps``, ``agent_steps``, ``iterations``) is updated after every iteration, so it is
    current when a KeyboardInterrupt ends the loop.
    """
    modules = sorted(algo.config.policies)
    fields = ["iteration", "env_steps", "agent_steps", "episodes", "episode_return_mean", "episode_len_mean",
              "iter_seconds", "time_total_s", "env_steps_per_s", "eval_mean_return", "eval_treasures_per_episode"]
    fields += [f"{m}/{k}" for m in modules for k in _LEARNER_STATS]
    next_eval = eval_freq if eval_freq > 0 else math.inf
    reporter = ProgressReporter(exp.n_timesteps, bar=progress, quiet=verbose <= 0)
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
            row.update({f"{m}/{k}": learners.get(m, {}).get(k, "") for m in modules for k in _LEARNER_STATS})
            if steps >= next_eval and steps < exp.n_timesteps:
                next_eval = steps - steps % eval_freq + eval_freq
                ckpt = algo.save_to_path(str((run_dir / CHECKPOINT_DIR).resolve()))
                ev = evaluate_checkpoint(ckpt, exp.env_id, exp.algo, exp.env_kwargs, eval_episodes, seed=seed)
                row.update(eval_mean_return=ev["mean_return"],
                           eval_treasures_per_episode=ev["metrics"]["treasures_per_episode"])
                reporter.evaluation(steps, ev["mean_return"], ev["std_return"], None,
                                    {"treasures_per_episode": ev["metrics"]["treasures_per_episode"]})
            writer.writerow(row)
            f.flush()
