"""Environment steps per second (resets included) of the Kuka push envs vs panda-gym's PandaPush-v3.

Random actions, one env, one process; rounds are interleaved and the median per env is reported, so
a load spike on the shared machine hits every env alike. panda-gym is optional: install it in a venv
that sees the system packages, e.g.

    python -m venv --system-site-packages PANDA_VENV && PANDA_VENV/bin/pip install panda-gym
    PANDA_VENV/bin/python benchmarks/kuka_speed.py --steps 3000 --rounds 3
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from sbagents.envs.kuka import PickAndPlaceEnv, PickAndPlaceGoalEnv, RobustPickAndPlaceEnv


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


def make_envs() -> dict[str, Callable[[], gym.Env[Any, Any]]]:
    """Constructors of the measured envs (PandaPush-v3 only if panda-gym is importable)."""
    envs: dict[str, Callable[[], gym.Env[Any, Any]]] = {
        "PickAndPlace-v0 (joints)": PickAndPlaceEnv,
        "PickAndPlace-v0 (ee)": lambda: PickAndPlaceEnv(control="ee"),
        "RobustPickAndPlace-v0 (joints)": RobustPickAndPlaceEnv,
        "PickAndPlaceGoal-v0 (ee)": PickAndPlaceGoalEnv,
    }
    try:
        import panda_gym  # noqa: F401

        envs["PandaPush-v3 (panda-gym)"] = lambda: gym.make("PandaPush-v3")
    except ImportError:
        print("panda-gym not importable: PandaPush-v3 skipped")
    return envs


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=3000, help="steps per env per round")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (median reported)")
    args = parser.parse_args()
    constructors = make_envs()
    envs = {name: make() for name, make in constructors.items()}
    rates: dict[str, list[float]] = {name: [] for name in envs}
    episodes: dict[str, int] = {}
    for r in range(args.rounds):
        for name, env in envs.items():
            rate, eps = steps_per_second(env, args.steps, seed=r)
            rates[name].append(rate)
            episodes[name] = eps
    panda = rates.get("PandaPush-v3 (panda-gym)")
    panda_rate = statistics.median(panda) if panda else float("nan")
    print(
        f"{'env':34s} {'steps/s (median)':>17s} {'min':>8s} {'max':>8s}"
        f" {'episodes/round':>15s} {'vs panda':>9s}"
    )
    for name, values in rates.items():
        med = statistics.median(values)
        ratio = med / panda_rate if np.isfinite(panda_rate) else float("nan")
        print(
            f"{name:34s} {med:17.0f} {min(values):8.0f} {max(values):8.0f} {episodes[name]:15d} {ratio:8.2f}x"
        )
    for env in envs.values():
        env.close()


if __name__ == "__main__":
    main()
