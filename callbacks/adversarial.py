"""Evaluation under observation attacks: plain functions for the ``evaluate`` CLI and an SB3 callback."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv

from sbagents.atomic import save_figure, write_csv
from sbagents.callbacks.attacks import AttackSpec, ObservationAttacker, parse_attack_spec
from sbagents.callbacks.common import PeriodicEvalCallback, output_dir
from sbagents.callbacks.rollout import as_vec_env, run_episodes, summarize_episodes, sync_normalization

ADVERSARIAL_CSV = "adversarial.csv"
ADVERSARIAL_PNG = "adversarial.png"
COLUMNS = (
    "attack", "eps", "mean_return", "std_return", "success_rate", "violations", "episodes", "mean_length",
    "max_perturbation",
)


def _attacks(attacks: str | Sequence[str] | Sequence[AttackSpec] | AttackSpec) -> list[AttackSpec]:
    if isinstance(attacks, AttackSpec):
        return [attacks]
    if isinstance(attacks, str):
        return parse_attack_spec(attacks)
    items = list(attacks)
    if all(isinstance(a, AttackSpec) for a in items):
        return items  # type: ignore[return-value]
    return parse_attack_spec([str(a) for a in items])


def evaluate_under_attack(
    model: BaseAlgorithm,
    env: gym.Env | VecEnv,
    attack: AttackSpec,
    n_episodes: int = 10,
    deterministic: bool = True,
    seed: int | None = None,
) -> dict[str, Any]:
    """Evaluate ``model`` for ``n_episodes`` episodes while ``attack`` perturbs what its policy sees.

    :param env: the evaluation env (a VecEnv wrapped like the training env, e.g. with a frozen
        ``VecNormalize`` holding the training statistics, or a plain Gymnasium env).
    :param seed: seeds the env (same episodes for every attack) and the attack's random numbers.
    :return: ``attack``, ``eps``, ``label``, ``mean_return``, ``std_return``, ``success_rate`` (NaN without
        ``is_success``), ``violations`` (violation steps), ``mean_ep_cost``, ``episodes``, ``mean_length``,
        ``max_perturbation`` (largest observed L-inf perturbation relative to the per-dimension scale).
    """
    venv = as_vec_env(env)
    attacker = ObservationAttacker(model.policy, venv, attack, seed)
    episodes = run_episodes(
        model, venv, n_episodes, deterministic, seed,
        policy=lambda obs, state, starts: attacker.step(obs, state, starts, deterministic),
    )
    return {
        "attack": attack.name,
        "eps": attack.eps,
        "label": attack.label,
        **summarize_episodes(episodes),
        "max_perturbation": attacker.max_perturbation,
    }


def write_adversarial_csv(
    rows: Sequence[dict[str, Any]], path: str | Path, extra: Sequence[str] = ()
) -> Path:
    """Write result rows (``extra`` columns first, e.g. ``timesteps``) to ``path``."""
    return write_csv(path, [*extra, *COLUMNS], rows)


def plot_adversarial(rows: Sequence[dict[str, Any]], path: str | Path, title: str = "") -> Path:
    """Mean return (+- std) against eps, one line per attack; the clean result (attack ``none``) is each
    line's eps = 0 point and a dashed reference line."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    clean = [r for r in rows if r["attack"] == "none"]
    for name in dict.fromkeys(r["attack"] for r in rows if r["attack"] != "none"):
        pts = sorted((float(r["eps"]), float(r["mean_return"]), float(r["std_return"]))
                     for r in rows if r["attack"] == name)
        if clean and pts[0][0] > 0:
            pts.insert(0, (0.0, float(clean[0]["mean_return"]), float(clean[0]["std_return"])))
        eps, mean, std = (np.array(v) for v in zip(*pts, strict=True))
        ax.plot(eps, mean, marker="o", label=name)
        ax.fill_between(eps, mean - std, mean + std, alpha=0.15)
    if clean:
        ax.axhline(float(clean[0]["mean_return"]), color="grey", linestyle="--", label="clean")
    ax.set_xlabel("eps (relative L-inf radius; std for gaussian)")
    ax.set_ylabel("mean episode return")
    ax.set_title(title or "Return under observation attacks")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    return Path(path)


def adversarial_report(
    model: BaseAlgorithm,
    env: gym.Env | VecEnv,
    attacks: str | Sequence[str] | Sequence[AttackSpec],
    n_episodes: int = 10,
    out_dir: str | Path | None = None,
    deterministic: bool = True,
    seed: int | None = 0,
    include_clean: bool = True,
) -> list[dict[str, Any]]:
    """Evaluate every attack (plus a clean ``none`` baseline) on the same seeded episodes.

    :param attacks: a spec string (``"gaussian:0.05,0.1 pgd:0.05"``), spec strings or :class:`AttackSpec` s.
    :param out_dir: if given, ``adversarial.csv`` and ``adversarial.png`` are written there.
    :return: one dict per attack (see :func:`evaluate_under_attack`), the clean baseline first.
    """
    specs = _attacks(attacks)
    if include_clean and not any(a.name == "none" for a in specs):
        specs.insert(0, AttackSpec("none", 0.0))
    rows = [evaluate_under_attack(model, env, a, n_episodes, deterministic, seed) for a in specs]
    if out_dir is not None:
        out = output_dir(out_dir, None)
        write_adversarial_csv(rows, out / ADVERSARIAL_CSV)
        plot_adversarial(rows, out / ADVERSARIAL_PNG)
    return rows


class AdversarialEvalCallback(PeriodicEvalCallback):
    """Evaluate the policy under observation attacks every ``eval_freq`` calls (vec steps) and at the end.

    Logs ``adversarial/<attack>_<eps>/mean_return`` and ``.../success_rate`` (when the env reports
    ``is_success``) plus ``adversarial/clean/mean_return``; writes ``adversarial.csv`` (every evaluation,
    with a ``timesteps`` column) and ``adversarial.png`` (the latest evaluation) to ``path`` (else the
    SB3 logger's dir). The eval env's ``VecNormalize`` statistics are synced from the training env first.

    :param eval_env: evaluation env, wrapped like the training env.
    :param attacks: spec string or list (see :func:`parse_attack_spec`).
    :param eval_freq: calls of ``_on_step`` between evaluations (divide env steps by ``n_envs``);
        <= 0: only at training end.
    :param n_eval_episodes: episodes per attack.
    :param seed: env/attack seed of every evaluation (the same episodes each time); None: 0.
    :param eval_at_end: also evaluate when training ends (if not just done).
    """

    def __init__(
        self,
        eval_env: gym.Env | VecEnv,
        attacks: str | Sequence[str] | Sequence[AttackSpec],
        eval_freq: int = 10_000,
        n_eval_episodes: int = 5,
        path: str | Path | None = None,
        deterministic: bool = True,
        seed: int | None = None,
        include_clean: bool = True,
        eval_at_end: bool = True,
        verbose: int = 0,
    ) -> None:
        super().__init__(int(eval_freq), eval_at_end, verbose)
        self.eval_env = as_vec_env(eval_env)
        self.attacks = _attacks(attacks)
        self.n_eval_episodes = int(n_eval_episodes)
        self.path = None if path is None else Path(path)
        self.deterministic, self.seed = deterministic, 0 if seed is None else int(seed)
        self.include_clean = include_clean
        self.history: list[dict[str, Any]] = []
        self.last_results: list[dict[str, Any]] = []

    def evaluate(self) -> list[dict[str, Any]]:
        """Run every attack now, log and write the results."""
        sync_normalization(self.training_env, self.eval_env)
        rows = adversarial_report(
            self.model, self.eval_env, self.attacks, self.n_eval_episodes, None, self.deterministic,
            self.seed, self.include_clean,
        )
        for row in rows:
            row["timesteps"] = self.num_timesteps
            tag = "clean" if row["attack"] == "none" else row["label"]
            self.logger.record(f"adversarial/{tag}/mean_return", row["mean_return"])
            if not math.isnan(row["success_rate"]):
                self.logger.record(f"adversarial/{tag}/success_rate", row["success_rate"])
            if self.verbose >= 1:
                print(f"adversarial {tag}: return {row['mean_return']:.2f} +- {row['std_return']:.2f}")
        self.last_results = rows
        self.history.extend(rows)
        self._last_eval_step = self.num_timesteps
        out = output_dir(self.path, self.logger.get_dir())
        write_adversarial_csv(self.history, out / ADVERSARIAL_CSV, extra=("timesteps",))
        plot_adversarial(rows, out / ADVERSARIAL_PNG, f"Return under attack at {self.num_timesteps} steps")
        return rows

