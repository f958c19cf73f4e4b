"""Our side of ``benchmarl-spread``: the shipped ``mpe2.simple_spread_v3`` entry trained through the CLI
(``python -m sbagents.train``), the checkpoints kept for each agent-step and wall-time budget, and their
evaluation on the benchmark's episodes (and with ``python -m sbagents.evaluate``)."""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.learning.benchmarl_side import ENV, last_json
from benchmarks.report import load_average


def _default_sigint() -> None:
    """In the child: SIGINT raises KeyboardInterrupt again (a benchmark started in the background, e.g. with
    ``nohup ... &``, passes on an ignored SIGINT, and Python then never installs its handler)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def cli(module: str, *args: str, timeout: float | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m sbagents.<module> args`` (checked); past ``timeout`` seconds it gets SIGINT (Ctrl-C: the run
    saves what it has and stops)."""
    proc = subprocess.Popen([sys.executable, "-m", f"sbagents.{module}", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate()
    if proc.returncode not in (0, 130, -signal.SIGINT):
        raise subprocess.CalledProcessError(proc.returncode, proc.args, stdout, stderr)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def ours_train(seed: int, folder: Path, n_timesteps: int | None, save_freq: int, max_seconds: float,
               reuse: bool = False) -> dict[str, Any]:
    """One run of the shipped entry; its run dir, summary and per-checkpoint training seconds.

    A checkpoint's seconds: ``train_seconds`` minus the time between it and the final model's save (as
    ``pettingzoo_learning``); for a run stopped at ``max_seconds`` without a summary, seconds since the command
    started (import and env build included). ``reuse``: a run this function finished in ``folder`` before is taken
    as it is.
    """
    from sbagents.core.run_dir import saved_checkpoints

    record = folder / "bench_run.json"
    if reuse and record.exists():
        done = json.loads(record.read_text())
        start, load_start, load_end = done["start"], done["load_start"], done["load_end"]
    else:
        n = ["-n", str(n_timesteps)] if n_timesteps else []
        load_start = load_average()
        start = time.time()
        cli("train", "--algo", "ppo", "--env", ENV, "--seed", str(seed), "-f", str(folder), *n, "--save-freq",
            str(save_freq), "--eval-freq", "0", "--final-eval-episodes", "0", "--verbose", "0",
            timeout=max_seconds)
        load_end = load_average()
        record.write_text(json.dumps({"start": start, "load_start": load_start, "load_end": load_end}))
    run_dir = sorted((folder / "ppo").iterdir(), key=lambda p: p.stat().st_mtime)[-1]
    summary_path = run_dir / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    final = run_dir / f"{summary.get('env', ENV)}.zip"
    if "train_seconds" in summary and final.exists():
        end = final.stat().st_mtime
        times = {s: summary["train_seconds"] - (end - p.stat().st_mtime) for s, p in saved_checkpoints(run_dir).items()}
    else:
        times = {s: p.stat().st_mtime - start for s, p in saved_checkpoints(run_dir).items()}
    return {"run_dir": run_dir, "summary": summary, "final": final.exists(), "checkpoints": times,
            "load_start": load_start, "load_end": load_end}


def ours_exact_episodes(log_folder: Path, exp_id: int, checkpoint: int | None, n: int, seed: int) -> dict[str, Any]:
    """A run's greedy team on the benchmark's episodes (episode ``k`` reset with seed ``seed + k``): a model of raw
    observations (shared policy, no agent id, wrapper or normalisation) plays them in the venv script's batched loop,
    any other through sbagents' own team VecEnv (mpe2's parallel env, wrapped as in training, frozen normalisation),
    one episode at a time."""
    import numpy as np

    from sbagents.core.run_dir import RunRef, load_run
    from sbagents.core.team_options import TeamOptions
    from sbagents.env_factory import make_team_vecs, normalize_for_eval
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes

    run = load_run(RunRef("ppo", ENV, log_folder, exp_id=exp_id, checkpoint=checkpoint))
    exp = run.experiment
    team = TeamOptions.of(exp)
    if (not exp.normalize and not exp.env_wrapper and not exp.vec_env_wrapper and not exp.frame_stack
            and team.policies == "shared" and not team.agent_id and len(run.models) == 1):
        # the policy sees mpe2's own observations: play 100 episodes side by side, one predict per step
        from benchmarks.learning.benchmarl_venv import spread_episodes

        (model,) = run.models.values()

        def act(obs: np.ndarray) -> np.ndarray:
            actions, _ = model.predict(obs.reshape(-1, obs.shape[-1]), deterministic=True)
            return np.asarray(actions).reshape(obs.shape[:2])

        returns = spread_episodes(act, n, seed)
        return {"mean_return": float(np.mean(returns)), "std_return": float(np.std(returns)), "n_episodes": n,
                "path": "mpe2 loop"}
    venvs = make_team_vecs(exp, run.env, 1, None, vec_env="dummy")
    venvs = {g: normalize_for_eval(v, exp, run.stats_paths.get(g)) for g, v in venvs.items()}
    try:
        actors = {g: model_actor(run.models[g], True) for g in venvs}
        returns = [run_team_episodes(venvs, actors, 1, seed + k)[0].ret for k in range(n)]
    finally:
        for venv in venvs.values():
            venv.close()
    return {"mean_return": float(np.mean(returns)), "std_return": float(np.std(returns)), "n_episodes": n,
            "path": "team VecEnv"}


def ours_cli_eval(log_folder: Path, exp_id: int, checkpoint: int | None, n: int, seed: int) -> float:
    """``python -m sbagents.evaluate ... -n N --seed SEED --json``: its mean team return."""
    ck = ["--load-checkpoint", str(checkpoint)] if checkpoint is not None else []
    out = cli("evaluate", "--algo", "ppo", "--env", ENV, "-f", str(log_folder), "--exp-id", str(exp_id), *ck,
              "-n", str(n), "--seed", str(seed), "--json")
    return float(last_json(out.stdout)["mean_return"])


def pick_checkpoints(run: dict[str, Any], agent_budgets: Sequence[int], second_budgets: Sequence[float]
                     ) -> list[dict[str, Any]]:
    """The policies of a run kept for each budget: the first checkpoint at or past each agent-step budget (else the
    final model when it has that many steps), the last checkpoint within each wall-time budget (the final model if
    the whole run fit)."""
    steps_total = run["summary"].get("n_timesteps")
    train_s = run["summary"].get("train_seconds")
    times: dict[int, float] = run["checkpoints"]
    kept = []
    for b in agent_budgets:
        past = [s for s in times if s >= b]
        if past:
            s = min(past)
            kept.append({"label": f"agent_steps{b}", "agent_steps": s, "train_s": round(times[s], 1), "checkpoint": s})
        elif run["final"] and steps_total is not None and steps_total >= b:
            kept.append({"label": f"agent_steps{b}", "agent_steps": steps_total, "train_s": round(train_s, 1),
                         "checkpoint": None})
    for sec in second_budgets:
        if run["final"] and train_s is not None and train_s <= sec:
            kept.append({"label": f"seconds{sec:g}", "agent_steps": steps_total, "train_s": round(train_s, 1),
                         "checkpoint": None})
            continue
        within = [s for s, t in times.items() if t <= sec]
        if within:
            s = max(within)
            kept.append({"label": f"seconds{sec:g}", "agent_steps": s, "train_s": round(times[s], 1), "checkpoint": s})
    return kept


def fitted_budget(run: dict[str, Any], seconds: float, step: int) -> int | None:
    """``-n`` for a run of about ``seconds`` at the speed of ``run`` (a multiple of ``step``); None when ``run``
    already took that long."""
    summary = run["summary"]
    if not summary.get("train_seconds") or summary["train_seconds"] >= seconds:
        return None
    return max(step, int(summary["n_timesteps"] / summary["train_seconds"] * seconds) // step * step)


def run_ours(seed: int, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Our side for one seed: the entry's own budget, then a run fitted to the longest wall-time budget."""
    longest = max(args.second_budgets)
    short_budgets = [s for s in args.second_budgets if s < longest]
    first = ours_train(seed, work / f"ours_seed{seed}_entry", args.ours_n, args.save_freq, longest + 60,
                       args.reuse)
    runs = [(first, pick_checkpoints(first, args.agent_budgets, short_budgets or args.second_budgets))]
    n_long = fitted_budget(first, longest, args.save_freq)
    if n_long is not None and short_budgets and args.fitted:
        long = ours_train(seed, work / f"ours_seed{seed}_fitted", n_long, args.save_freq, longest + 60,
                          args.reuse)
        runs.append((long, pick_checkpoints(long, [], [longest])))
    elif short_budgets:
        runs[0] = (first, pick_checkpoints(first, args.agent_budgets, args.second_budgets))
    out = []
    for run, kept in runs:
        folder = run["run_dir"].parent.parent
        exp_id = int(run["run_dir"].name.rsplit("_", 1)[1])
        cache_path = folder / f"bench_evals_n{args.n_eval}_seed{args.eval_seed}.json"
        cache = json.loads(cache_path.read_text()) if args.reuse and cache_path.exists() else {}
        for k in kept:
            key = str(k["checkpoint"])
            if key not in cache:
                exact = ours_exact_episodes(folder, exp_id, k["checkpoint"], args.n_eval, args.eval_seed)
                cache[key] = {"team_return": round(exact["mean_return"], 3),
                              "std_return": round(exact["std_return"], 3)}
            if args.cli_eval and "cli_team_return" not in cache[key]:
                cache[key]["cli_team_return"] = round(ours_cli_eval(folder, exp_id, k["checkpoint"], args.n_eval,
                                                                    args.eval_seed), 3)
            cache_path.write_text(json.dumps(cache))
            k.update(cache[key])
        s = run["summary"]
        out.append({"n_timesteps": s.get("n_timesteps"), "train_s": s.get("train_seconds"), "fps": s.get("fps"),
                    "interrupted": not run["final"], "load_start": run["load_start"], "load_end": run["load_end"],
                    "kept": kept})
    return {"seed": seed, "runs": out}


def ours_entry() -> dict[str, Any]:
    """The shipped entry's hyperparameters as the benchmark ran it."""
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec
    from sbagents.core.team_options import TeamOptions

    exp = build_experiment(TrainSpec("ppo", ENV), resolve_env(ENV))
    return {"n_envs": exp.n_envs, "normalize": jsonable(exp.normalize), "hyperparams": jsonable(exp.hyperparams),
            "team": jsonable(vars(TeamOptions.of(exp)))}


def jsonable(value: Any) -> Any:
    """``value`` with everything JSON cannot hold (schedules, classes) as its ``str``."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return str(value)

