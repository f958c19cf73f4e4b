"""What a person sees while a run trains: a progress bar on a terminal and one line per evaluation.

SB3's own log tables are for ``--verbose 2``; by default a run shows :class:`ProgressReporter` output (the bar on
stderr when it is a terminal or ``-P`` asks for it, evaluation lines on stdout either way) and the CLI prints a
short summary at the end.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.core.extensions import registered_extensions
from sbagents.core.progress import ProgressReporter


class ProgressCallback(BaseCallback):
    """Drives a :class:`ProgressReporter` from SB3's training loop (steps on every call).

    :param scale: run timesteps per timestep of this model (a group's model: the team's agents / the group's).
    """

    def __init__(self, reporter: ProgressReporter, scale: float = 1.0) -> None:
        super().__init__(verbose=0)
        self.reporter, self.scale = reporter, scale

    def _on_step(self) -> bool:
        self.reporter.update(round(self.num_timesteps * self.scale))
        return True

    def _on_training_end(self) -> None:
        self.reporter.close()


def console_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The metrics an evaluation line shows: each group's return (``adversary_return``, for runs of one model per
    group) and the env's declared scalar metrics."""
    shown = {f"{g}_return": float(v) for g, v in (metrics.get("per_group_return") or {}).items()}
    shown.update({k: float(v) for k, v in metrics.items() if isinstance(v, int | float) and k != "episode_length"})
    return shown


class EvalReportCallback(BaseCallback):
    """``callback_after_eval`` of an ``EvalCallback`` (or a subclass): reports its latest evaluation.

    Reads the parent's ``evaluations_results[-1]`` (episode returns), its success buffer and, when the parent
    has one, ``last_result["metrics"]`` (e.g. a team evaluation's per-episode metrics).
    """

    def __init__(self, reporter: ProgressReporter, scale: float = 1.0) -> None:
        super().__init__(verbose=0)
        self.reporter, self.scale = reporter, scale

    def _on_step(self) -> bool:
        parent = self.parent
        if parent is None:
            return True
        results = getattr(parent, "evaluations_results", None)  # EvalCallback keeps them when it has a log_path
        returns = results[-1] if results else [float(getattr(parent, "last_mean_reward", float("nan")))]
        successes = list(getattr(parent, "_is_success_buffer", []))
        metrics = (getattr(parent, "last_result", None) or {}).get("metrics") or {}
        scalars = console_metrics(metrics)
        self.reporter.evaluation(
            round(self.num_timesteps * self.scale), float(np.mean(returns)), float(np.std(returns)),
            float(np.mean(successes)) if successes else None, scalars,
        )
        return True


def format_evaluation(summary: Mapping[str, Any]) -> str:
    """An evaluation summary (``evaluate``) as a two-column text table, trust results included."""
    if "win_rate" in summary:  # a turn-based game's match
        rows = [(k, summary[k]) for k in ("env", "algo", "opponent", "n_games", "win_rate", "draw_rate",
                                          "loss_rate", "mean_reward")]
        rows.append(("reward_ci95", "[{:.4g}, {:.4g}]".format(*summary["reward_ci95"])))
        rows += [(f"{seat}.win/draw/loss", "{win_rate:.3f} / {draw_rate:.3f} / {loss_rate:.3f}".format(**rates))
                 for seat, rates in summary["per_seat"].items() if rates["n_games"]]
        rows += [("illegal_moves", summary["illegal_moves"]), ("mean_length", summary["mean_length"])]
    else:
        rows = [(k, summary[k]) for k in ("env", "algo", "n_episodes", "mean_return", "std_return", "mean_length",
                                          "success_rate")]
        rows += [("mean_cost", summary["mean_cost"])] if "mean_cost" in summary else []
    for key, value in summary["metrics"].items():
        items = value.items() if isinstance(value, dict) else [(None, value)]
        rows += [(f"metrics.{key}" + (f".{sub}" if sub is not None else ""), v) for sub, v in items]
    rows += [(f"attack.{r['label']}.mean_return", r["mean_return"]) for r in summary.get("adversarial", [])]
    if "fairness" in summary:
        fair = summary["fairness"]
        rows += [("fairness.metric", fair["metric"]), ("fairness.worst_bucket_value", fair["worst"]["value"]),
                 ("fairness.gap", fair["gap"])]
    width = max(len(k) for k, _ in rows)
    table = "\n".join(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}" for k, v in rows)
    return table + (f"\nnote: {summary['env']}: {summary['note']}" if summary.get("note") else "")


def train_summary_lines(summary: Mapping[str, Any], run_dir: Any, interrupted: bool) -> list[str]:
    """The lines ``train`` ends with: where the run went, its speed and its final evaluation, then every extension's
    lines of its ``summary.json`` items (:meth:`~sbagents.extensions.TrainingExtension.describe`)."""
    if interrupted:
        lines = [f"interrupted after {summary['n_timesteps']} steps; model and logs saved in {run_dir}"]
    else:
        lines = [f"run dir: {run_dir}  ({summary['train_seconds']:.1f} s, {summary['fps']:.0f} steps/s)"]
        lines += _evaluation_lines(summary.get("eval"))
    for extension in registered_extensions():  # e.g. the replay buffer, a constraint's verdicts, DP's epsilon
        lines += extension.describe(summary, Path(run_dir))
    return lines


def _evaluation_lines(ev: Mapping[str, Any] | None) -> list[str]:
    """The final evaluation's line (none without one)."""
    if ev and "win_rate" in ev:
        return [f"evaluation against {ev['opponent']}: win {ev['win_rate']:.2f}, draw {ev['draw_rate']:.2f}, "
                f"loss {ev['loss_rate']:.2f} over {ev['n_games']} games (seats alternating), "
                f"mean reward {ev['mean_reward']:.3f}"]
    if ev:
        success = "" if ev["success_rate"] is None else f", success rate {ev['success_rate']:.2f}"
        metrics = "".join(f", {k} {v:.3g}" for k, v in console_metrics(ev["metrics"]).items())
        cost = "" if ev.get("mean_cost") is None else f", mean episode cost {ev['mean_cost']:.3g}"
        return [f"evaluation: mean return {ev['mean_return']:.2f} +- {ev['std_return']:.2f} over "
                f"{ev['n_episodes']} episodes{success}{cost}{metrics}",
                *([f"note: {ev['env']}: {ev['note']}"] if ev.get("note") else [])]
    return []

