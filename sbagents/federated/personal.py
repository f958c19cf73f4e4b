"""Personal fine-tuning: a finished SmartHome policy (federated or not) adapted to one home with a small local
budget, on that home's experience only; the home's comfort and energy use before and after, and the personal
model as a run dir of its own."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.utils import set_random_seed

from sbagents.algos import ALGOS
from sbagents.atomic import save_model, write_with
from sbagents.core.lifecycle import LearningClock, base_summary, finish_run, new_run_dir
from sbagents.core.run_dir import env_stem, load_experiment, model_path
from sbagents.errors import UsageError
from sbagents.federated.evaluation import evaluate_home, for_home
from sbagents.federated.homes import Home
from sbagents.federated.local import make_env
from sbagents.safe_load import load_model
from sbagents.state_files import VECNORMALIZE_FILE, existing

#: Seed offset of the before/after evaluation episodes (the same episodes before and after).
EVAL_SEED = 70_000


@dataclass
class PersonalResult:
    """The personal run dir and the home's comfort before and after (see :func:`evaluate_home`)."""

    run_dir: Path
    before: dict[str, float]
    after: dict[str, float]


def personalize(base_run: Path, algo: str, env_id: str, home: Home, steps: int, episodes: int = 20, seed: int = 0,
                log_folder: str | Path = "logs", learning_starts: int | None = None) -> PersonalResult:
    """Fine-tune the model of ``base_run`` for ``steps`` env steps in ``home``; write a new run dir.

    :param learning_starts: random steps before the first update (default: the run's, at most a quarter of
        ``steps``).
    """
    if steps < 1:
        raise UsageError(f"the fine-tuning budget must be >= 1 step, got {steps}")
    torch.set_num_threads(1)
    exp = for_home(load_experiment(base_run, algo, env_id), home)
    stats = existing(base_run / VECNORMALIZE_FILE)
    env = make_env(exp, seed, stats_path=stats)
    model = load_model(ALGOS[algo].cls, model_path(base_run, env_id), env=env, device="cpu")
    before = evaluate_home(model, exp, home, episodes, seed + EVAL_SEED, stats)
    if hasattr(model, "learning_starts"):
        model.learning_starts = min(int(model.learning_starts), steps // 4) if learning_starts is None \
            else learning_starts
    args: dict[str, Any] = {"algo": algo, "env": env_id, "seed": seed, "n_timesteps": steps,
                            "personalized_from": str(base_run), "home": vars(home), "log_folder": str(log_folder)}
    command = f"python -m sbagents.federated.personalize --home {home.index}"
    with new_run_dir(log_folder, algo, env_id, {**exp.hyperparams, "env_kwargs": exp.env_kwargs}, args,
                     command) as run_dir:
        set_random_seed(seed)
    clock = LearningClock(graceful=True)
    with clock:
        model.learn(steps, reset_num_timesteps=True)
    if stats is not None:  # the statistics the model was trained with, kept fixed
        write_with(run_dir / stats.name, lambda tmp: shutil.copyfile(stats, tmp))
    save_model(model, run_dir / f"{env_stem(env_id)}.zip")
    after = evaluate_home(model, exp, home, episodes, seed + EVAL_SEED, stats)
    env.close()
    summary = base_summary(algo, env_id, seed, model.num_timesteps, model.num_timesteps, clock)
    summary["personalization"] = {"home": vars(home), "steps": steps, "episodes": episodes, "before": before,
                                  "after": after, "base_run": str(base_run)}
    finish_run(run_dir, summary, None)
    return PersonalResult(run_dir, before, after)
