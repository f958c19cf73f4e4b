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

    python -m benchmarks.federated_homes --seeds 0 1 2 --rounds 24 --local-steps 250
    python -m benchmarks.federated_homes --seeds 0 --add fedprox:0.01 dp-fedavg:0.1 dp-fedavg:0.3   # more rows
    python -m benchmarks.federated_homes --seeds 0 1 2 --add personal:27.5:95

``--add STRATEGY:PARAM`` trains only the federation with that strategy (FedProx's mu, DP-FedAvg's noise
multiplier with clip ``--dp-clip``) and adds its rows to the saved results of the same seeds; ``--add personal:T:L``
trains the federation again and fine-tunes it for a user outside the population's ranges (T C, L lux).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from benchmarks.report import publish
from sbagents.core.zoo_config import parse_overrides
from sbagents.federated.evaluation import evaluate_homes, for_home
from sbagents.federated.homes import Home, client_homes, held_out_homes
from sbagents.federated.local import home_experiment, make_env, new_model
from sbagents.federated.personal import personalize
from sbagents.federated.runner import federate
from sbagents.federated.settings import FederatedSettings

RESULTS = Path(__file__).resolve().parent / "results"
SECTION = "federated-homes"
EVAL_SEED = 90_000


def evaluate(model: Any, settings: FederatedSettings, episodes: int) -> dict[str, Any]:
    """Held-out and client homes' comfort of ``model``."""
    exp = home_experiment(settings)
    held = evaluate_homes(model, exp, held_out_homes(settings.held_out, settings.seed), episodes, EVAL_SEED)
    clients = evaluate_homes(model, exp, client_homes(settings.homes, settings.seed), episodes, EVAL_SEED)
    return {"heldout_share": held["criterion_share"], "heldout_success": held["success_rate"],
            "client_share": clients["criterion_share"], "client_success": clients["success_rate"],
            "heldout_per_home": held["per_home"], "client_per_home": clients["per_home"]}


def train_alone(settings: FederatedSettings, homes: list[Home]) -> tuple[Any, float]:
    """One learner on ``homes``' envs at once (one home: local only; all: centralized), for each home's share of
    the federation's steps."""
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


def run_seed(settings: FederatedSettings, episodes: int, personal_steps: int, logs: str) -> dict[str, Any]:
    """The three trainings of one seed, and personal fine-tuning of the federated policy."""
    from stable_baselines3 import DDPG

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


def personal_outside(settings: FederatedSettings, spec: str, episodes: int, personal_steps: int, logs: str
                     ) -> dict[str, Any]:
    """``personal:T:L``: the federation trained again (same settings and seed), then fine-tuned for a user outside
    the population's ranges (T C, L lux), where the global policy has never been."""
    _, temp, light = spec.split(":")
    fed = federate(settings, logs, final_eval_episodes=0, quiet=True, verbose=0)
    home = Home(0, "outside", float(temp), float(light))
    result = personalize(fed.run_dir, settings.algo, settings.env, home, personal_steps, episodes, settings.seed,
                         logs)
    return {"kind": "outside the ranges", "home": vars(home), "before": result.before, "after": result.after}


def run_added(settings: FederatedSettings, spec: str, episodes: int, logs: str) -> tuple[str, dict[str, Any]]:
    """One more federated row (``fedprox:MU`` or ``dp-fedavg:NOISE``): its name and its results."""
    from stable_baselines3 import DDPG

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
    params = " ".join(f"{k}:{v}" for k, v in result["params"].items())
    seeds = " ".join(str(r["seed"]) for r in result["runs"])
    lines = ["## Federated homes: SmartHome DDPG across 8 non-IID homes (Flower)", "",
             f"Command: `python -m benchmarks.federated_homes --seeds {seeds} --rounds {s['rounds']} --local-steps "
             f"{s['local_steps']} --strategy {s['strategy']} --episodes {result['episodes']} --personal-steps "
             f"{result['personal_steps']}" + (f" --params {params}" if params else "") + "`. "
             f"8 client homes in 4 tastes (cool/warm x dim/bright corners of the preference ranges), 8 held-out users "
             f"drawn over the whole ranges; every home trains {s['rounds']} x {s['local_steps']} steps. Local only: "
             f"home 0 alone, the same steps; centralized: one learner on the 8 homes' envs, their pooled steps. "
             f"Comfort share = steps after the warm-up within 1 C and 5 lux ({result['episodes']} greedy episodes per "
             "home); success = episodes with a share >= 97%.", "",
             *[f"More rows: `python -m benchmarks.federated_homes --seeds {' '.join(map(str, a['seeds']))} --add "
               f"{' '.join(a['add'])} --dp-clip {a['dp_clip']}`." for a in result.get("added", [])], "",
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
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.federated_homes", description=__doc__)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--rounds", type=int, default=24)
    parser.add_argument("--local-steps", type=int, default=250)
    parser.add_argument("--strategy", default="fedavg")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per home in the evaluations")
    parser.add_argument("--personal-steps", type=int, default=2000)
    parser.add_argument("--params", nargs="*", default=[], metavar="KEY:VALUE")
    parser.add_argument("--output", default="BENCHMARKS.md", help="Markdown file to update ('' = none)")
    parser.add_argument("--json", default=str(RESULTS / "federated_homes.json"), help="raw results ('' = none)")
    parser.add_argument("--render-only", action="store_true", help="re-render the section from --json")
    parser.add_argument("--add", nargs="+", default=[], metavar="STRATEGY:PARAM",
                        help="only train these federations (fedprox:MU, dp-fedavg:NOISE, personal:T:L) and add "
                             "their rows to --json's seeds")
    parser.add_argument("--dp-clip", type=float, default=1.0, help="--add dp-fedavg: the update clip")
    args = parser.parse_args(argv)
    if args.render_only:
        result = json.loads(Path(args.json).read_text())
    elif args.add:
        torch.set_num_threads(1)
        result = json.loads(Path(args.json).read_text())
        s = result["settings"]
        with tempfile.TemporaryDirectory() as logs:
            for run in result["runs"]:
                if run["seed"] not in args.seeds:
                    continue
                for spec in args.add:
                    settings = FederatedSettings(homes=8, rounds=s["rounds"], local_steps=s["local_steps"],
                                                 seed=run["seed"], dp_clip=args.dp_clip,
                                                 hyperparams=result["params"])
                    if spec.startswith("personal:"):
                        run["personal"].append(personal_outside(settings, spec, result["episodes"],
                                                                result["personal_steps"], logs))
                        print(json.dumps({"seed": run["seed"], "personal": run["personal"][-1]}), flush=True)
                        continue
                    name, row = run_added(settings, spec, result["episodes"], logs)
                    run["rows"][name] = row
                    print(json.dumps({"seed": run["seed"], name: row}), flush=True)
        result.setdefault("added", []).append({"seeds": args.seeds, "add": args.add, "dp_clip": args.dp_clip})
    else:
        torch.set_num_threads(1)
        params = parse_overrides(args.params, "--params")
        runs = []
        with tempfile.TemporaryDirectory() as logs:
            for seed in args.seeds:
                settings = FederatedSettings(homes=8, rounds=args.rounds, local_steps=args.local_steps,
                                             strategy=args.strategy, seed=seed, hyperparams=params)
                runs.append(run_seed(settings, args.episodes, args.personal_steps, logs))
                print(json.dumps(runs[-1]), flush=True)
        result = {"settings": {"rounds": args.rounds, "local_steps": args.local_steps, "strategy": args.strategy},
                  "params": params, "episodes": args.episodes, "personal_steps": args.personal_steps, "runs": runs}
    publish(markdown(result), result, args.output, None if args.render_only else args.json, SECTION)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
