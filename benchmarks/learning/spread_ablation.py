"""What each choice of the shipped ``mpe2.simple_spread_v3`` PPO entry is worth: ``spread-ablation``.

Every variant is the shipped entry with a few overrides (``python -m sbagents.train ... -params``), trained through
the CLI on the same seed for the same agent-step budget and evaluated greedily on the same 1,000 episodes (seeds
10000+) as ``pettingzoo-spread``: team return T, R = 2T - 75 (the MAPPO repository's scale), collisions and
landmarks covered (the env's metrics), training seconds and agent steps per second::

    python -m benchmarks run spread-ablation --jobs 2                  # every variant, seed 0, 2M agent steps
    python -m benchmarks run spread-ablation --variants mlp --add      # one variant, beside the saved ones
"""

from __future__ import annotations

import argparse
import json
import shlex
import tempfile
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.learning import machine_line
from benchmarks.learning.pettingzoo_learning import Task, run_one
from benchmarks.learning.seed_table import iqm_note
from benchmarks.report import RESULTS_DIR, load_results, machine_info, recorded_argv

ENV = "mpe2.simple_spread_v3"
_ARCH = "net_arch: [64, 64]"
_PAIRWISE = ('features_extractor_class: "sbagents.multiagent.relational:PairwiseDistanceFeatures", '
             "features_extractor_kwargs: {targets: [4, 10], agents: [10, 14]}")
_ATTENTION = ('features_extractor_class: "sbagents.multiagent.relational:EntityAttentionFeatures", '
              "features_extractor_kwargs: {targets: [4, 10], agents: [10, 14], own: [0, 4], hidden: 32, heads: 2}")


@dataclass(frozen=True)
class Variant:
    """One row: the shipped entry with ``params`` (train's ``-params KEY:VALUE`` overrides)."""

    name: str
    change: str
    params: tuple[str, ...] = ()


VARIANTS: tuple[Variant, ...] = (
    Variant("shipped", "the shipped entry (entity attention, 64 teams x 25 steps, 10 epochs, ent_coef 0.001)"),
    Variant("previous", "the previous entry: plain MLP, 16 teams x 100 steps, ent_coef 0.01",
            (f"policy_kwargs:{{{_ARCH}}}", "n_envs:16", "n_steps:100", "ent_coef:0.01")),
    Variant("mlp", "plain MLP on the observation instead of entity attention", (f"policy_kwargs:{{{_ARCH}}}",)),
    Variant("pairwise", "MLP on the observation + the 9 landmark-agent distances instead of attention",
            (f"policy_kwargs:{{{_ARCH}, {_PAIRWISE}}}",)),
    Variant("centralized", "MAPPO's centralized critic (global state + agent id; MLP actor, no attention)",
            ("critic:centralized", "agent_id:true")),
    Variant("ent-0.003", "ent_coef 0.003", ("ent_coef:0.003",)),
    Variant("ent-0.01", "ent_coef 0.01", ("ent_coef:0.01",)),
    Variant("16x100", "16 teams x 100 steps per rollout (the same 4,800 samples)", ("n_envs:16", "n_steps:100")),
    Variant("epochs-5", "5 epochs instead of 10", ("n_epochs:5",)),
    Variant("gamma-0.99", "gamma 0.99 (MAPPO's)", ("gamma:0.99",)),
    Variant("norm-reward", "reward scaling by the running return std (VecNormalize; like MAPPO's value norm)",
            ("normalize:{norm_obs: false, norm_reward: true}",)),
    Variant("clip-vf", "value clipping 0.2 (MAPPO's)", ("clip_range_vf:0.2",)),
    Variant("no-ortho", "default PyTorch init instead of orthogonal", (f"policy_kwargs:{{{_ARCH}, {_ATTENTION}, "
                                                                       "ortho_init: false}",)),
)
_BY_NAME = {v.name: v for v in VARIANTS}
#: The results file (under benchmarks/results/).
RESULTS = "spread_ablation.json"


def run_variant(variant: Variant, seed: int, budget: int, episodes: int, logs: Path) -> dict[str, Any]:
    """Train and evaluate one variant; its results row."""
    task = Task(variant.change, ENV, train_args=("-params", *variant.params) if variant.params else (),
                eval_episodes=episodes, metric_keys=("collisions", "landmarks_covered"))
    row = run_one(task, seed, budget, logs)
    return {"variant": variant.name, "change": variant.change, "params": list(variant.params), "seed": seed,
            "n_timesteps": row["n_timesteps"], "train_s": row["train_s"], "mean_return": row["mean_return"],
            "collisions": row["collisions"], "landmarks_covered": row["landmarks_covered"], "load": row["load"]}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks run spread-ablation",
                                     description="simple_spread: the shipped PPO entry against one change at a time")
    parser.add_argument("--variants", nargs="+", choices=list(_BY_NAME), default=list(_BY_NAME))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-n", "--n-timesteps", type=int, default=2_000_000, help="agent steps per variant")
    parser.add_argument("--eval-episodes", type=int, default=1000)
    parser.add_argument("--jobs", type=int, default=1, help="variants trained at once (one core each)")
    parser.add_argument("--add", action="store_true", help="keep the saved rows of the variants not run now")
    parser.add_argument("--note", default="", help="a paragraph for the section (what the rows say, how they ran)")
    return parser


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Every chosen variant; the results."""
    args = build_parser().parse_args(list(argv))
    variants = [_BY_NAME[name] for name in args.variants]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(max(1, args.jobs)) as pool:
        def one(variant: Variant) -> dict[str, Any]:
            row = run_variant(variant, args.seed, args.n_timesteps, args.eval_episodes, Path(tmp) / variant.name)
            print(json.dumps(row), flush=True)
            return row

        rows = list(pool.map(one, variants))
    if args.add:
        saved = load_results(RESULTS_DIR / RESULTS)
        done = {r["variant"] for r in rows}
        rows += [r for r in saved["rows"] if r["variant"] not in done]
    order = list(_BY_NAME)
    rows.sort(key=lambda r: order.index(r["variant"]) if r["variant"] in order else len(order))
    return {"env": ENV, "seed": args.seed, "n_timesteps": args.n_timesteps, "eval_episodes": args.eval_episodes,
            "rows": rows, "machine": machine_info(), **({"note": args.note} if args.note else {}),
            "command": " ".join(["python -m benchmarks run spread-ablation",
                                 *map(shlex.quote, recorded_argv(list(argv)))])}


def render(result: dict[str, Any]) -> str:
    """The section, from the results alone."""
    shipped = next((r["mean_return"] for r in result["rows"] if r["variant"] == "shipped"), None)
    lines = ["## mpe2 simple_spread: what each choice of the PPO entry is worth", "",
             f"Each row is the shipped `{ENV}` PPO entry with one change (`python -m sbagents.train --algo ppo "
             f"--env {ENV} -params ...`), seed {result['seed']}, {result['n_timesteps']:,} agent steps each, "
             f"evaluated greedily on the same {result['eval_episodes']:,} episodes (`python -m sbagents.evaluate "
             f"-n {result['eval_episodes']} --seed 10000`). T: team return (higher is better; MAPPO's level is "
             "-22.5, R = 2T - 75 = -120); collisions: colliding pairs per step, summed over the episode; covered: "
             "landmarks with an agent within 0.1 at the last step. One seed per row: differences under ~0.3 are "
             f"within seed noise. Command: `{result['command']}`.", "",
             "| variant | change | T | vs shipped | R | collisions/episode | landmarks covered | train s | "
             "agent steps/s | load |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        delta = "" if shipped is None or r["variant"] == "shipped" else f"{r['mean_return'] - shipped:+.2f}"
        params = " ".join(f"`{p}`" for p in r["params"])
        change = r["change"] + (f" ({params})" if params and r["variant"] != "no-ortho" else "")
        lines.append(f"| {r['variant']} | {change} | {r['mean_return']:.2f} | {delta} | "
                     f"{2 * r['mean_return'] - 75:.1f} | {r['collisions']:.2f} | {r['landmarks_covered']:.2f} | "
                     f"{r['train_s']:.0f} | {r['n_timesteps'] / r['train_s']:,.0f} | {r['load']} |")
    lines += ["", iqm_note(1)]
    if result.get("note"):
        lines += ["", result["note"]]
    lines += machine_line(result.get("machine"))
    return "\n".join(lines)


BENCHMARKS = (Benchmark(name="spread-ablation", kind="learning", results=RESULTS,
                        summary="simple_spread: the shipped PPO entry against one change at a time (1 seed)",
                        run=run, render=render),)
