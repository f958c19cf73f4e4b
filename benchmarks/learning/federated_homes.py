"""Federated homes vs a single home's local model vs centralized training, on held-out homes (3 seeds).

For each seed, with the same 8 non-IID client homes (``sbagents.federated.homes``) and the same 8 held-out users:

- **federated**: ``python -m sbagents.federated --homes 8 --rounds R --local-steps K --strategy S --seed SEED`` (the
  same library call, Flower's simulation); each home trains R x K steps on its own user;
- **local only**: home 0 alone (cool and dim), the same R x K steps on its own user, no federation;
- **centralized**: one learner on the 8 homes' envs at once (their pooled experience: 8 x R x K steps), the upper
  bound federated learning approaches without sharing data.

All three train the shipped DDPG entry with the same overrides and are evaluated by the same function: the comfort
criterion share and success rate on the held-out homes (``--episodes`` greedy episodes each) and on the client homes.
Then personal fine-tuning (``--personal-steps``) of the federated policy in the client and held-out homes where it
does worst: comfort and energy use before and after.

    python -m benchmarks run federated-homes --seeds 0 1 2 --rounds 24 --local-steps 250
    python -m benchmarks run federated-homes --seeds 0 --add fedprox:0.01 dp-fedavg:0.1 dp-fedavg:0.3   # more rows
    python -m benchmarks run federated-homes --seeds 0 1 2 --add personal:27.5:95

``--add STRATEGY:PARAM`` trains only the federation with that strategy (FedProx's mu, DP-FedAvg's noise
multiplier with clip ``--dp-clip``) and adds its rows to the saved results (``--stored``, by default the results
file) of the same seeds; ``--add personal:T:L`` trains the federation again and fine-tunes it for a user outside the
population's ranges (T C, L lux). Flower (``pip install -e ".[federated]"``) is imported only to train.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.harness import Benchmark
from benchmarks.learning.seed_table import StatsRow, grouped_stats_table, stats_of
from benchmarks.report import RESULTS_DIR, load_results, recorded_argv

SECTION = "federated-homes"
EVAL_SEED = 90_000


def evaluate(model: Any, settings: Any, episodes: int) -> dict[str, Any]:
    """Held-out and client homes' comfort of ``model``."""
    from sbagents.federated.evaluation import evaluate_homes
    from sbagents.federated.homes import client_homes, held_out_homes
    from sbagents.federated.local import home_experiment

    exp = home_experiment(settings)
    held = evaluate_homes(model, exp, held_out_homes(settings.held_out, settings.seed), episodes, EVAL_SEED)
    clients = evaluate_homes(model, exp, client_homes(settings.homes, settings.seed), episodes, EVAL_SEED)
    return {"heldout_share": held["criterion_share"], "heldout_success": held["success_rate"],
            "client_share": clients["criterion_share"], "client_success": clients["success_rate"],
            "heldout_per_home": held["per_home"], "client_per_home": clients["per_home"]}


def train_alone(settings: Any, homes: list[Any]) -> tuple[Any, float]:
    """One learner on ``homes``' envs at once (one home: local only; all: centralized), for each home's share of
    the federation's steps (``settings``: a ``FederatedSettings``; ``homes``: ``Home`` objects)."""
    from sbagents.federated.evaluation import for_home
    from sbagents.federated.local import home_experiment, make_env, new_model

    steps = settings.total_local_steps * len(homes)
    exp = home_experiment(settings, n_timesteps=steps)
    if len(homes) == 1:
        exp = for_home(exp, homes[0])
        env = make_env(exp, settings.seed)
    else:
        env = make_env(exp, settings.seed, env_kwargs=[h.env_kwargs() for h in homes])
    model = new_model(exp, env, settings.seed)
    start = time.perf_counter()
    model.learn(steps)
    return model, time.perf_counter() - start


def run_seed(settings: Any, episodes: int, personal_steps: int, logs: str) -> dict[str, Any]:
    """The three trainings of one seed, and personal fine-tuning of the federated policy."""
    from stable_baselines3 import DDPG

    from sbagents.federated.homes import client_homes, held_out_homes
    from sbagents.federated.personal import personalize
    from sbagents.federated.runner import federate

    load = os.getloadavg()[0]
    fed = federate(settings, logs, final_eval_episodes=0, quiet=True, verbose=0)
    model = DDPG.load(str(fed.run_dir / "sbagents_SmartHome-v0.zip"), device="cpu")
    rows = {"federated": {**evaluate(model, settings, episodes), "train_s": fed.summary["train_seconds"]}}
    homes = client_homes(settings.homes, settings.seed)
    local, local_s = train_alone(settings, homes[:1])
    rows["local only (home 0)"] = {**evaluate(local, settings, episodes), "train_s": local_s}
    central, central_s = train_alone(settings, homes)
    rows["centralized"] = {**evaluate(central, settings, episodes), "train_s": central_s}
    personal = []
    fed_rows = rows["federated"]
    worst_client = min(fed_rows["client_per_home"], key=lambda r: r["criterion_share"])
    worst_held = min(fed_rows["heldout_per_home"], key=lambda r: r["criterion_share"])
    for kind, row, pool in (("client", worst_client, homes),
                            ("held-out", worst_held, held_out_homes(settings.held_out, settings.seed))):
        home = pool[row["home"]]
        result = personalize(fed.run_dir, settings.algo, settings.env, home, personal_steps, episodes,
                             settings.seed, logs)
        personal.append({"kind": kind, "home": vars(home), "before": result.before, "after": result.after})
    bytes_per_round = fed.record["bytes_per_round_per_home"]
    for name in rows:
        rows[name].pop("heldout_per_home"), rows[name].pop("client_per_home")
    return {"seed": settings.seed, "rows": rows, "personal": personal, "bytes_per_round_per_home": bytes_per_round,
            "parameters": fed.record["parameters"], "load": round(load, 2),
            "dp_epsilon": fed.summary["federated"]["dp_epsilon"]}


def personal_outside(settings: Any, spec: str, episodes: int, personal_steps: int, logs: str) -> dict[str, Any]:
    """``personal:T:L``: the federation trained again (same settings and seed), then fine-tuned for a user outside
    the population's ranges (T C, L lux), where the global policy has never been."""
    from sbagents.federated.homes import Home
    from sbagents.federated.personal import personalize
    from sbagents.federated.runner import federate

    _, temp, light = spec.split(":")
    fed = federate(settings, logs, final_eval_episodes=0, quiet=True, verbose=0)
    home = Home(0, "outside", float(temp), float(light))
    result = personalize(fed.run_dir, settings.algo, settings.env, home, personal_steps, episodes, settings.seed,
                         logs)
    return {"kind": "outside the ranges", "home": vars(home), "before": result.before, "after": result.after}


def run_added(settings: Any, spec: str, episodes: int, logs: str) -> tuple[str, dict[str, Any]]:
    """One more federated row (``fedprox:MU`` or ``dp-fedavg:NOISE``): its name and its results."""
    from stable_baselines3 import DDPG

    from sbagents.federated.runner import federate

    strategy, _, value = spec.partition(":")
    if strategy == "fedprox":
        settings.strategy, settings.proximal_mu = strategy, float(value or settings.proximal_mu)
        name = f"federated (fedprox, mu {settings.proximal_mu:g})"
    elif strategy == "dp-fedavg":
        settings.strategy, settings.dp_noise = strategy, float(value or settings.dp_noise)
    else:
        raise SystemExit(f"--add {spec}: use fedprox:MU or dp-fedavg:NOISE")
    fed = federate(settings, logs, final_eval_episodes=0, quiet=True, verbose=0)
    if strategy == "dp-fedavg":
        name = (f"federated (dp-fedavg, noise {settings.dp_noise:g}, clip {settings.dp_clip:g}: user-level epsilon "
                f"{fed.summary['federated']['dp_epsilon']:.0f} at delta {settings.dp_delta:g})")
    model = DDPG.load(str(fed.run_dir / "sbagents_SmartHome-v0.zip"), device="cpu")
    row = {**evaluate(model, settings, episodes), "train_s": fed.summary["train_seconds"]}
    row.pop("heldout_per_home"), row.pop("client_per_home")
    return name, row


def markdown(result: dict[str, Any]) -> str:
    """The BENCHMARKS.md section."""
    s = result["settings"]
    lines = ["## Federated homes: SmartHome DDPG across 8 non-IID homes (Flower)", "",
             f"Command: `{result['command']}`. 8 client homes in 4 tastes (cool/warm x dim/bright corners of the "
             "preference ranges), 8 held-out users "
             f"drawn over the whole ranges; every home trains {s['rounds']} x {s['local_steps']} steps. Local only: "
             f"home 0 alone, the same steps; centralized: one learner on the 8 homes' envs, their pooled steps. "
             f"Comfort share = steps after the warm-up within 1 C and 5 lux ({result['episodes']} greedy episodes per "
             "home); success = episodes with a share >= 97%.", "",
             *[f"More rows: `{a['command']}`." for a in result.get("added", [])], "",
             "| seed | training | held-out comfort | held-out success | client homes' comfort | train s |",
             "|---:|---|---:|---:|---:|---:|"]
    for run in result["runs"]:
        for name, r in run["rows"].items():
            lines.append(f"| {run['seed']} | {name} | {100 * r['heldout_share']:.1f}% | "
                         f"{100 * r['heldout_success']:.0f}% | {100 * r['client_share']:.1f}% | {r['train_s']:.0f} |")
    run0 = result["runs"][0]
    lines += ["", f"Traffic: {run0['parameters']:,} parameters (actor and critic, float32) down and up per home per "
              f"round: {run0['bytes_per_round_per_home'] / 1024:.1f} KiB per home per round, "
              f"{s['rounds'] * run0['bytes_per_round_per_home'] / 1024 ** 2:.1f} MiB per home over the run.", "",
              f"Personal fine-tuning of the federated policy ({result['personal_steps']} steps, on that home's "
              "experience only): in the client and the held-out home where it does worst, and (`--add personal:T:L`, "
              "the federation trained again) for a user outside the population's ranges:", "",
              "| seed | home | user | comfort before -> after | energy per step before -> after | return before -> "
              "after |", "|---:|---|---|---:|---:|---:|"]
    for run in result["runs"]:
        for p in run["personal"]:
            h, b, a = p["home"], p["before"], p["after"]
            lines.append(f"| {run['seed']} | {p['kind']} | {h['preferred_temp']:.1f} C, {h['preferred_light']:.0f} "
                         f"lux | {100 * b['criterion_share']:.1f}% -> {100 * a['criterion_share']:.1f}% | "
                         f"{b['mean_energy']:.3f} -> {a['mean_energy']:.3f} | {b['mean_return']:.1f} -> "
                         f"{a['mean_return']:.1f} |")
    rows: list[StatsRow] = [(name, "held-out comfort (%)", stats, ".1f") for name, stats in result["stats"].items()]
    return "\n".join([*lines, "", *grouped_stats_table("training", rows)])


def add_stats(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with ``stats[training]``: the held-out comfort share (%) over the seeds that have the row."""
    names = list(dict.fromkeys(name for run in result["runs"] for name in run["rows"]))
    stats = {name: stats_of([100 * run["rows"][name]["heldout_share"] for run in result["runs"]
                             if name in run["rows"]]) for name in names}
    return {**result, "stats": stats}


def build_parser() -> argparse.ArgumentParser:
    """The benchmark's options."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--rounds", type=int, default=24)
    parser.add_argument("--local-steps", type=int, default=250)
    parser.add_argument("--strategy", default="fedavg")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per home in the evaluations")
    parser.add_argument("--personal-steps", type=int, default=2000)
    parser.add_argument("--params", nargs="*", default=[], metavar="KEY:VALUE")
    parser.add_argument("--add", nargs="+", default=[], metavar="STRATEGY:PARAM",
                        help="only train these federations (fedprox:MU, dp-fedavg:NOISE, personal:T:L) and add "
                             "their rows to --stored's seeds")
    parser.add_argument("--dp-clip", type=float, default=1.0, help="--add dp-fedavg: the update clip")
    parser.add_argument("--stored", default=str(RESULTS_DIR / "federated_homes.json"),
                        help="--add: the results the rows are added to")
    return parser


def add_rows(result: dict[str, Any], args: argparse.Namespace, logs: str) -> None:
    """``--add``: train the added federations for ``args.seeds`` and put their rows into ``result``."""
    from sbagents.federated.settings import FederatedSettings

    s = result["settings"]
    for run in result["runs"]:
        if run["seed"] not in args.seeds:
            continue
        for spec in args.add:
            settings = FederatedSettings(homes=8, rounds=s["rounds"], local_steps=s["local_steps"],
                                         seed=run["seed"], dp_clip=args.dp_clip, hyperparams=result["params"])
            if spec.startswith("personal:"):
                run["personal"].append(personal_outside(settings, spec, result["episodes"],
                                                        result["personal_steps"], logs))
                print(json.dumps({"seed": run["seed"], "personal": run["personal"][-1]}), flush=True)
                continue
            name, row = run_added(settings, spec, result["episodes"], logs)
            run["rows"][name] = row
            print(json.dumps({"seed": run["seed"], name: row}), flush=True)


def train_seeds(args: argparse.Namespace, logs: str) -> dict[str, Any]:
    """The three trainings (and the fine-tuning) of every seed."""
    from sbagents.core.zoo_config import parse_overrides
    from sbagents.federated.settings import FederatedSettings

    params = parse_overrides(args.params, "--params")
    runs = []
    for seed in args.seeds:
        settings = FederatedSettings(homes=8, rounds=args.rounds, local_steps=args.local_steps,
                                     strategy=args.strategy, seed=seed, hyperparams=params)
        runs.append(run_seed(settings, args.episodes, args.personal_steps, logs))
        print(json.dumps(runs[-1]), flush=True)
    return {"settings": {"rounds": args.rounds, "local_steps": args.local_steps, "strategy": args.strategy},
            "params": params, "episodes": args.episodes, "personal_steps": args.personal_steps, "runs": runs}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """Train every seed (or, with ``--add``, the added rows of the stored results); the results of the section."""
    import torch

    args = build_parser().parse_args(list(argv))
    kept = [a for i, a in enumerate(argv) if "--stored" not in {a, argv[i - 1] if i else ""}]
    command = shlex.join(["python", "-m", "benchmarks", "run", SECTION, *recorded_argv(kept)])
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as logs:
        if args.add:
            result = load_results(Path(args.stored))
            add_rows(result, args, logs)
            result.setdefault("added", []).append({"seeds": args.seeds, "add": args.add, "dp_clip": args.dp_clip,
                                                   "command": command})
        else:
            result = {"command": command, **train_seeds(args, logs)}
    return add_stats(result)


BENCHMARKS = (
    Benchmark(name=SECTION, kind="learning", results="federated_homes.json",
              summary="Federated SmartHome DDPG over 8 non-IID homes vs local only vs centralized, held-out comfort",
              run=run, render=markdown),
)
