"""Optuna hyperparameter search behind ``python -m sbagents.tune``.

Unlike RL Zoo, a trial's objective is the *best* periodic evaluation (not the last), averaged over
``n_seeds`` seeds, and the study lives in an RDB storage (an SQLite file in the log folder by default), so an
interrupted study resumes and several machines can share one study through a server URL.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import torch
import yaml
from sqlalchemy.exc import SQLAlchemyError
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.utils import set_random_seed

from sbagents.algos import ALGOS
from sbagents.atomic import save_figure, write_text
from sbagents.core.env_names import EnvRef, resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import StudyOptions, TrainSpec
from sbagents.core.run_dir import env_stem
from sbagents.env_factory import make_eval_vec, make_vec, normalize_for_training
from sbagents.errors import UsageError
from sbagents.pipeline.kinds import EVAL_SEED_OFFSET
from sbagents.pipeline.models import check_spaces, make_model

SAMPLERS = {"tpe": optuna.samplers.TPESampler, "random": optuna.samplers.RandomSampler}
PRUNERS = {"median": optuna.pruners.MedianPruner, "halving": optuna.pruners.SuccessiveHalvingPruner,
           "none": optuna.pruners.NopPruner}


def sample_params(trial: optuna.Trial, algo: str) -> dict[str, Any]:
    """Hyperparameters for one trial, as zoo-config values (plain YAML data)."""
    params: dict[str, Any] = {
        "learning_rate": trial.suggest_float("learning_rate", 1e-4, 1e-2, log=True),
        "gamma": trial.suggest_categorical("gamma", [0.9, 0.95, 0.98, 0.99]),
    }
    if algo in ("qlearning", "sarsa"):
        params["learning_rate"] = trial.suggest_float("alpha", 0.05, 0.5, log=True)
        params["exploration_initial_eps"] = trial.suggest_float("exploration_initial_eps", 0.05, 0.5)
        return params
    width = trial.suggest_categorical("net_width", [32, 64, 128])
    params["policy_kwargs"] = {"net_arch": [width, width]}
    if algo in ("ppo", "a2c", "trpo"):
        params["n_steps"] = trial.suggest_categorical("n_steps", [32, 64, 128, 256])
        params["ent_coef"] = trial.suggest_float("ent_coef", 1e-8, 0.05, log=True)
        if algo == "ppo":
            params["batch_size"] = trial.suggest_categorical("batch_size", [64, 128, 256])
    elif algo in ("dqn", "qrdqn"):
        params["exploration_fraction"] = trial.suggest_float("exploration_fraction", 0.05, 0.5)
        params["target_update_interval"] = trial.suggest_categorical("target_update_interval", [100, 500, 2000])
    elif ALGOS[algo].off_policy:
        params["batch_size"] = trial.suggest_categorical("batch_size", [64, 128, 256])
        params["tau"] = trial.suggest_categorical("tau", [0.005, 0.01, 0.02])
    return params


class _BestEval(EvalCallback):
    """EvalCallback that reports the running best mean return to the trial (for pruning)."""

    def __init__(self, trial: optuna.Trial, step_offset: int, seeds_done: list[float], **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.trial, self.step_offset, self.seeds_done = trial, step_offset, seeds_done
        self.n_evals = 0
        self.pruned = False

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            super()._on_step()
            self.n_evals += 1
            running = float(np.mean([*self.seeds_done, self.best_mean_reward]))
            self.trial.report(running, self.step_offset + self.n_evals)
            if self.trial.should_prune():
                self.pruned = True
                return False
        return True


@dataclass
class TuneResult:
    """A finished (or resumed) study: where it is stored and the best trial's zoo entry."""

    study: optuna.Study
    best_config_path: Path
    history_plot_path: Path


def _objective(spec: TrainSpec, ref: EnvRef, study: StudyOptions, seed: int) -> Any:
    def objective(trial: optuna.Trial) -> float:
        params = sample_params(trial, spec.algo)
        exp = build_experiment(replace(spec, hyperparams={**spec.hyperparams, **params}), ref)
        trial.set_user_attr("config", exp.hyperparams)
        bests: list[float] = []
        for k in range(study.n_seeds):
            run_seed = seed + k
            set_random_seed(run_seed)
            env = normalize_for_training(make_vec(exp, ref, exp.n_envs, run_seed), exp)
            eval_env = make_eval_vec(exp, ref, 1, run_seed + EVAL_SEED_OFFSET)
            try:
                model = make_model(exp, env, run_seed, "cpu")
            except UsageError as exc:
                raise optuna.TrialPruned(str(exc)) from None
            freq = max(exp.n_timesteps // (study.n_evaluations * env.num_envs), 1)
            callback = _BestEval(trial, k * study.n_evaluations, bests, eval_env=eval_env, eval_freq=freq,
                                 n_eval_episodes=study.eval_episodes, deterministic=exp.deterministic_eval, verbose=0)
            model.learn(exp.n_timesteps, callback=callback)
            env.close()
            eval_env.close()
            if callback.pruned:
                raise optuna.TrialPruned()
            bests.append(float(callback.best_mean_reward))
        return float(np.mean(bests))

    return objective


def tune(
    spec: TrainSpec, study: StudyOptions | None = None, log_folder: str | Path = "logs", seed: int = 0,
    verbose: int = 1,
) -> TuneResult:
    """Run (or resume) an Optuna study over ``spec.algo``'s hyperparameters on ``spec.env`` until it holds
    ``study.n_trials`` finished trials. ``spec.n_timesteps`` is the budget of every training run.

    :param study: the study's size, storage, sampler and pruner. Its default storage is an SQLite file
        ``<log_folder>/<algo>/<EnvId>_tune.db``; a server URL (``postgresql://...``) lets several machines share it.
    :param seed: first training seed (trial seeds are ``seed .. seed + n_seeds - 1``) and the sampler's seed.
    :param verbose: 1 prints one line per finished trial (value or pruned, and its parameters), 0 nothing.
    :return: the study, the best trial's zoo entry (``<EnvId>_tune_best.yml``) and the history plot path.
    """
    study = study or StudyOptions()
    if spec.algo not in ALGOS:
        raise UsageError(f"unknown algo {spec.algo!r}; available: {', '.join(ALGOS)}")
    if study.sampler not in SAMPLERS or study.pruner not in PRUNERS:
        raise UsageError(f"--sampler must be one of {', '.join(SAMPLERS)} and --pruner one of {', '.join(PRUNERS)}")
    study.validate()
    spec.validate()
    torch.set_num_threads(1)
    ref = resolve_env(spec.env, spec.gym_packages)
    probe = build_experiment(spec, ref)
    if probe.n_timesteps < 1:
        raise UsageError(f"no n_timesteps for {spec.algo} on {ref.env_id} in its config; pass -n N")
    check_spaces(probe, ref)
    folder = Path(log_folder) / spec.algo
    folder.mkdir(parents=True, exist_ok=True)
    stem = env_stem(ref.env_id)
    storage = study.storage or f"sqlite:///{(folder / f'{stem}_tune.db').resolve()}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        optuna_study = optuna.create_study(
            study_name=study.study_name or f"{spec.algo}-{stem}", storage=storage, load_if_exists=True,
            direction="maximize", sampler=SAMPLERS[study.sampler](seed=seed), pruner=PRUNERS[study.pruner](),
        )
    except (ImportError, ValueError, SQLAlchemyError) as exc:
        reason = str(exc).strip().splitlines()[0]
        raise UsageError(f"--storage {storage}: cannot open the study ({type(exc).__name__}: {reason})") from None
    finished = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    done = len(optuna_study.get_trials(deepcopy=False, states=finished))
    remaining = study.n_trials - done
    if remaining > 0:
        optuna_study.optimize(_objective(spec, ref, study, seed), n_trials=remaining, n_jobs=study.n_jobs,
                              catch=(), callbacks=[_print_trial] if verbose >= 1 else [])
    elif verbose >= 1:
        print(f"study {optuna_study.study_name} is already complete: {done} finished trials "
              f"(--n-trials {study.n_trials}); raise --n-trials to run more")
    return _write_outputs(optuna_study, folder, stem, ref.env_id)


def format_trial(trial: optuna.trial.FrozenTrial) -> str:
    """``trial 3: value 93 | learning_rate 0.0031, gamma 0.99`` (or ``pruned at step 2``)."""
    params = ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in trial.params.items())
    if trial.state == optuna.trial.TrialState.PRUNED:
        step = trial.last_step
        outcome = "pruned" if step is None else f"pruned at step {step}"
    elif trial.value is not None:
        outcome = f"value {trial.value:.4g}"
    else:
        outcome = trial.state.name.lower()
    return f"trial {trial.number}: {outcome} | {params}"


def _print_trial(study: optuna.Study, trial: optuna.trial.FrozenTrial) -> None:
    print(format_trial(trial), flush=True)


def _write_outputs(study: optuna.Study, folder: Path, stem: str, env_id: str) -> TuneResult:
    best_path, plot_path = folder / f"{stem}_tune_best.yml", folder / f"{stem}_tune_history.png"
    completed = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    if completed:
        best = study.best_trial
        header = f"# best of {len(completed)} trials: objective {best.value:.4g} (trial {best.number})\n"
        write_text(best_path, header + yaml.safe_dump({env_id: best.user_attrs["config"]}, sort_keys=True))
    import matplotlib

    matplotlib.use("Agg")
    from optuna.visualization.matplotlib import plot_optimization_history

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        ax = plot_optimization_history(study)
    figure = ax.get_figure(root=True)
    assert figure is not None
    save_figure(figure, plot_path, dpi=100, bbox_inches="tight")
    matplotlib.pyplot.close(figure)
    return TuneResult(study, best_path, plot_path)
