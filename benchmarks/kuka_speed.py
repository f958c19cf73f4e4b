"""Environment steps per second (resets included) of the Kuka envs vs panda-gym's matching task.

Random actions, one env, one process; rounds are interleaved and the median per env is reported, so
a load spike on the shared machine hits every env alike. Each Kuka env is compared with ITS panda-gym
task: the pushes (book envs, the goal push, the randomized cube push of ``configs/kuka_random.yml``)
with ``PandaPush-v3``, the gripper envs (``KukaPickAndPlace-v0`` and its robust variant) with
``PandaPickAndPlace-v3``. panda-gym is optional: install it in a venv that sees the system packages, e.g.

    python -m venv --system-site-packages PANDA_VENV && PANDA_VENV/bin/pip install panda-gym
    PANDA_VENV/bin/python benchmarks/kuka_speed.py --steps 3000 --rounds 3 [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

from sbagents.envs.kuka import (
    KukaPickAndPlaceEnv,
    PickAndPlaceEnv,
    PickAndPlaceGoalEnv,
    RobustKukaPickAndPlaceEnv,
    RobustPickAndPlaceEnv,
)

#: panda-gym's task each Kuka env is compared with.
PUSH_REFERENCE = "PandaPush-v3 (panda-gym)"
PICK_REFERENCE = "PandaPickAndPlace-v3 (panda-gym)"
RANDOM_CONFIG = Path(__file__).resolve().parent / "configs" / "kuka_random.yml"


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


def make_envs() -> dict[str, tuple[Callable[[], gym.Env[Any, Any]], str | None]]:
    """Constructor and reference name (``None`` for a reference itself) of each measured env.

    The panda-gym envs are included only if panda-gym is importable.
    """
    push_kwargs = random_push_kwargs()
    envs: dict[str, tuple[Callable[[], gym.Env[Any, Any]], str | None]] = {
        "PickAndPlace-v0 (joints)": (PickAndPlaceEnv, PUSH_REFERENCE),
        "PickAndPlace-v0 (ee)": (lambda: PickAndPlaceEnv(control="ee"), PUSH_REFERENCE),
        "RobustPickAndPlace-v0 (joints)": (RobustPickAndPlaceEnv, PUSH_REFERENCE),
        "PickAndPlaceGoal-v0 (ee)": (PickAndPlaceGoalEnv, PUSH_REFERENCE),
        "PickAndPlaceGoal-v0 (random cube)": (lambda: PickAndPlaceGoalEnv(**push_kwargs), PUSH_REFERENCE),
        "KukaPickAndPlace-v0": (KukaPickAndPlaceEnv, PICK_REFERENCE),
        "RobustKukaPickAndPlace-v0": (RobustKukaPickAndPlaceEnv, PICK_REFERENCE),
    }
    try:
        import panda_gym  # noqa: F401

        envs[PUSH_REFERENCE] = (lambda: gym.make("PandaPush-v3"), None)
        envs[PICK_REFERENCE] = (lambda: gym.make("PandaPickAndPlace-v3"), None)
    except ImportError:
        print("panda-gym not importable: the panda-gym references are skipped")
    return envs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000, help="steps per env per round")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (median reported)")
    parser.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = parser.parse_args()
    specs = make_envs()
    envs = {name: make() for name, (make, _) in specs.items()}
    rates: dict[str, list[float]] = {name: [] for name in envs}
    episodes: dict[str, int] = {}
    for r in range(args.rounds):
        for name, env in envs.items():
            rate, eps = steps_per_second(env, args.steps, seed=r)
            rates[name].append(rate)
            episodes[name] = eps
    medians = {name: statistics.median(values) for name, values in rates.items()}
    rows = []
    print(
        f"{'env':34s} {'steps/s (median)':>17s} {'min':>8s} {'max':>8s}"
        f" {'episodes/round':>15s} {'ratio':>7s}  reference"
    )
    for name, values in rates.items():
        reference = specs[name][1]
        ratio = 1.0 if reference is None else medians[name] / medians.get(reference, float("nan"))
        rows.append(
            {
                "env": name,
                "steps_per_s": medians[name],
                "min": min(values),
                "max": max(values),
                "episodes_per_round": episodes[name],
                "reference": reference,
                "ratio": ratio,
            }
        )
        print(
            f"{name:34s} {medians[name]:17.0f} {min(values):8.0f} {max(values):8.0f}"
            f" {episodes[name]:15d} {ratio:6.2f}x  {reference or '-'}"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"steps": args.steps, "rounds": args.rounds, "envs": rows}, indent=1) + "\n")
    for env in envs.values():
        env.close()


if __name__ == "__main__":
    main()
