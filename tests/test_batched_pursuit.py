"""Batched SISL pursuit (:mod:`sbagents.batched.pursuit`) vs the reference team VecEnv, step by step.

Reference: :func:`sbagents.multiagent.groups.team_vec_envs` with ``policies: shared`` over copies of
``pettingzoo.sisl.pursuit_v5.parallel_env`` (what ``python -m sbagents.train --env pettingzoo.sisl.pursuit_v5``
builds without the batched VecEnv). Seeded copies and random actions: observations, rewards, dones, infos, episode
stats and monitor rows are identical, through catches, terminations (every evader caught), truncations, auto-resets
and a mid-episode ``reset()``, with shared and individual rewards. Also: seeding, the ``--vec-env`` choice.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecEnv

from sbagents.batched import BatchedPursuitVecEnv, batched_env_id, make_batched_vec_env, unbatchable_kwargs
from sbagents.batched.pursuit import need_to_surround
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import TrainSpec
from sbagents.core.team_options import TeamOptions
from sbagents.env_factory import vec_env_kind
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs

pursuit_v5 = pytest.importorskip("pettingzoo.sisl.pursuit_v5")

PU = "pettingzoo.sisl.pursuit_v5"


def reference(n_envs: int, seed: int | None, kwargs: dict[str, Any], monitor_dir: str | None = None) -> VecEnv:
    """The VecEnv sbagents trains pursuit on without the batched one (one ``shared`` group)."""
    return team_vec_envs(ParallelEnvFactory(PU, (), kwargs), n_envs, TeamOptions(), seed=seed,
                         monitor_dir=monitor_dir)["shared"]


def _compare(batched: VecEnv, ref: VecEnv, n_steps: int, seed: int, reset_at: int | None) -> dict[str, int]:
    """Step both with the same random actions; everything must be identical. Counts what the steps covered."""
    np.testing.assert_array_equal(batched.reset(), ref.reset())
    rng = np.random.default_rng(seed)
    counts = {"episodes": 0, "terminated": 0, "catch_steps": 0}
    for t in range(n_steps):
        if t == reset_at:
            np.testing.assert_array_equal(batched.reset(), ref.reset())
        actions = rng.integers(0, 5, size=ref.num_envs)
        o_b, r_b, d_b, i_b = batched.step(actions)
        o_r, r_r, d_r, i_r = ref.step(actions)
        assert o_b.dtype == o_r.dtype == np.float32 and r_b.dtype == r_r.dtype  # type: ignore[union-attr]
        np.testing.assert_array_equal(o_b, o_r, err_msg=f"observations differ at step {t}")
        np.testing.assert_array_equal(r_b, r_r, err_msg=f"rewards differ at step {t}")
        np.testing.assert_array_equal(d_b, d_r, err_msg=f"dones differ at step {t}")
        counts["catch_steps"] += int((r_r > 0.5).any())  # a catch pays catch_reward (5) to its pursuers
        for k, (ib, ir) in enumerate(zip(i_b, i_r, strict=True)):
            assert ib.keys() == ir.keys(), f"info keys differ at step {t}, slot {k}"
            if "terminal_observation" in ir:
                np.testing.assert_array_equal(ib["terminal_observation"], ir["terminal_observation"])
                assert ib["TimeLimit.truncated"] is ir["TimeLimit.truncated"]
            if "episode" in ir:
                assert ib["episode"]["r"] == ir["episode"]["r"] and ib["episode"]["l"] == ir["episode"]["l"]
                counts["episodes"] += 1
                counts["terminated"] += not ir["TimeLimit.truncated"]
    return counts


def _rows(path: Path) -> list[tuple[str, str]]:
    return [(row["r"], row["l"]) for row in csv.DictReader(path.read_text().splitlines()[1:])]


CASES = [  # kwargs, copies, steps, mid-episode reset, (min episodes, min terminated episodes, min catch steps)
    ({"max_cycles": 30}, 2, 70, None, (4, 0, 0)),
    ({"x_size": 5, "y_size": 5, "n_evaders": 1, "n_pursuers": 6, "max_cycles": 50}, 4, 200, 90, (10, 5, 5)),
    ({"x_size": 8, "y_size": 7, "n_evaders": 4, "n_pursuers": 5, "max_cycles": 40, "shared_reward": False,
      "obs_range": 5, "tag_reward": 0.1, "catch_reward": 2.0, "urgency_reward": -0.2}, 3, 160, None, (9, 0, 1)),
]


@pytest.mark.parametrize(("env_kwargs", "n_envs", "n_steps", "reset_at", "least"), CASES)
def test_matches_reference_team_vec_env(env_kwargs: dict[str, Any], n_envs: int, n_steps: int,
                                        reset_at: int | None, least: tuple[int, int, int], tmp_path: Path) -> None:
    seed = 7
    batched = make_batched_vec_env(PU, n_envs, seed, env_kwargs, str(tmp_path / "b"))
    ref = reference(n_envs, seed, env_kwargs, str(tmp_path / "r"))
    assert isinstance(batched, BatchedPursuitVecEnv)
    assert batched.num_envs == ref.num_envs and batched.observation_space == ref.observation_space
    assert batched.action_space == ref.action_space
    counts = _compare(batched, ref, n_steps, seed, reset_at)
    assert counts["episodes"] >= least[0] and counts["terminated"] >= least[1] and counts["catch_steps"] >= least[2], \
        counts
    batched.close()
    ref.close()
    rows = _rows(tmp_path / "b" / "0.monitor.csv")
    assert rows == _rows(tmp_path / "r" / "0.monitor.csv") and len(rows) == counts["episodes"]


def test_seeding_like_reference() -> None:
    n, n_p = 2, 8
    batched = make_batched_vec_env(PU, n, None, {}, None)
    ref = reference(n, None, {})
    assert batched.seed(42) == ref.seed(42) == [42 + k // n_p for k in range(n * n_p)]
    first = np.asarray(batched.reset())
    np.testing.assert_array_equal(first, np.asarray(ref.reset()))
    for i in range(n):  # copy i starts as a lone env reset with seed + i
        alone, _ = pursuit_v5.parallel_env().reset(seed=42 + i)
        np.testing.assert_array_equal(first.reshape(n, n_p, 7, 7, 3)[i], np.stack(list(alone.values())))
    second = np.asarray(batched.reset())  # the generators continue, as the reference's
    np.testing.assert_array_equal(second, np.asarray(ref.reset()))
    assert not np.array_equal(first, second)
    batched.seed(42)
    np.testing.assert_array_equal(np.asarray(batched.reset()), first)


def test_need_to_surround_and_attributes() -> None:
    game = pursuit_v5.parallel_env().unwrapped.env
    table = need_to_surround(np.array(game.map_matrix))
    for x, y in [(0, 0), (0, 7), (15, 15), (3, 3), (4, 8), (5, 2), (12, 12), (13, 8)]:
        assert table[x, y] == game.need_to_surround(x, y), (x, y)
    batched = make_batched_vec_env(PU, 2, 3, {"max_cycles": 20}, None)
    ref = reference(2, 3, {"max_cycles": 20})
    with pytest.raises(RuntimeError, match="reset"):
        batched.step(np.zeros(16, dtype=np.int64))
    batched.reset()
    ref.reset()
    for actions in np.random.default_rng(1).integers(0, 5, size=(12, 16)):
        batched.step(actions)
        ref.step(actions)
    for index in (0, 9):
        np.testing.assert_array_equal(batched.env_method("state", indices=[index])[0],
                                      ref.env_method("state", indices=[index])[0])
    assert batched.get_attr("possible_agents") == ref.get_attr("possible_agents")
    bad = np.zeros(16, dtype=np.int64)
    bad[3] = 5
    with pytest.raises(ValueError, match="actions must be"):
        batched.step(bad)


def test_batchable_kwargs() -> None:
    assert batched_env_id("pursuit_v5", PU) == batched_env_id("parallel_env", f"{PU}:parallel_env") == PU
    assert unbatchable_kwargs(PU, {"n_evaders": 5, "shared_reward": False, "surround": True}) == []
    assert len(unbatchable_kwargs(PU, {"surround": False, "freeze_evaders": True, "render_mode": "rgb_array"})) == 3
    with pytest.raises(ValueError, match="surround=False"):
        BatchedPursuitVecEnv(1, {"surround": False})
    ref = resolve_env(PU)
    exp = build_experiment(TrainSpec("ppo", PU), ref)
    assert vec_env_kind("auto", exp, ref, {}) == "batched"
    assert vec_env_kind("auto", exp, ref, {"freeze_evaders": True}) == "dummy"
    per_agent = build_experiment(TrainSpec("ppo", PU, hyperparams={"policies": "per_agent"}), ref)
    assert vec_env_kind("auto", per_agent, ref, {}) == "dummy"
