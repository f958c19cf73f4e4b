"""Pong on the RLlib backend: env steps per second of PPO (the shipped ``rllib_ppo.yml`` ``atari`` entry) with 1, 2
and 4 env runners on this machine, and on a local multi-node test cluster (``ray.cluster_utils.Cluster``: a head and
worker nodes, each a Ray node of its own on this machine, the way a real cluster splits its CPUs), needs
``pip install 'sbagents[distributed]'``.

Per setting: :func:`sbagents.rllib.training.train_rllib` for ``--steps`` env steps (its ``summary.json``: steps over
training seconds, Ray's start and the algorithm build excluded) and the median of its iterations' env steps/s after
the first (``progress.csv``: the steady rate, without the first iteration's warm-up)::

    python -m benchmarks run rllib-pong --runners 1 2 4 --steps 20000 [--cluster-nodes 2]
"""

from __future__ import annotations

import argparse
import csv
import statistics
import tempfile
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.report import load_average, machine_info, recorded_argv

NAME = "rllib-pong"
ENV = "PongNoFrameskip-v4"


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run rllib-pong``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {NAME}", description=__doc__.splitlines()[0])
    parser.add_argument("--runners", type=int, nargs="+", default=[1, 2, 4], help="env runner counts")
    parser.add_argument("--steps", type=int, default=20_000, help="env steps per setting")
    parser.add_argument("--cluster-nodes", type=int, default=2,
                        help="nodes of the local test cluster (0: no cluster settings); its runners: the largest "
                             "--runners")
    parser.add_argument("--params", nargs="+", default=[], metavar="KEY:VALUE", help="overrides of the atari entry")
    parser.add_argument("--quick", action="store_true", help="smoke run: 1 runner, 400 steps, small batches")
    return parser


def _measure(steps: int, runners: int, params: dict[str, Any], address: str | None, folder: str) -> dict[str, Any]:
    """One training run: its steps, seconds and rates."""
    from sbagents.core.options import EvalOptions, ExecOptions, OutputOptions, RllibOptions, TrainSpec
    from sbagents.rllib import PROGRESS_FILE
    from sbagents.rllib.training import train_rllib

    result = train_rllib(TrainSpec("ppo", ENV, steps, params), OutputOptions(folder),
                         EvalOptions(eval_freq=-1, final_eval_episodes=0),
                         ExecOptions(seed=0, backend="rllib", num_threads=1, verbose=0),
                         RllibOptions(num_env_runners=runners, address=address))
    with (result.run_dir / PROGRESS_FILE).open() as f:
        rates = [float(r["env_steps_per_s"]) for r in csv.DictReader(f)]
    s = result.summary
    return {"runners": runners, "env_steps": s["n_timesteps"], "train_s": s["train_seconds"], "fps": s["fps"],
            "steady_fps": round(statistics.median(rates[1:]), 1) if len(rates) > 1 else None,
            "iterations": s["iterations"]}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every setting's rates (local Ray per runner count, then the test cluster)."""
    from sbagents.core.zoo_config import parse_overrides

    args = build_parser().parse_args(list(argv))
    if args.quick:
        args.runners, args.steps, args.cluster_nodes = [1], 400, min(args.cluster_nodes, 2)
        args.params = [*args.params, "train_batch_size_per_learner:200", "minibatch_size:50", "num_epochs:1",
                       "num_envs_per_env_runner:1"]
    params = parse_overrides(args.params, "--params")
    load_before = load_average()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for runners in args.runners:
            rows.append({"where": "local Ray", **_measure(args.steps, runners, params, None, tmp)})
        if args.cluster_nodes > 0:
            from ray.cluster_utils import Cluster

            cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
            try:
                for _ in range(args.cluster_nodes - 1):
                    cluster.add_node(num_cpus=max(args.runners))
                cluster.wait_for_nodes()
                row = _measure(args.steps, max(args.runners), params, cluster.address, tmp)
                rows.append({"where": f"test cluster, {args.cluster_nodes} nodes", **row})
            finally:
                cluster.shutdown()
    return {"command": " ".join(["python -m benchmarks run", NAME, *recorded_argv(list(argv))]), "env": ENV,
            "params": params, "rows": rows,
            "machine": {**machine_info(), "load_before": load_before, "load_after": load_average()}}


def render(results: dict[str, Any]) -> str:
    """The section: one row per setting."""
    m = results["machine"]
    base = results["rows"][0]["fps"]
    epochs = results.get("params", {}).get("num_epochs", 10)  # the atari entry's, unless --params changed it
    lines = [f"## RLlib PPO on Pong: env steps per second against env runners ({m['cores']} cores)", "",
             f"Command: `{results['command']}` (Ray venv). The shipped `rllib_ppo.yml` `atari` entry (RLlib's tuned "
             f"Atari PPO: 5 envs per runner, batches of 4,000 env steps, {epochs} epochs: {epochs} gradient passes "
             "per env step), one learner in the driver, 1 torch thread per process; the test cluster is "
             "`ray.cluster_utils.Cluster` (a head node with 1 CPU and worker nodes, all "
             f"on this machine). {m['cpu']}, {m['date']}, load {m['load_before'][0]} before / "
             f"{m['load_after'][0]} after.", "",
             "| where | env runners | env steps | train s | env steps/s | vs 1st row | steady env steps/s |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in results["rows"]:
        steady = "-" if r["steady_fps"] is None else f"{r['steady_fps']:,.0f}"
        lines.append(f"| {r['where']} | {r['runners']} | {r['env_steps']:,} | {r['train_s']:.0f} | {r['fps']:,.0f} | "
                     f"{r['fps'] / base:.2f}x | {steady} |")
    return "\n".join(lines)


BENCHMARKS = (
    Benchmark(name=NAME, kind="speed", results="rllib_pong.json",
              summary="RLlib PPO on Pong (needs Ray): env steps/s with 1, 2, 4 env runners and on a local test cluster",
              run=run, render=render),
)
