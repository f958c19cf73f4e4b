"""simple_spread's team metrics (:mod:`sbagents.batched.spread_metrics`): collisions (colliding agent pairs per step,
summed over the episode), landmarks covered (nearest agent within 0.1) at the last step and on average.

Hand-built states give known counts on the batched VecEnv and on mpe2's own env under the observer wrapper; on seeded
random episodes the batched VecEnv, the array ParallelEnv and mpe2's env report the same metrics; they reach the
team summary (``evaluate --json``, the train summary) and the monitor file.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sbagents.batched.spread_metrics import (
    COVER_RADIUS,
    SPREAD_METRICS,
    SpreadMetricsWrapper,
    landmark_distances,
    pair_distances,
    spread_metrics_env,
    step_counts,
)

mpe2_spread = pytest.importorskip("mpe2.simple_spread_v3")

SS = "mpe2.simple_spread_v3"

# (agent positions, landmark positions) -> (colliding pairs, landmarks covered); agents have size 0.15 (collide
# closer than 0.3)
STATES: list[tuple[list[list[float]], list[list[float]], int, int]] = [
    # agents 0 and 1 overlap, agent 2 far away; no landmark within 0.1 of an agent
    ([[0.0, 0.0], [0.1, 0.0], [0.9, 0.9]], [[-0.8, -0.8], [0.5, -0.5], [-0.5, 0.5]], 1, 0),
    # every agent on its own landmark, far apart
    ([[-0.7, -0.7], [0.7, -0.7], [0.0, 0.7]], [[-0.7, -0.7], [0.7, -0.65], [0.05, 0.7]], 0, 3),
    # all three in one heap on one landmark: three pairs, one landmark covered
    ([[0.0, 0.0], [0.05, 0.0], [0.0, 0.05]], [[0.0, 0.0], [0.9, 0.9], [-0.9, 0.9]], 3, 1),
]


def test_step_counts_on_arrays() -> None:
    for agents, landmarks, pairs, covered in STATES:
        pos, lm = np.array(agents), np.array(landmarks)
        _, dist = pair_distances(pos)
        hits = dist < np.where(np.eye(3, dtype=bool), 0.0, 0.3)
        got = step_counts(hits, landmark_distances(pos, lm))
        assert (int(got[0]), int(got[1])) == (pairs, covered)
    # the radius is inclusive: a landmark exactly 0.1 away is covered, one a bit further is not
    closest = np.array([COVER_RADIUS, COVER_RADIUS + 1e-9, 0.0])
    assert int(step_counts(np.zeros((3, 3), dtype=bool), closest)[1]) == 2


def _batched_one_step(states: list[tuple[list[list[float]], list[list[float]], int, int]]) -> list[dict[str, Any]]:
    """One-step episodes of the batched VecEnv from hand-built states (no-op actions: no velocity, so positions
    stay); every copy's episode metrics."""
    from sbagents.batched import make_batched_vec_env

    venv = make_batched_vec_env(SS, len(states), 0, {"max_cycles": 1}, None)
    venv.reset()
    venv._pos[:] = np.array([s[0] for s in states])  # type: ignore[attr-defined]
    venv._lm[:] = np.array([s[1] for s in states])  # type: ignore[attr-defined]
    venv._geometry()  # type: ignore[attr-defined]
    _, _, dones, infos = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
    assert dones.all()
    venv.close()
    n_a = 3
    for k, info in enumerate(infos):  # every slot of a copy carries its copy's metrics
        assert {key: info[key] for key in SPREAD_METRICS} == {key: infos[k - k % n_a][key] for key in SPREAD_METRICS}
    return [infos[i * n_a]["episode"] for i in range(len(states))]


def test_batched_metrics_on_hand_built_states() -> None:
    episodes = _batched_one_step(STATES)
    for episode, (_, _, pairs, covered) in zip(episodes, STATES, strict=True):
        assert episode["collisions"] == pairs
        assert episode["landmarks_covered"] == covered
        assert episode["landmarks_covered_mean"] == float(covered)  # one step: the mean is the last count


def test_wrapper_metrics_on_hand_built_states() -> None:
    for agents, landmarks, pairs, covered in STATES:
        env = SpreadMetricsWrapper(mpe2_spread.parallel_env(max_cycles=2))
        env.reset(seed=0)
        world = env.unwrapped.world
        for agent, p in zip(world.agents, agents, strict=True):
            agent.state.p_pos, agent.state.p_vel = np.array(p), np.zeros(2)
        for landmark, p in zip(world.landmarks, landmarks, strict=True):
            landmark.state.p_pos = np.array(p)
        _, _, _, _, infos = env.step(dict.fromkeys(env.agents, 0))
        assert infos == {a: {} for a in env.possible_agents}  # nothing before the episode's last step
        # second (last) step: no velocity -> the same positions; the overlapping agents have been pushed apart by
        # now, so count again from this step's positions
        _, _, _, truncs, infos = env.step(dict.fromkeys(env.agents, 0))
        assert all(truncs.values()) and not env.agents
        pos = np.array([a.state.p_pos for a in world.agents])
        lm = np.array([lm.state.p_pos for lm in world.landmarks])
        _, dist = pair_distances(pos)
        last_pairs, last_cov = step_counts(dist < np.where(np.eye(3, dtype=bool), 0.0, 0.3),
                                           landmark_distances(pos, lm))
        expected = {"collisions": pairs + int(last_pairs), "landmarks_covered": int(last_cov),
                    "landmarks_covered_mean": (covered + int(last_cov)) / 2}
        assert all(info == expected for info in infos.values()), (infos, expected)
        env.close()


def _random_episodes(venv: Any, n_episodes: int, seed: int) -> list[dict[str, Any]]:
    """The team ``episode`` infos of ``n_episodes`` episodes of random actions (per copy, in order)."""
    venv.seed(seed)
    venv.reset()
    rng = np.random.default_rng(seed)
    out: list[dict[str, Any]] = []
    while len(out) < n_episodes:
        _, _, _, infos = venv.step(rng.integers(0, 5, size=venv.num_envs))
        out += [{k: v for k, v in info["episode"].items() if k != "t"} for info in infos if "episode" in info]
    return out


@pytest.mark.parametrize("kwargs", [{}, {"N": 4, "local_ratio": 0.2, "max_cycles": 15}])
def test_batched_equals_reference_paths(kwargs: dict[str, Any]) -> None:
    from sbagents.batched import make_batched_vec_env
    from sbagents.batched.spread_env import SimpleSpreadParallelEnv
    from sbagents.multiagent.parameter_sharing import ParameterSharingVecEnv

    n_envs, n_episodes, seed = 3, 24, 7
    batched = make_batched_vec_env(SS, n_envs, None, kwargs, None)
    array = ParameterSharingVecEnv([lambda: SimpleSpreadParallelEnv(**kwargs)] * n_envs)
    mpe2 = ParameterSharingVecEnv([lambda: spread_metrics_env(mpe2_spread.parallel_env(**kwargs))] * n_envs)
    got = [_random_episodes(v, n_episodes, seed) for v in (batched, array, mpe2)]
    for v in (batched, array, mpe2):
        v.close()
    assert got[0] == got[1] == got[2]
    assert all(set(SPREAD_METRICS) <= set(e) for e in got[0])
    assert sum(e["collisions"] for e in got[0]) > 0  # random play collides now and then
    n_landmarks = kwargs.get("N", 3)
    assert all(0 <= e["landmarks_covered"] <= n_landmarks for e in got[0])


def test_make_parallel_env_declares_the_metrics_on_every_path() -> None:
    from sbagents.batched.spread_env import SimpleSpreadParallelEnv
    from sbagents.core.env_names import make_parallel_env

    fast = make_parallel_env(SS)
    own = make_parallel_env(SS, continuous_actions=True)  # not reproduced by the array env: mpe2's, observed
    other = make_parallel_env("mpe2.simple_push_v3")
    assert isinstance(fast, SimpleSpreadParallelEnv) and isinstance(own, SpreadMetricsWrapper)
    assert fast.metadata["info_metrics"] == own.metadata["info_metrics"] == SPREAD_METRICS
    assert "info_metrics" not in other.metadata
    assert spread_metrics_env(fast) is fast  # declared already: not wrapped twice
    own.reset(seed=1)
    while own.agents:
        *_, infos = own.step({a: own.action_space(a).sample() for a in own.agents})
    assert all(set(SPREAD_METRICS) <= set(i) for i in infos.values())
    for env in (fast, own, other):
        env.close()


def test_team_summary_and_monitor_carry_the_means(tmp_path: Path) -> None:
    from sbagents.batched import make_batched_vec_env
    from sbagents.multiagent.team_eval import evaluate_team

    def still(obs: np.ndarray) -> np.ndarray:
        return np.zeros(len(obs), dtype=np.int64)

    summary = evaluate_team(None, make_batched_vec_env(SS, 1, None, {}, str(tmp_path / "m")), n_episodes=4,
                            seed=3, act=still)
    metrics = summary["metrics"]
    assert set(SPREAD_METRICS) <= set(metrics) and all(isinstance(metrics[k], float) for k in SPREAD_METRICS)
    assert metrics["collisions"] >= 0 and 0.0 <= metrics["landmarks_covered_mean"] <= 3.0
    rows = list(csv.DictReader((tmp_path / "m" / "0.monitor.csv").read_text().splitlines()[1:]))
    assert len(rows) == 4 and list(rows[0]) == ["r", "l", "t", *SPREAD_METRICS]
