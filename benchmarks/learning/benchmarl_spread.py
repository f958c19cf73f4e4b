"""BenchMARL's MAPPO and IPPO beside our PPO on mpe2 ``simple_spread_v3`` (N=3, 25 steps, discrete actions,
local_ratio 0.5), same machine, same agent-step budgets (1M, 4M) and wall-time budgets (5, 10 min), evaluated on the
same 1,000 episodes::

    python -m benchmarks run benchmarl-spread                       # seed 0, both algorithms, both libraries
    python -m benchmarks run benchmarl-spread --seeds 0 1 --reuse   # keep finished runs of --work-dir

BenchMARL (on TorchRL) runs in a venv of its own (``--venv``, default ``.venv-benchmarl/`` at the repo root), created
on first use with CPU torch and the mpe2 we use; its training and evaluation are
``benchmarks/learning/benchmarl_venv.py`` run by that venv's python. One BenchMARL run per algorithm and seed serves
every budget: it keeps the policy at the first batch past each agent-step budget and at the last batch within each
wall-time budget, and stops after the last budget (or at ``--max-seconds``).

Our side is the shipped ``mpe2.simple_spread_v3`` entry of ``zoo_configs/ppo.yml`` as it is when the benchmark runs:
``python -m sbagents.train --algo ppo --env mpe2.simple_spread_v3 --seed S --save-freq F`` (periodic evaluations
off, as BenchMARL's): one run at the entry's own budget (the 1M-step checkpoint, the 4M/final model, the last
checkpoint within 5 min), one at ``-n`` fitted to 10 minutes from that run's speed (the last checkpoint within 10 min,
or its final model). Every kept policy is evaluated greedily on mpe2's own env, episode ``k`` reset with seed
``10000 + k`` (``benchmarl_venv.spread_episodes``; our runs through the same episodes via sbagents' team VecEnv), and
our final models also with ``python -m sbagents.evaluate -n 1000 --seed 10000 --json`` (the CLI's episodes: one
seeded reset, then the env's RNG).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import grouped_stats_table, stats_of
from benchmarks.report import BENCHMARKS_DIR, load_average, machine_info, recorded_argv

REPO = BENCHMARKS_DIR.parent
#: The venv script (run by the BenchMARL venv's python).
VENV_SCRIPT = Path(__file__).resolve().with_name("benchmarl_venv.py")
ENV = "mpe2.simple_spread_v3"
N_AGENTS = 3
#: BenchMARL release the venv gets, and the torch / torchvision it is given (CPU torch; TorchRL accepts it).
BENCHMARL_VERSION = "1.5.2"
TORCH_PINS = ("torch==2.13.0", "torchvision==0.28.0")
#: BenchMARL's default on-policy frames (env steps) per batch.
FRAMES_PER_BATCH = 6000


def frame_budget(agent_steps: int, frames_per_batch: int = FRAMES_PER_BATCH) -> int:
    """Env (team) steps of the first BenchMARL batch at or past ``agent_steps`` agent steps (3 agents)."""
    if agent_steps <= 0 or frames_per_batch <= 0:
        raise ValueError(f"budgets must be positive, got {agent_steps} agent steps, {frames_per_batch} frames/batch")
    return math.ceil(agent_steps / N_AGENTS / frames_per_batch) * frames_per_batch


def team_to_mappo(team_return: float) -> float:
    """MAPPO's logged score of a team return: R = 2T - 75 (its reward counts self-collisions, sums over agents)."""
    return 2.0 * team_return - 75.0


def venv_python(venv: Path) -> Path:
    """The python of a venv."""
    return venv / "bin" / "python"


def ensure_venv(venv: Path) -> Path:
    """BenchMARL's venv, created on first use (CPU torch first, then BenchMARL and our mpe2 version); its python."""
    python = venv_python(venv)
    if python.exists():
        return python
    mpe2_version = metadata.version("mpe2")
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(venv)], check=True)
    constraints = venv / "constraints.txt"
    constraints.write_text("\n".join(TORCH_PINS) + "\n")
    pip = [str(python), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, TORCH_PINS[0]], check=True)
    subprocess.run([*pip, "-c", str(constraints), f"benchmarl=={BENCHMARL_VERSION}", f"mpe2=={mpe2_version}"],
                   check=True)
    return python


def venv_versions(python: Path) -> dict[str, str]:
    """Versions of the BenchMARL venv's packages."""
    code = ("import json, importlib.metadata as m; print(json.dumps({p: m.version(p) for p in "
            "('benchmarl', 'torchrl', 'tensordict', 'torch', 'mpe2', 'pettingzoo')}))")
    return dict(json.loads(subprocess.run([str(python), "-c", code], capture_output=True, text=True,
                                          check=True).stdout))


def last_json(stdout: str) -> Any:
    """The last line of a command's output, as JSON."""
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise RuntimeError("the command printed no JSON result")
    return json.loads(lines[-1])


def benchmarl_train_args(algo: str, seed: int, out: Path, agent_budgets: Sequence[int],
                         second_budgets: Sequence[float], max_seconds: float,
                         frames_per_batch: int | None = None) -> list[str]:
    """The venv script's ``train`` arguments for one run."""
    fpb = frames_per_batch or FRAMES_PER_BATCH
    frames = [frame_budget(b, fpb) for b in agent_budgets]
    args = ["train", "--algo", algo, "--seed", str(seed), "--out", str(out),
            "--frame-budgets", *map(str, frames), "--second-budgets", *(f"{s:g}" for s in second_budgets),
            "--max-seconds", f"{max_seconds:g}"]
    return args + (["--frames-per-batch", str(frames_per_batch)] if frames_per_batch else [])


def run_benchmarl(python: Path, algo: str, seed: int, work: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Train (or reuse, with ``--reuse``) one BenchMARL run and evaluate its kept policies."""
    out = work / f"benchmarl_{algo}_seed{seed}"
    train_json = out / "train.json"
    if not (args.reuse and train_json.exists()):
        out.mkdir(parents=True, exist_ok=True)
        cmd = [str(python), str(VENV_SCRIPT), *benchmarl_train_args(
            algo, seed, out, args.agent_budgets, args.second_budgets, args.max_seconds, args.frames_per_batch)]
        with (out / "stdout.log").open("w") as log:
            subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True)
    train = json.loads(train_json.read_text())
    policies = [str(out / f"policy_{k['label']}.pt") for k in train["kept"]]
    cache = out / f"evals_n{args.n_eval}_seed{args.eval_seed}.json"
    evals = json.loads(cache.read_text()) if args.reuse and cache.exists() else {}
    if not all(Path(p).name in evals for p in policies):
        evals = last_json(subprocess.run([str(python), str(VENV_SCRIPT), "eval", "--algo", algo, "--policies",
                                          *policies, "-n", str(args.n_eval), "--seed", str(args.eval_seed)],
                                         capture_output=True, text=True, check=True).stdout)
        cache.write_text(json.dumps(evals))
    budgets = {f"frames{frame_budget(b, args.frames_per_batch or FRAMES_PER_BATCH)}": f"agent_steps{b}"
               for b in args.agent_budgets}
    for kept in train["kept"]:
        kept["budget"] = budgets.get(kept["label"], kept["label"])
        kept["team_return"] = round(evals[f"policy_{kept['label']}.pt"]["mean_return"], 3)
        kept["std_return"] = round(evals[f"policy_{kept['label']}.pt"]["std_return"], 3)
    return train


# --- our side -------------------------------------------------------------------------------------------------


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
    from sbagents.env_factory import make_team_vecs, normalize_for_eval
    from sbagents.multiagent.team_eval import model_actor, run_team_episodes

    run = load_run(RunRef("ppo", ENV, log_folder, exp_id=exp_id, checkpoint=checkpoint))
    exp = run.experiment
    team = exp.team
    if (not exp.normalize and not exp.env_wrapper and not exp.vec_env_wrapper and not exp.frame_stack
            and team is not None and team.policies == "shared" and not team.agent_id and len(run.models) == 1):
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

    exp = build_experiment(TrainSpec("ppo", ENV), resolve_env(ENV))
    return {"n_envs": exp.n_envs, "normalize": jsonable(exp.normalize), "hyperparams": jsonable(exp.hyperparams),
            "team": jsonable(vars(exp.team)) if exp.team is not None else None}


def jsonable(value: Any) -> Any:
    """``value`` with everything JSON cannot hold (schedules, classes) as its ``str``."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    return str(value)


#: What differs between the two sides (BenchMARL's values from its default configs in the venv's release).
BENCHMARL_SETTINGS: dict[str, str] = {
    "network": "MLP 256-256, tanh, actor and critic separate",
    "parameter sharing": "one actor shared by the 3 agents (share_policy_params), one critic (share_param_critic)",
    "critic input": "MAPPO: the env's global state (all agents' observations); IPPO: the agent's own observation",
    "recurrent": "no",
    "normalization": "none (observations, advantages, values: normalize_advantage=False, no value normalization)",
    "batch": "6,000 env steps = 18,000 agent steps per iteration (10 serial envs x 600 steps)",
    "epochs / minibatches": "45 minibatches of 400 env steps (3 passes over the batch)",
    "lr": "5e-5 constant (Adam eps 1e-6), grad-norm clip 5, no value clipping",
    "gamma / lambda": "0.99 / 0.9",
    "clip / entropy": "0.2 / 0",
    "episode": "25 steps (max_cycles set to 25; BenchMARL's own default is 100)",
    "actions": "discrete, categorical (prefer_continuous_actions set to False)",
    "env": "mpe2 simple_spread_v3 through TorchRL's PettingZooEnv (PettingZoo 1.27 no longer has MPE: the script "
           "points TorchRL's task table at mpe2's module)",
}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    p = argparse.ArgumentParser(prog="python -m benchmarks run benchmarl-spread",
                                description=(__doc__ or "").splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--algos", nargs="+", default=["mappo", "ippo"], choices=["mappo", "ippo"])
    p.add_argument("--venv", type=Path, default=REPO / ".venv-benchmarl", help="BenchMARL's venv (created if absent)")
    p.add_argument("--work-dir", type=Path, default=REPO / "logs" / "benchmarl-spread",
                   help="runs and kept policies of both libraries")
    p.add_argument("--reuse", action="store_true",
                   help="reuse finished runs and evaluations of --work-dir (BenchMARL: train.json; ours: "
                        "bench_run.json)")
    p.add_argument("--agent-budgets", type=int, nargs="+", default=[1_000_000, 4_000_000])
    p.add_argument("--second-budgets", type=float, nargs="+", default=[300.0, 600.0])
    p.add_argument("--max-seconds", type=float, default=1080.0,
                   help="stop a BenchMARL run here even if an agent-step budget is not reached")
    p.add_argument("--frames-per-batch", type=int, default=None, help="BenchMARL's on-policy batch (default 6000)")
    p.add_argument("--ours-n", type=int, default=None, help="-n of our first run (default: the entry's)")
    p.add_argument("--save-freq", type=int, default=100_000, help="our checkpoints, every N agent steps")
    p.add_argument("--n-eval", type=int, default=1000)
    p.add_argument("--eval-seed", type=int, default=10_000)
    p.add_argument("--no-cli-eval", dest="cli_eval", action="store_false",
                   help="skip the `sbagents.evaluate` column of our runs")
    p.add_argument("--note", default="", help="a sentence for the section (e.g. what else ran on the machine)")
    p.add_argument("--no-ours", action="store_true", help="BenchMARL only")
    p.add_argument("--no-fitted", dest="fitted", action="store_false",
                   help="no second run of ours fitted to the longest wall-time budget: the entry's run serves every "
                        "budget (its last checkpoint within each, or its final model when it ends sooner)")
    p.add_argument("--no-benchmarl", action="store_true", help="our side only")
    return p


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Both libraries on every seed; the results."""
    args = build_parser().parse_args(list(argv))
    if any(b <= 0 for b in args.agent_budgets) or any(s <= 0 for s in args.second_budgets):
        raise SystemExit("benchmarl-spread: budgets must be positive")
    work = args.work_dir.resolve()
    work.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"env": ENV, "agent_budgets": args.agent_budgets, "second_budgets": args.second_budgets,
                              "n_eval": args.n_eval, "eval_seed": args.eval_seed, "seeds": args.seeds,
                              "max_seconds": args.max_seconds, "machine": machine_info(),
                              "command": " ".join(["python -m benchmarks run benchmarl-spread",
                                                   *map(shlex.quote, recorded_argv(list(argv)))]),
                              "benchmarl_settings": BENCHMARL_SETTINGS, "benchmarl": [], "ours": [], "note": args.note}
    if not args.no_benchmarl:
        python = ensure_venv(args.venv)
        result["benchmarl_versions"] = venv_versions(python)
        for seed in args.seeds:
            for algo in args.algos:
                row = run_benchmarl(python, algo, seed, work, args)
                print(json.dumps({k: v for k, v in row.items() if k != "settings"}), flush=True)
                result["benchmarl"].append(row)
    if not args.no_ours:
        result["ours_entry"] = ours_entry()
        for seed in args.seeds:
            row = run_ours(seed, work, args)
            print(json.dumps(row), flush=True)
            result["ours"].append(row)
    result["load_end"] = load_average()
    result["stats"] = [[group, budget, stats_of(values)] for (group, budget), values in seed_values(result).items()]
    return result


def seed_values(result: dict[str, Any]) -> dict[tuple[str, str], list[float]]:
    """(library / algorithm, budget) -> T of each seed, in table order."""
    values: dict[tuple[str, str], list[float]] = {}
    for row in table_rows(result):
        values.setdefault((row[0], row[2]), []).append(float(row[5]))
    return values


# --- rendering ------------------------------------------------------------------------------------------------


def _budget_label(label: str) -> str:
    """``agent_steps1000000`` / ``frames336000`` / ``seconds300`` -> the table's budget cell."""
    if label == "capped":
        return "time cap"
    if label.startswith("seconds"):
        return f"{float(label[len('seconds'):]) / 60:g} min"
    if label.startswith("frames"):
        return f"{int(label[len('frames'):]) * N_AGENTS / 1e6:g}M agent steps"
    return f"{int(label[len('agent_steps'):]) / 1e6:g}M agent steps"


def _rate(steps: float | None, seconds: float | None) -> str:
    return "-" if not steps or not seconds else f"{steps / seconds:,.0f}"


def table_rows(result: dict[str, Any]) -> list[list[str]]:
    """One row per library, algorithm, seed and kept policy."""
    rows = []
    for r in result["benchmarl"]:
        load = f"{r['load_start'][0]} / {r['load_end'][0]}"
        for k in r["kept"]:
            rows.append([f"BenchMARL {r['algo'].upper()}", str(r["seed"]), _budget_label(k.get("budget", k["label"])),
                         f"{k['agent_steps']:,}", f"{k['train_s']:.0f}", f"{k['team_return']:.2f}",
                         f"{team_to_mappo(k['team_return']):.1f}", "-",
                         _rate(k["agent_steps"], k["collection_s"]), _rate(k["agent_steps"], k["train_s"]), load])
    for seed_row in result["ours"]:
        for r in seed_row["runs"]:
            load = f"{r['load_start'][0]} / {r['load_end'][0]}"
            for k in r["kept"]:
                rows.append(["ours PPO (shipped entry)", str(seed_row["seed"]), _budget_label(k["label"]),
                             f"{k['agent_steps']:,}", f"{k['train_s']:.0f}", f"{k['team_return']:.2f}",
                             f"{team_to_mappo(k['team_return']):.1f}",
                             f"{k['cli_team_return']:.2f}" if "cli_team_return" in k else "-", "-",
                             _rate(k["agent_steps"], k["train_s"]), load])
    return rows


def render(result: dict[str, Any]) -> str:
    """The ``benchmarl-spread`` section from the results alone."""
    versions = result.get("benchmarl_versions", {})
    lines = [
        "## BenchMARL side by side: mpe2 simple_spread (N=3, 25 steps, discrete, local_ratio 0.5)", "",
        f"Command: `{result['command']}`. Machine: {result['machine']['cpu']}, {result['machine']['cores']} cores, "
        "shared with other work (load averages: 1-minute, at the start / end of each run); every process uses one "
        "torch thread. BenchMARL " + ", ".join(f"{k} {v}" for k, v in versions.items())
        + f"; ours: torch {result['machine']['torch']}, SB3 {result['machine']['stable_baselines3']}.", "",
        f"T: mean team return (sum of the 3 agents' 25-step returns) of the greedy team over the same "
        f"{result['n_eval']:,} episodes for every row (mpe2's parallel env, episode k reset with seed "
        f"{result['eval_seed']} + k); R = 2T - 75 is the scale of the MAPPO authors' logs (their -120 is T = -22.5). "
        "CLI T: `python -m sbagents.evaluate -n 1000 --seed 10000 --json` of the same model (one seeded reset, then "
        "the env's RNG: other episodes). A budget's policy: agent-step budgets keep the first policy at or past the "
        "budget (BenchMARL: the first 6,000-frame batch; ours: the first checkpoint, every 100,000 agent steps); "
        "wall-time budgets keep the last policy within it. BenchMARL counts frames as env (team) steps: agent steps "
        "= 3 x frames. Train s: BenchMARL from `experiment.run()` (experiment build excluded); ours `model.learn` "
        "(SB3's `train_seconds`). Collection: agent steps per second of collection time alone (BenchMARL: the time "
        "between a training step's end and the next batch); overall: agent steps per train second.", "",
        "| library / algorithm | seed | budget | agent steps | train s | T | R = 2T - 75 | CLI T | collection "
        "agent steps/s | overall agent steps/s | load |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in table_rows(result)]
    capped = [r for r in result["benchmarl"] if (r.get("total") or {}).get("capped")]
    for r in capped:
        t = r["total"]
        reached = [_budget_label(k.get("budget", k["label"])) for k in r["kept"] if k["label"] != "capped"]
        lines += ["", f"BenchMARL {r['algo'].upper()} seed {r['seed']} was stopped at its time cap (--max-seconds "
                  f"{r.get('max_seconds', result['max_seconds']):g}) after {t['agent_steps']:,} agent steps "
                  f"({t['frames']:,} frames) "
                  f"in {t['train_s']:.0f} s; budgets reached: {', '.join(reached) or 'none'}; the others are missing "
                  "from the table."]
    for seed_row in result["ours"]:
        for r in seed_row["runs"]:
            lines += ["", f"Ours seed {seed_row['seed']}: a run of {r['n_timesteps']:,} agent steps in "
                      f"{r['train_s']:.0f} s ({r['fps']:,.0f} agent steps/s overall)"
                      + (", stopped at the time cap" if r["interrupted"] else "") + "."]
    if result.get("note"):
        lines += ["", result["note"]]
    lines += ["", *grouped_stats_table("library / algorithm", [
        (group, f"T, {budget}", stats, ".2f") for group, budget, stats in result["stats"]])]
    lines += ["", "Settings that differ (ours: the shipped entry as run; BenchMARL: its default configs):", "",
              "| setting | BenchMARL | ours |", "|---|---|---|"]
    entry = result.get("ours_entry", {})
    ours_cells = ours_settings(entry)
    for key, value in result["benchmarl_settings"].items():
        lines.append(f"| {key} | {value} | {ours_cells.get(key, '-')} |")
    return "\n".join(lines)


def ours_settings(entry: dict[str, Any]) -> dict[str, str]:
    """Our side of the settings table, from the entry's recorded hyperparameters (SB3's PPO defaults where the entry
    sets nothing)."""
    hp = entry.get("hyperparams") or {}
    if not hp:
        return {}
    team = entry.get("team") or {}
    pk = hp.get("policy_kwargs") or {}
    n_envs, n_steps = entry.get("n_envs"), hp.get("n_steps", 2048)
    known = {"policy", "policy_kwargs", "n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda",
             "ent_coef", "clip_range", "n_envs", "n_timesteps", "policies", "normalize", "max_grad_norm"}
    extra = {k: v for k, v in hp.items() if k not in known}
    critic = {"local": "the agent's own observation", "centralized": "centralized (all agents' observations)"}
    agent_steps = n_envs * n_steps * N_AGENTS if n_envs else None
    return {
        "network": (f"{str(pk['features_extractor_class']).rsplit(':', 1)[-1].rsplit('.', 1)[-1]} "
                    f"{pk.get('features_extractor_kwargs', {})}, then " if pk.get("features_extractor_class") else "")
                   + f"MLP {pk.get('net_arch', '64-64 (SB3 default)')}, {pk.get('activation_fn', 'tanh')}, "
                   "features shared by actor and critic",
        "parameter sharing": f"policies: {team.get('policies', hp.get('policies', '-'))}"
                             + (", agent id appended" if team.get("agent_id") else ""),
        "critic input": critic.get(str(team.get("critic", "local")), str(team.get("critic"))),
        "recurrent": "no",
        "normalization": f"VecNormalize: {entry.get('normalize')}; advantages normalized per minibatch (SB3)",
        "batch": f"{n_envs} envs x {n_steps} steps = {agent_steps:,} agent steps per iteration"
                 if agent_steps else "-",
        "epochs / minibatches": f"{hp.get('n_epochs', 10)} epochs, minibatch {hp.get('batch_size', 64)} agent steps",
        "lr": f"{hp.get('learning_rate', 3e-4)} (Adam eps 1e-5), grad-norm clip {hp.get('max_grad_norm', 0.5)}",
        "gamma / lambda": f"{hp.get('gamma', 0.99)} / {hp.get('gae_lambda', 0.95)}",
        "clip / entropy": f"{hp.get('clip_range', 0.2)} / {hp.get('ent_coef', 0.0)}",
        "episode": "25 steps",
        "actions": "discrete",
        "env": "sbagents' batched numpy copy of mpe2 simple_spread_v3 (training); mpe2's env (evaluation)"
               + (f"; other entry settings: {', '.join(f'{k}: {v}' for k, v in extra.items())}" if extra else ""),
    }


BENCHMARKS = (
    Benchmark(name="benchmarl-spread", kind="learning", results="benchmarl_spread.json",
              summary="BenchMARL MAPPO/IPPO (own venv) beside our PPO on mpe2 simple_spread: 1M/4M agent steps, "
                      "5/10 min, 1,000 episodes",
              run=run, render=render),
)
