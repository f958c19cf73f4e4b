"""Environment steps per second (resets included) of the Kuka envs vs panda-gym's matching task.

Random actions, one env per task, one process. Each Kuka env is compared with ITS panda-gym task: the
pushes (book envs, the goal push, the randomized cube push of ``configs/kuka_random.yml``) with
``PandaPush-v3``, the gripper envs (``KukaPickAndPlace-v0`` and its robust variant) with
``PandaPickAndPlace-v3``. In each round every Kuka env is timed right beside a fresh timing of its reference (the
pair's order alternating), so a ratio compares two timings seconds apart; the table reports the median of those
per-round ratios and their range, so a slow spell of a shared host hits both sides of a ratio alike.

panda-gym is optional: install it in a venv that sees the system packages, then run from the repository root::

    python -m venv --system-site-packages PANDA_VENV && PANDA_VENV/bin/pip install panda-gym
    PANDA_VENV/bin/python -m benchmarks run kuka-speed --steps 1000 --rounds 15

Results: ``benchmarks/results/kuka_speed.json``; section ``kuka-speed`` of ``BENCHMARKS.md``.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import yaml

from benchmarks.harness import Benchmark
from benchmarks.report import BENCHMARKS_DIR, recorded_argv
from sbagents.envs.kuka import (
    KukaPickAndPlaceEnv,
    PickAndPlaceEnv,
    PickAndPlaceGoalEnv,
    RobustKukaPickAndPlaceEnv,
    RobustPickAndPlaceEnv,
)

#: panda-gym's task each Kuka env is compared with.
PUSH_REFERENCE = "PandaPush-v3"
PICK_REFERENCE = "PandaPickAndPlace-v3"
RANDOM_CONFIG = BENCHMARKS_DIR / "configs" / "kuka_random.yml"
SECTION = "kuka-speed"
#: One Kuka env: table label, constructor, and the panda-gym env id it is compared with.
Spec = tuple[str, Callable[[], gym.Env[Any, Any]], str]


def steps_per_second(env: gym.Env[Any, Any], n_steps: int, seed: int = 0) -> tuple[float, int]:
    """Run ``n_steps`` random steps (resetting at episode ends); return (steps/s, episodes)."""
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    env.reset(seed=seed)
    episodes = 0
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
            episodes += 1
    return n_steps / (time.perf_counter() - start), episodes


def random_push_kwargs() -> dict[str, Any]:
    """``env_kwargs`` of the randomized cube push (``sbagents/PickAndPlaceGoal-v0`` in ``kuka_random.yml``)."""
    with open(RANDOM_CONFIG, encoding="utf-8") as f:
        config = yaml.safe_load(f)
    return dict(config["sbagents/PickAndPlaceGoal-v0"]["env_kwargs"])


def kuka_specs() -> list[Spec]:
    """The Kuka envs measured, each with its panda-gym reference (push: PandaPush-v3, gripper: PandaPickAndPlace-v3)."""
    push_kwargs = random_push_kwargs()
    return [
        ("`sbagents/PickAndPlace-v0` (joints, default)", PickAndPlaceEnv, PUSH_REFERENCE),
        ("`sbagents/RobustPickAndPlace-v0` (joints, default)", RobustPickAndPlaceEnv, PUSH_REFERENCE),
        ("`sbagents/PickAndPlace-v0` (`control=\"ee\"`)", lambda: PickAndPlaceEnv(control="ee"), PUSH_REFERENCE),
        ("`sbagents/PickAndPlaceGoal-v0` (ee, default)", PickAndPlaceGoalEnv, PUSH_REFERENCE),
        (
            "`sbagents/PickAndPlaceGoal-v0` (ee, randomized cube push of `kuka_random.yml`)",
            lambda: PickAndPlaceGoalEnv(**push_kwargs),
            PUSH_REFERENCE,
        ),
        ("`sbagents/KukaPickAndPlace-v0` (gripper)", KukaPickAndPlaceEnv, PICK_REFERENCE),
        ("`sbagents/RobustKukaPickAndPlace-v0` (gripper)", RobustKukaPickAndPlaceEnv, PICK_REFERENCE),
    ]


def measure(
    specs: list[Spec], references: dict[str, Callable[[], gym.Env[Any, Any]]], steps: int, rounds: int
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Steps/s of each Kuka env ``(rounds,)`` and its per-round ratios to its reference ``(rounds,)``.

    In each round every Kuka env is timed right beside a fresh timing of its reference (the pair's order
    alternating), so a ratio compares two timings seconds apart. References without panda-gym give no ratios.
    The references' own rates (all their timings) are returned under their names.
    """
    envs = {name: make() for name, make, _ in specs}
    refs = {name: make() for name, make in references.items()}
    rates: dict[str, list[float]] = {name: [] for name in [*envs, *refs]}
    ratios: dict[str, list[float]] = {name: [] for name in envs}
    try:
        for r in range(rounds):
            for i, (name, _, reference) in enumerate(specs):
                pair = [name] if reference not in refs else [name, reference]
                timed: dict[str, float] = {}
                for key in pair if (r + i) % 2 == 0 else reversed(pair):
                    env = envs[key] if key in envs else refs[key]
                    timed[key] = steps_per_second(env, steps, seed=r)[0]
                    rates[key].append(timed[key])
                if reference in timed:
                    ratios[name].append(timed[name] / timed[reference])
            print(f"round {r + 1}/{rounds} done", file=sys.stderr, flush=True)
    finally:
        for env in [*envs.values(), *refs.values()]:
            env.close()
    return rates, ratios


def summarize(specs: list[Spec], rates: dict[str, list[float]], ratios: dict[str, list[float]]) -> list[dict[str, Any]]:
    """One row per env: median steps/s and, for a Kuka env with its reference, the median and range of its
    per-round ratios; the references last."""
    rows = []
    for name, _, reference in specs:
        row: dict[str, Any] = {"env": name, "reference": reference, "steps_per_s": statistics.median(rates[name])}
        if ratios[name]:
            row.update(ratio=statistics.median(ratios[name]), ratio_min=min(ratios[name]), ratio_max=max(ratios[name]))
        rows.append(row)
    for reference in (PUSH_REFERENCE, PICK_REFERENCE):
        if rates.get(reference):
            rows.append({"env": f"panda-gym `{reference}`", "reference": None,
                         "steps_per_s": statistics.median(rates[reference])})
    return rows


def cpu_name() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), else the machine type."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return f"{os.cpu_count()} x {line.split(':', 1)[1].strip()}"
    except OSError:
        pass
    return platform.machine()


def markdown(results: dict[str, Any]) -> str:
    """The ``kuka-speed`` section of BENCHMARKS.md, from the results alone."""
    rows, steps, rounds = results["rows"], results["steps"], results["rounds"]
    command = results["command"].replace("python ", "<panda-gym venv>/bin/python ", 1)
    lines = [
        "## Kuka env speed vs panda-gym",
        "",
        "Command: `python -m venv --system-site-packages <panda-gym venv> && <panda-gym venv>/bin/pip install "
        f"panda-gym`, then `{command}`. Random "
        f"actions, resets included, one env each, one process; {rounds} rounds of {steps} steps per env "
        f"({results['cpu']}, load average {results['load_average']:.1f} at the start). The ratio is "
        "taken within each round against a timing of the matching panda-gym task right beside it (push: "
        "`PandaPush-v3`, gripper: `PandaPickAndPlace-v3`); the table gives the median and the range of the "
        "per-round ratios.",
        "",
        "| env | steps/s (median) | vs panda-gym (median of rounds) | range over rounds | reference |",
        "|---|---:|---:|---:|---|",
    ]
    for row in rows:
        if row["reference"] is None:
            lines.append(f"| {row['env']} | {row['steps_per_s']:,.0f} | 1.00x | | |")
        elif "ratio" in row:
            lines.append(
                f"| {row['env']} | {row['steps_per_s']:,.0f} | {row['ratio']:.2f}x "
                f"| {row['ratio_min']:.2f}-{row['ratio_max']:.2f}x | `{row['reference']}` |"
            )
        else:
            lines.append(f"| {row['env']} | {row['steps_per_s']:,.0f} | n/a | | `{row['reference']}` (not installed) |")
    lines += [
        "",
        "The ee variants pay for inverse kinematics (PyBullet's, 50 iterations to 0.1 mm for the pusher, 30 to 2 mm "
        "for the gripper) and the physics of a 7-joint arm at 240 Hz (pusher) or 192 Hz (gripper); the joint-control "
        "envs skip the inverse kinematics. Absolute rates vary with the host; ratios from one run are comparable.",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Options of ``python -m benchmarks run kuka-speed``."""
    parser = argparse.ArgumentParser(prog=f"python -m benchmarks run {SECTION}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=1000, help="steps per env per round")
    parser.add_argument("--rounds", type=int, default=15, help="interleaved rounds (medians reported)")
    return parser


def panda_references() -> dict[str, Callable[[], gym.Env[Any, Any]]]:
    """panda-gym's tasks by id, or none when panda-gym is not importable."""
    try:
        import panda_gym  # noqa: F401
    except ImportError:
        print("panda-gym is not importable: the ratios are skipped (see this module's docstring)", file=sys.stderr)
        return {}
    return {ref: functools.partial(gym.make, ref) for ref in (PUSH_REFERENCE, PICK_REFERENCE)}


def run(argv: Sequence[str]) -> dict[str, Any]:
    """``python -m benchmarks run kuka-speed [OPTIONS]``: measure; the results record the command."""
    parser = build_parser()
    args = parser.parse_args(list(argv))
    if args.steps < 1 or args.rounds < 1:
        parser.error("--steps and --rounds must be >= 1")
    specs = kuka_specs()
    load = os.getloadavg()[0]
    rates, ratios = measure(specs, panda_references(), args.steps, args.rounds)
    return {"command": " ".join(["python -m benchmarks run", SECTION, *recorded_argv(list(argv))]),
            "cpu": cpu_name(), "steps": args.steps, "rounds": args.rounds, "load_average": load, "rates": rates,
            "ratios": ratios, "rows": summarize(specs, rates, ratios)}


BENCHMARKS = (
    Benchmark(name=SECTION, kind="speed", results="kuka_speed.json",
              summary="Kuka env steps/s vs panda-gym's matching task (per-round ratios)",
              run=run, render=markdown),
)
