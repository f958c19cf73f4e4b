"""simple_spread throughput, agent steps per second per core, one command on one machine::

    python -m benchmarks run spread-throughput [--rounds 3] [--venv .venv-benchmarl]

(a) our batched simple_spread VecEnv alone (random actions, 16 and 64 teams); (b) mpe2's own parallel env stepped
in a plain Python loop; (c) our PPO with the shipped ``mpe2.simple_spread_v3`` entry: overall (``python -m
sbagents.train -n BUDGET``, ``n_timesteps / train_seconds`` of its ``summary.json``) and collection alone (SB3's PPO
with the entry's hyperparameters on the batched VecEnv, rollout time measured by a callback); (d) BenchMARL's
collection (its MAPPO policy and TorchRL collector over 10 serial PettingZoo envs, ``benchmarl_venv.py collect``)
when its venv exists, and its overall training rate from the ``benchmarl-spread`` results. Every measurement runs in
one process with one torch thread (one core); rounds are interleaved and medians reported, so a load spike on the
shared machine hits every variant alike.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import RESULTS_DIR, load_average, machine_info, recorded_argv

ENV = "mpe2.simple_spread_v3"
N_AGENTS = 3
TEAMS: tuple[int, ...] = (16, 64)


def batched_rate(n_teams: int, n_steps: int, seed: int = 0) -> float:
    """Agent steps/s of our batched simple_spread VecEnv of ``n_teams`` teams (random actions, resets included)."""
    from benchmarks.speed.batched import vec_env_rate, zoo_env_kwargs
    from sbagents.batched import make_batched_vec_env

    vec = make_batched_vec_env(ENV, n_teams, seed, zoo_env_kwargs(ENV), None)
    return vec_env_rate(vec, n_steps, seed)  # one VecEnv transition is one agent's step


def mpe2_loop_rate(n_steps: int, seed: int = 0) -> float:
    """Agent steps/s of mpe2's parallel env in a plain Python loop (random actions, resets included)."""
    from benchmarks.speed.batched import single_env_rate, zoo_env_kwargs

    return single_env_rate(ENV, zoo_env_kwargs(ENV), n_steps, seed)


def ppo_collection_rate(min_steps: int, seed: int = 0) -> dict[str, float]:
    """SB3's PPO with the entry's hyperparameters on the batched VecEnv (the entry's ``n_envs``), one torch thread:
    agent steps/s of rollout collection alone and of the whole ``learn`` (collection and updates)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    from benchmarks.speed.batched import make_vec_kind, ppo_experiment, ppo_kwargs

    class RolloutTimer(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.collect_s, self._t = 0.0, 0.0

        def _on_rollout_start(self) -> None:
            self._t = time.perf_counter()

        def _on_rollout_end(self) -> None:
            self.collect_s += time.perf_counter() - self._t

        def _on_step(self) -> bool:
            return True

    torch.set_num_threads(1)
    exp = ppo_experiment(ENV)
    vec = make_vec_kind(ENV, "batched", exp.n_envs, seed, exp.env_kwargs)
    model = PPO(exp.policy, vec, seed=seed, verbose=0, **ppo_kwargs(ENV, exp.n_envs))
    rollout = model.n_steps * vec.num_envs
    steps = max(2, -(-min_steps // rollout)) * rollout
    model.learn(rollout)  # warm-up, not timed
    timer = RolloutTimer()
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False, callback=timer)
    total = time.perf_counter() - start
    vec.close()
    return {"collection": steps / timer.collect_s, "learn": steps / total}


def cli_training_rate(n_timesteps: int, seed: int = 0) -> float:
    """Agent steps/s of ``python -m sbagents.train`` with the shipped entry for ``n_timesteps`` (``model.learn``
    time: ``summary.json``'s ``train_seconds``; periodic evaluations off)."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "sbagents.train", "--algo", "ppo", "--env", ENV, "--seed", str(seed),
                        "-n", str(n_timesteps), "-f", tmp, "--eval-freq", "0", "--final-eval-episodes", "0",
                        "--verbose", "0", "--num-threads", "1"], check=True, capture_output=True)
        (summary_path,) = Path(tmp).glob("ppo/*/summary.json")
        summary = json.loads(summary_path.read_text())
    return float(summary["n_timesteps"]) / float(summary["train_seconds"])


def benchmarl_collection_rate(python: Path, frames: int) -> float:
    """Agent steps/s of BenchMARL's collector (MAPPO policy, 10 serial envs) in its venv."""
    script = Path(__file__).resolve().parents[1] / "learning" / "benchmarl_venv.py"
    out = subprocess.run([str(python), str(script), "collect", "--frames", str(frames)], check=True,
                         capture_output=True, text=True).stdout
    line = [x for x in out.splitlines() if x.startswith("{")][-1]
    return float(json.loads(line)["agent_steps_per_s"])


def benchmarl_training_rates(path: Path) -> list[dict[str, Any]]:
    """Overall and collection agent steps/s of each BenchMARL run in the ``benchmarl-spread`` results file."""
    if not path.exists():
        return []
    results = json.loads(path.read_text())
    rows = []
    for r in results.get("benchmarl", []):
        total = r.get("total") or {}
        if total.get("train_s"):
            rows.append({"algo": r["algo"], "seed": r["seed"], "agent_steps": total["agent_steps"],
                         "overall": total["agent_steps"] / total["train_s"],
                         "collection": total["agent_steps"] / total["collection_s"],
                         "load": [r["load_start"][0], r["load_end"][0]]})
    return rows


def median_rounds(fns: dict[str, Callable[[], float]], rounds: int) -> dict[str, dict[str, Any]]:
    """Every measurement ``rounds`` times, interleaved; per key its median and the rounds' values."""
    samples: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(rounds):
        for key, fn in fns.items():
            samples[key].append(fn())
    return {k: {"median": statistics.median(v), "rounds": v} for k, v in samples.items()}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    from benchmarks.learning.benchmarl_side import REPO

    p = argparse.ArgumentParser(prog="python -m benchmarks run spread-throughput",
                                description=(__doc__ or "").splitlines()[0])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--venv", type=Path, default=REPO / ".venv-benchmarl", help="BenchMARL's venv (skipped if absent)")
    p.add_argument("--env-steps", type=int, default=2000, help="VecEnv steps of each batched measurement")
    p.add_argument("--loop-steps", type=int, default=2000, help="env steps of the mpe2 loop")
    p.add_argument("--ppo-steps", type=int, default=48_000, help="agent steps of the collection measurement")
    p.add_argument("--cli-steps", type=int, default=200_000, help="-n of the CLI training run")
    p.add_argument("--benchmarl-frames", type=int, default=1200, help="env steps of BenchMARL's collection")
    return p


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Measure; the results."""
    from benchmarks.learning.benchmarl_side import venv_python

    args = build_parser().parse_args(list(argv))
    if min(args.rounds, args.env_steps, args.loop_steps, args.ppo_steps, args.cli_steps, args.benchmarl_frames) <= 0:
        raise SystemExit("spread-throughput: rounds and step counts must be positive")
    python = venv_python(args.venv)
    fns: dict[str, Callable[[], float]] = {f"batched_{n}": partial(batched_rate, n, args.env_steps) for n in TEAMS}
    fns["mpe2_loop"] = partial(mpe2_loop_rate, args.loop_steps)
    ppo: dict[str, list[float]] = {"collection": [], "learn": []}

    def ppo_collection() -> float:
        rates = ppo_collection_rate(args.ppo_steps)
        ppo["learn"].append(rates["learn"])
        return rates["collection"]

    fns["ppo_collection"] = ppo_collection
    fns["ppo_cli"] = partial(cli_training_rate, args.cli_steps)
    if python.exists():
        fns["benchmarl_collection"] = partial(benchmarl_collection_rate, python, args.benchmarl_frames)
    load_start = load_average()
    measured = median_rounds(fns, args.rounds)
    measured["ppo_learn"] = {"median": statistics.median(ppo["learn"]), "rounds": ppo["learn"]}
    return {"rates": measured, "rounds": args.rounds, "load_start": load_start, "load_end": load_average(),
            "benchmarl_venv": python.exists(),
            "benchmarl_training": benchmarl_training_rates(RESULTS_DIR / "benchmarl_spread.json"),
            "settings": {k: getattr(args, k) for k in ("env_steps", "loop_steps", "ppo_steps", "cli_steps",
                                                       "benchmarl_frames")},
            "machine": machine_info(),
            "command": " ".join(["python -m benchmarks run spread-throughput", *recorded_argv(list(argv))])}


#: Row labels of the measurements, in table order.
LABELS: dict[str, str] = {
    "batched_16": "(a) our batched VecEnv, 16 teams, random actions",
    "batched_64": "(a) our batched VecEnv, 64 teams, random actions",
    "mpe2_loop": "(b) mpe2's parallel env, plain Python loop",
    "ppo_collection": "(c) our PPO, collection alone (entry's hyperparameters, batched env)",
    "ppo_learn": "(c) our PPO, whole `learn` of the same runs",
    "ppo_cli": "(c) our PPO, `python -m sbagents.train` overall (train_seconds)",
    "benchmarl_collection": "(d) BenchMARL collection (MAPPO policy, 10 serial envs)",
}


def render(result: dict[str, Any]) -> str:
    """The ``spread-throughput`` section from the results alone."""
    m = result["machine"]
    loop = result["rates"]["mpe2_loop"]["median"]
    lines = ["## simple_spread throughput (agent steps/s per core)", "",
             f"Command: `{result['command']}`. {m['cpu']}, {m['cores']} cores, shared with other work (load "
             f"{result['load_start'][0]} at the start, {result['load_end'][0]} at the end); every figure is one "
             f"process with one torch thread, i.e. one core. Medians of {result['rounds']} interleaved rounds (the "
             "rounds' values in brackets). One agent step = one agent's transition (a team step of simple_spread "
             "is 3). Settings: " + ", ".join(f"{k} {v:,}" for k, v in result["settings"].items()) + ".", "",
             "| measurement | agent steps/s | x mpe2 loop | rounds |", "|---|---:|---:|---|"]
    for key, label in LABELS.items():
        if key not in result["rates"]:
            continue
        r = result["rates"][key]
        lines.append(f"| {label} | {r['median']:,.0f} | {r['median'] / loop:.2f} | "
                     + " / ".join(f"{v:,.0f}" for v in r["rounds"]) + " |")
    for t in result["benchmarl_training"]:
        lines.append(f"| (d) BenchMARL {t['algo'].upper()} training overall, `benchmarl-spread` seed {t['seed']} "
                     f"({t['agent_steps']:,} agent steps; collection alone {t['collection']:,.0f}; load "
                     f"{t['load'][0]} / {t['load'][1]}) | {t['overall']:,.0f} | {t['overall'] / loop:.2f} | "
                     "from its results |")
    if not result["benchmarl_venv"]:
        lines += ["", "BenchMARL's venv was absent: its collection was not measured here."]
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name="spread-throughput", kind="speed", results="spread_throughput.json",
              summary="simple_spread agent steps/s per core: batched VecEnv, mpe2 loop, our PPO, BenchMARL",
              run=run, render=render),
)
