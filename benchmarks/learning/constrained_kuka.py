"""SAC, SAC with a -50 zone penalty and SAC-Lagrangian on RobustPickAndPlace with the cost-only path zone.

The env (``benchmarks/configs/kuka_constrained.yml``): ``sbagents/RobustPickAndPlace-v0`` in end-effector control with
the dense reward, ``safety_zone="path"`` (a box under the ready pose, across the arm's direct way down to the block)
and ``zone_mode="cost"``: a step into the zone is applied and costs 1 (``info["cost"]``). Methods, same entry and
seed:

- ``sac``: reward only (no penalty);
- ``sac -50 penalty``: ``zone_penalty=-50`` added to the reward of every zone step (same dynamics: the book's -50,
  but the step is not undone);
- ``sac-lagrangian``: :class:`~sbagents.constrained.SACLagrangian` with ``cost_limit`` (episode cost).

Each is evaluated greedily on fresh episodes: success rate, mean episode cost (EpCost) and the task return (reward
without the penalty). The runs the results file already holds (``--stored``, by default
``benchmarks/results/constrained_kuka.json``; same budget, settings and config entry) are kept and not redone, so a
rerun with more ``--seeds`` only trains the missing (method, seed) pairs, and processes for different methods add
their runs to each other's (the file is re-read just before the results are returned);
``--evaluate-checkpoints`` adds the missing pairs from their newest checkpoint under ``--logs`` (marked partial,
with the steps they reached). ``python -m benchmarks render constrained-kuka`` rebuilds the section.

    python -m benchmarks run constrained-kuka [-n 120000] [--seeds 0 1 2] [--cost-limit 1] [--methods ...]
"""

from __future__ import annotations

import argparse
import json
import shlex
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.monitor import Monitor

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import RESULTS_DIR, recorded_argv
from sbagents.constrained import SACLagrangian

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "kuka_constrained.yml"
ENV = "sbagents/RobustPickAndPlace-v0"
SECTION = "constrained-kuka"
PENALTY = -50.0
METHODS = ("sac-lagrangian", "sac", "sac -50 penalty")
#: Arguments that must match for stored runs to be kept (the config entry must match too).
SETTINGS = ("n_timesteps", "cost_limit", "multiplier_lr", "episodes")


class EpisodeStats(BaseCallback):
    """Records each finished training episode's cost (sum of ``info["cost"]``) and ``is_success``."""

    def __init__(self) -> None:
        super().__init__()
        self.costs: list[float] = []
        self.successes: list[bool] = []
        self._running: np.ndarray | None = None

    def _on_step(self) -> bool:
        infos, dones = self.locals["infos"], self.locals["dones"]
        if self._running is None:
            self._running = np.zeros(len(infos))
        self._running += [float(info.get("cost", 0.0)) for info in infos]
        for idx in np.flatnonzero(dones):
            self.costs.append(float(self._running[idx]))
            self.successes.append(bool(infos[idx].get("is_success", False)))
            self._running[idx] = 0.0
        return True


def evaluate(model: Any, env: gym.Env[Any, Any], episodes: int, penalty: float) -> dict[str, float]:
    """Greedy episodes (seeds 10000...): success rate, mean episode cost, mean task return (penalty removed)."""
    success, costs, returns = [], [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=10_000 + episode)
        done, total, cost = False, 0.0, 0.0
        info: dict[str, Any] = {}
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            cost += float(info.get("cost", 0.0))
            done = terminated or truncated
        success.append(bool(info.get("is_success")))
        costs.append(cost)
        returns.append(total - penalty * cost)
    return {"success": float(np.mean(success)), "cost": float(np.mean(costs)), "return": float(np.mean(returns))}


def method_env(method: str) -> tuple[str, dict[str, Any], float, dict[str, Any]]:
    """The config entry's policy, env kwargs (with the method's ``zone_penalty``), penalty and hyperparameters."""
    entry = dict(yaml.safe_load(CONFIG.read_text())[ENV])
    entry.pop("n_timesteps")
    policy = entry.pop("policy")
    penalty = PENALTY if method == "sac -50 penalty" else 0.0
    return policy, {**entry.pop("env_kwargs"), "zone_penalty": penalty}, penalty, entry


def run_one(
    method: str, seed: int, n_timesteps: int, cost_limit: float, multiplier_lr: float, episodes: int, logs: Path
) -> dict[str, Any]:
    """Train one method on one seed (checkpoints every 10k steps under ``logs``), then evaluate it greedily."""
    import sbagents.envs  # noqa: F401  (registers the ids; imported here so that list and render need no pybullet)

    policy, env_kwargs, penalty, entry = method_env(method)
    env = Monitor(gym.make(ENV, **env_kwargs))
    folder = logs / f"{method.replace(' ', '_')}_{seed}"
    if method == "sac-lagrangian":
        model: SAC = SACLagrangian(
            policy,
            env,
            cost_limit=cost_limit,
            multiplier_kwargs={"lr": multiplier_lr},
            seed=seed,
            device="cpu",
            **entry,
        )
    else:
        model = SAC(policy, env, seed=seed, device="cpu", **entry)
    stats = EpisodeStats()
    start = time.perf_counter()
    model.learn(n_timesteps, callback=[stats, CheckpointCallback(10_000, str(folder), name_prefix="model")])
    train_s = time.perf_counter() - start
    model.save(folder / "final")
    result = evaluate(model, gym.make(ENV, **env_kwargs), episodes, penalty)
    multiplier = getattr(model, "multiplier", None)
    return {
        "method": method,
        "seed": seed,
        "n_timesteps": n_timesteps,
        "train_s": train_s,
        **result,
        "train_cost_last100": float(np.mean(stats.costs[-100:])),
        "train_success_last100": float(np.mean(stats.successes[-100:])),
        "multiplier": None if multiplier is None else multiplier.value,
        "history": [] if multiplier is None else multiplier.history[:: max(1, len(multiplier.history) // 200)],
    }


def evaluate_checkpoint(method: str, seed: int, episodes: int, logs: Path) -> dict[str, Any]:
    """Evaluate the newest checkpoint of an unfinished run (``model_<steps>_steps.zip``); marked ``partial``."""
    import sbagents.envs  # noqa: F401  (registers the ids)

    folder = logs / f"{method.replace(' ', '_')}_{seed}"
    checkpoints = sorted(folder.glob("model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[1]))
    if not checkpoints:
        raise SystemExit(f"no checkpoint of {method} under {folder}")
    _, env_kwargs, penalty, _ = method_env(method)
    cls = SACLagrangian if method == "sac-lagrangian" else SAC
    model = cls.load(checkpoints[-1], device="cpu")
    multiplier = getattr(model, "multiplier", None)
    return {
        "method": method,
        "seed": seed,
        "n_timesteps": int(checkpoints[-1].stem.split("_")[1]),
        "partial": True,
        "train_s": None,
        **evaluate(model, gym.make(ENV, **env_kwargs), episodes, penalty),
        "train_cost_last100": None,
        "train_success_last100": None,
        "multiplier": None if multiplier is None else multiplier.value,
        "history": [],
    }


def _cell(value: float | None, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def _row(label: str, steps: str, r: dict[str, Any]) -> str:
    minutes = None if r.get("train_s") is None else r["train_s"] / 60
    return (
        f"| {label} | {steps} | {r['success']:.2f} | {r['cost']:.2f} | {r['return']:.1f} | "
        f"{_cell(r.get('train_cost_last100'), '.2f')} | {_cell(r.get('train_success_last100'), '.2f')} | "
        f"{_cell(r.get('multiplier'), '.2f')} | {_cell(minutes, '.0f')} |"
    )


def findings(result: dict[str, Any]) -> list[str]:
    """Plain statements from the numbers: each method's mean EpCost against the limit, and whether anything
    succeeded at all."""
    limit = result["args"]["cost_limit"]
    out = []
    for method in METHODS:
        runs = [r for r in result["runs"] if r["method"] == method]
        if runs:
            cost = float(np.mean([r["cost"] for r in runs]))
            side = "within" if cost <= limit else "above"
            per_seed = ", ".join(format(r["cost"], ".2f") for r in runs)
            out.append(f"- {method}: mean greedy EpCost {cost:.2f}, {side} the limit {limit:g} (per seed: {per_seed}).")
    if result["runs"] and all(r["success"] == 0 for r in result["runs"]):
        out.append(
            "- No run pushed the block onto the target at this budget (SAC needs ~120k steps on the easier "
            "PickAndPlace, section kuka-learning), so the success-rate side of the comparison is not "
            "measured here: only the cost side and the task return (reaching the block) are."
        )
    return out


def _kwargs(config: dict[str, Any]) -> str:
    return ", ".join(f"`{key}: {value}`" for key, value in config["env_kwargs"].items())


def _train_minutes(result: dict[str, Any]) -> float:
    return sum(r["train_s"] or 0.0 for r in result["runs"]) / 60


def markdown(result: dict[str, Any]) -> str:
    """The ``constrained-kuka`` section: command, setup, one row per (method, seed) and the mean over seeds."""
    a = result["args"]
    lines = [
        "## Constrained SAC on RobustPickAndPlace (cost-only path zone)",
        "",
        f"{' and '.join(f'`{c}`' for c in result['commands'])} — {ENV} with `benchmarks/configs/kuka_constrained.yml` "
        f"(ee control, dense reward, ready pose, `safety_zone: path`, `zone_mode: cost`: a zone step is applied and "
        f"costs 1; env kwargs {_kwargs(result['config'])}), {a['n_timesteps']} steps per method, seeds "
        f"{', '.join(map(str, a['seeds']))}, cost limit {a['cost_limit']:g} zone steps per episode, multiplier "
        f"lr {a['multiplier_lr']:g}, greedy evaluation on {a['episodes']} fresh episodes. Machine: 2 cores, two runs "
        f"at a time, torch 1 thread; training time summed over the runs {_train_minutes(result):.0f} min.",
        "",
        "The `-50 penalty` row adds -50 to the reward of every zone step (the step is still applied, so all rows "
        "share the dynamics); task return = reward without that penalty. success, EpCost and task return: greedy "
        "(deterministic) actions, SB3's evaluation convention. Train columns: the last 100 training episodes, with "
        "SAC's stochastic actions"
        + ("; a partial row was stopped at the session's deadline and evaluated from its last checkpoint."
           if any(r.get("partial") for r in result["runs"]) else "."),
        "",
        "| method (seed) | steps | success | EpCost | task return | train EpCost | train success | final lambda | "
        "minutes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method in METHODS:
        runs = sorted((r for r in result["runs"] if r["method"] == method), key=lambda r: r["seed"])
        for r in runs:
            steps = f"{r['n_timesteps']}" + (" (partial)" if r.get("partial") else "")
            lines.append(_row(f"{method} ({r['seed']})", steps, r))
        if len(runs) > 1:
            mean = {key: float(np.mean([r[key] for r in runs])) for key in ("success", "cost", "return")}
            lines.append(_row(f"**{method} mean**", "", mean))
    lines += ["", *findings(result)]
    rows: list[StatsRow] = [(method, label, result["stats"][method][key], fmt)
                            for method in METHODS if method in result["stats"]
                            for key, (label, fmt) in STATS_METRICS.items()]
    if rows:
        lines += ["", *grouped_stats_table("method", rows)]
    done = {(r["method"], r["seed"]) for r in result["runs"]}
    missing = [f"{m} ({seed})" for seed in a["seeds"] for m in a["methods"] if (m, seed) not in done]
    if missing:
        lines += ["", f"Not finished in this session: {', '.join(missing)}."]
    return "\n".join(lines)


def recorded_command(argv: Sequence[str]) -> str:
    """The command as published: ``--logs`` and ``--stored`` (folders of this machine, not settings) left out."""
    local = {"--logs", "--stored"}
    kept = [arg for i, arg in enumerate(argv) if arg not in local and (i == 0 or argv[i - 1] not in local)]
    return shlex.join(["python", "-m", "benchmarks", "run", SECTION, *recorded_argv(kept)])


#: The metrics of the over-seeds table: run key -> (label, number format).
STATS_METRICS = {"success": ("success", ".2f"), "cost": ("EpCost", ".2f"), "return": ("task return", ".1f")}


def add_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[method][metric]``: greedy success, EpCost and task return over its seeds."""
    stats = {}
    for method in METHODS:
        runs = sorted((r for r in result["runs"] if r["method"] == method), key=lambda r: r["seed"])
        if runs:
            stats[method] = {key: stats_of([r[key] for r in runs]) for key in STATS_METRICS}
    return {**result, "stats": stats}


def stored_runs(path: Path, args: argparse.Namespace, config: dict[str, Any]) -> list[dict[str, Any]]:
    """The runs ``path`` holds for this config and these settings (budget, limit, multiplier lr, episodes)."""
    if not path.exists():
        return []
    old = json.loads(path.read_text())
    same = old.get("config") == config and all(old["args"].get(k) == getattr(args, k) for k in SETTINGS)
    return list(old["runs"]) if same else []


def merged(
    path: Path, args: argparse.Namespace, config: dict[str, Any], command: str, outcomes: list[dict[str, Any]]
) -> dict[str, Any]:
    """The results file with ``outcomes`` added, re-read just before returning, so that processes sharing one
    results file (say, one per method) keep each other's runs; ``commands`` lists every command that added runs."""
    old = json.loads(path.read_text()) if path.exists() else {}
    runs = stored_runs(path, args, config)
    commands = old.get("commands", []) if runs else []
    seeds = sorted({*(old["args"]["seeds"] if runs else []), *args.seeds})
    methods = [m for m in METHODS if m in {*(old["args"]["methods"] if runs else []), *args.methods}]
    return {
        "commands": [*commands, command] if command not in commands else commands,
        "args": {**{k: v for k, v in vars(args).items() if k not in ("logs", "stored")}, "seeds": seeds,
                 "methods": methods},
        "config": config,
        "runs": [*runs, *outcomes],
    }


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-n", "--n-timesteps", type=int, default=120_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--cost-limit", type=float, default=1.0)
    parser.add_argument("--multiplier-lr", type=float, default=0.05)
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--logs", default="logs/constrained_kuka", help="checkpoints and final models")
    parser.add_argument("--stored", default=str(RESULTS_DIR / "constrained_kuka.json"),
                        help="results whose runs (same budget and settings) are kept, not redone")
    parser.add_argument("--evaluate-checkpoints", action="store_true",
                        help="add the (method, seed) runs missing from --stored from their newest checkpoint")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train (or evaluate from checkpoints) the (method, seed) pairs ``--stored`` lacks; the merged results."""
    args = build_parser().parse_args(list(argv))
    path = Path(args.stored)
    th.set_num_threads(1)
    command = recorded_command(list(argv))
    config = yaml.safe_load(CONFIG.read_text())[ENV]
    outcomes = []
    for seed in args.seeds:
        for method in args.methods:
            if (method, seed) in {(r["method"], r["seed"]) for r in stored_runs(path, args, config)}:
                continue
            if args.evaluate_checkpoints:
                outcomes.append(evaluate_checkpoint(method, seed, args.episodes, Path(args.logs)))
            else:
                outcomes.append(run_one(method, seed, args.n_timesteps, args.cost_limit, args.multiplier_lr,
                                        args.episodes, Path(args.logs)))
            print(json.dumps({k: v for k, v in outcomes[-1].items() if k != "history"}), flush=True)
    return add_stats(merged(path, args, config, command, outcomes))


BENCHMARKS = (
    Benchmark(name=SECTION, kind="learning", results="constrained_kuka.json",
              summary="SAC, SAC with a -50 zone penalty and SAC-Lagrangian on RobustPickAndPlace: success and EpCost",
              run=run, render=markdown),
)
