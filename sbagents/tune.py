"""``python -m sbagents.tune``: an Optuna search over an algorithm's hyperparameters.

Parses the flags and calls :func:`sbagents.pipeline.tuning.tune`.
"""

from __future__ import annotations

import argparse
from typing import Any

from sbagents.openmp import passive_wait_policy

passive_wait_policy()  # before torch is imported (below): see sbagents.openmp

from sbagents.cli_common import ArgumentParser, run  # noqa: E402
from sbagents.core.options import StudyOptions, TrainSpec  # noqa: E402
from sbagents.pipeline.tuning import PRUNERS, SAMPLERS, tune  # noqa: E402


def build_parser() -> ArgumentParser:
    """The ``tune`` argument parser."""
    p = ArgumentParser(prog="python -m sbagents.tune", description="Optuna search over an algorithm's hyperparameters.")
    p.add_argument("--algo", required=True, help="algorithm to tune")
    p.add_argument("--env", required=True, help="env id")
    p.add_argument("--n-trials", type=int, default=20, help="finished trials the study should hold (resumes)")
    p.add_argument("--storage", default=None, help="RDB URL (default: sqlite file in the log folder)")
    p.add_argument("--study-name", default=None, help="study name (default: <algo>-<EnvId>)")
    p.add_argument("--n-jobs", type=int, default=1, help="parallel trials in this process")
    p.add_argument("--sampler", default="tpe", choices=list(SAMPLERS), help="Optuna sampler")
    p.add_argument("--pruner", default="median", choices=list(PRUNERS), help="Optuna pruner")
    p.add_argument("--n-seeds", type=int, default=1, help="seeds per trial (objective: mean of best evaluations)")
    p.add_argument("-n", "--n-timesteps", type=int, default=None, help="training budget per trial and seed")
    p.add_argument("--n-evaluations", type=int, default=5, help="evaluations per training run")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per evaluation")
    p.add_argument("-f", "--log-folder", default="logs", help="where the study file and outputs go")
    p.add_argument("--seed", type=int, default=0, help="first seed (trial seeds are seed..seed+n_seeds-1)")
    p.add_argument("--gym-packages", nargs="+", default=[], help="packages to import that register envs")
    p.add_argument("--verbose", type=int, default=1, help="0 quiet, 1 one line per finished trial (default)")
    return p


def options_from_args(a: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of :func:`sbagents.pipeline.tuning.tune` from the parsed flags."""
    return {
        "spec": TrainSpec(a.algo, a.env, n_timesteps=a.n_timesteps, gym_packages=tuple(a.gym_packages)),
        "study": StudyOptions(n_trials=a.n_trials, storage=a.storage, study_name=a.study_name, n_jobs=a.n_jobs,
                              sampler=a.sampler, pruner=a.pruner, n_seeds=a.n_seeds, n_evaluations=a.n_evaluations,
                              eval_episodes=a.eval_episodes),
        "log_folder": a.log_folder, "seed": a.seed, "verbose": a.verbose,
    }


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, run or resume the study, print the best trial and where its zoo entry is."""
    result = tune(**options_from_args(build_parser().parse_args(argv)))
    print(f"study {result.study.study_name}: {len(result.study.trials)} trials")
    if result.best_config_path.exists():
        print(f"best objective {result.study.best_value:.4g} (trial {result.study.best_trial.number}); "
              f"zoo entry: {result.best_config_path}")
    print(f"history plot: {result.history_plot_path}")
    return 0


if __name__ == "__main__":
    run("python -m sbagents.tune", main)
