"""Batched VecEnvs (``sbagents.batched``) vs the reference VecEnvs, step by step.

References: GridWorld -> ``make_vec_env`` (DummyVecEnv of Monitor-wrapped envs);
TreasureHunt -> :class:`sbagents.multiagent.parameter_sharing.ParameterSharingVecEnv`. Random seeds and random actions;
observations, rewards, dones and infos (Monitor's wall-clock ``t`` aside) must be identical, including
across auto-resets, and so must the monitor CSVs.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

import sbagents  # noqa: F401  (registers the Gymnasium ids)
from sbagents.batched import BatchedGridWorldVecEnv, BatchedTreasureHuntVecEnv, make_batched_vec_env
from sbagents.envs.treasure_hunt_v0 import parallel_env
from sbagents.multiagent.parameter_sharing import make_parameter_sharing_vec_env

GW = "sbagents/GridWorld-v0"
TH = "treasure_hunt_v0"


def _strip_time(info: dict[str, Any]) -> dict[str, Any]:
    info = dict(info)
    if "episode" in info:
        info["episode"] = {k: v for k, v in info["episode"].items() if k != "t"}
    return info


def _compare(batched: VecEnv, ref: VecEnv, n_steps: int, seed: int) -> dict[str, int]:
    """Step both with the same random actions; assert identical outputs; count episode outcomes."""
    obs_b, obs_r = np.asarray(batched.reset()), np.asarray(ref.reset())
    assert obs_b.dtype == obs_r.dtype and obs_b.shape == obs_r.shape
    np.testing.assert_array_equal(obs_b, obs_r)
    assert batched.reset_infos == ref.reset_infos
    rng = np.random.default_rng(seed)
    counts = {"terminated": 0, "truncated": 0}
    for t in range(n_steps):
        actions = rng.integers(0, int(ref.action_space.n), size=ref.num_envs)  # type: ignore[attr-defined]
        o_b, r_b, d_b, i_b = batched.step(actions)
        o_r, r_r, d_r, i_r = ref.step(actions)
        assert isinstance(o_b, np.ndarray) and isinstance(o_r, np.ndarray)
        assert o_b.dtype == o_r.dtype and r_b.dtype == r_r.dtype and d_b.dtype == d_r.dtype
        np.testing.assert_array_equal(o_b, o_r, err_msg=f"observations differ at step {t}")
        np.testing.assert_array_equal(r_b, r_r, err_msg=f"rewards differ at step {t}")
        np.testing.assert_array_equal(d_b, d_r, err_msg=f"dones differ at step {t}")
        for k, (ib, ir) in enumerate(zip(i_b, i_r, strict=True)):
            ib, ir = _strip_time(ib), _strip_time(ir)
            term_b, term_r = ib.pop("terminal_observation", None), ir.pop("terminal_observation", None)
            assert ib == ir, f"infos differ at step {t}, slot {k}: {ib} != {ir}"
            assert (term_b is None) == (term_r is None)
            if term_r is not None:
                assert type(term_b) is type(term_r) and np.array_equal(term_b, term_r)
            if "episode" in ir:
                counts["truncated" if ir["TimeLimit.truncated"] else "terminated"] += 1
        assert batched.reset_infos == ref.reset_infos
    return counts


def _monitor_rows(path: Path) -> list[tuple[str, str, str]]:
    with path.open() as fh:
        lines = fh.read().splitlines()
    assert lines[0].startswith("#")
    return [(row["r"], row["l"], row.get("treasures_collected", "")) for row in csv.DictReader(lines[1:])]


@pytest.mark.parametrize(
    "env_kwargs",
    [
        {},
        {"max_steps": 12},
        {"size": (4, 6), "start": (3, 0), "goal": (0, 5), "obstacles": [(1, 1), (2, 3)], "max_steps": 30},
    ],
)
@pytest.mark.parametrize("seed", [0, 7])
def test_gridworld_matches_dummy_vec_env(env_kwargs: dict[str, Any], seed: int, tmp_path: Path) -> None:
    n_envs = 6
    batched = make_batched_vec_env(GW, n_envs, seed, env_kwargs, str(tmp_path / "b"))
    ref = make_vec_env(GW, n_envs=n_envs, seed=seed, env_kwargs=env_kwargs, monitor_dir=str(tmp_path / "r"))
    assert isinstance(batched, BatchedGridWorldVecEnv)
    counts = _compare(batched, ref, 400, seed)
    assert counts["truncated"] > 0
    batched.close()
    ref.close()
    for i in range(n_envs):
        rows = _monitor_rows(tmp_path / "b" / f"{i}.monitor.csv")
        assert rows and rows == _monitor_rows(tmp_path / "r" / f"{i}.monitor.csv")


def test_gridworld_terminates_with_success_like_reference() -> None:
    # a policy that walks the optimal path reaches the goal: terminal infos and returns must match too
    path = [3, 3, 3, 3, 1, 1, 1, 1]  # along the top row, then down the last column: return 93
    batched = make_batched_vec_env(GW, 3, 0, {}, None)
    ref = make_vec_env(GW, n_envs=3, seed=0)
    batched.reset()
    ref.reset()
    for a in path:
        o_b, r_b, d_b, i_b = batched.step(np.full(3, a))
        o_r, r_r, d_r, i_r = ref.step(np.full(3, a))
        np.testing.assert_array_equal(o_b, o_r)
        assert [_strip_time(i) for i in i_b][0].keys() == _strip_time(i_r[0]).keys()
    assert d_b.all() and i_b[0]["is_success"] is True and i_b[0]["episode"]["r"] == 93.0
    assert i_b[0]["TimeLimit.truncated"] is False and i_b[0]["terminal_observation"] == 24


TH_CASES = [
    {"observation": "egocentric"},
    {"observation": "book"},
    {"observation": "egocentric", "reward_mode": "individual", "max_cycles": 12},
    # dense: frequent terminations and two agents stepping onto the same treasure in one step
    {"observation": "egocentric", "grid_size": 4, "obstacles": [], "n_treasures": 8, "max_cycles": 20},
    {"observation": "book", "grid_size": 5, "obstacles": [(2, 2)], "n_agents": 4, "n_treasures": 10},
    {"observation": "egocentric", "n_agents": 1, "max_cycles": 15},
]


@pytest.mark.parametrize("env_kwargs", TH_CASES)
@pytest.mark.parametrize("seed", [3, 11])
def test_treasure_hunt_matches_parameter_sharing_vec_env(
    env_kwargs: dict[str, Any], seed: int, tmp_path: Path
) -> None:
    n_envs = 5
    batched = make_batched_vec_env(TH, n_envs, seed, env_kwargs, str(tmp_path / "b"))
    ref = make_parameter_sharing_vec_env(parallel_env, n_envs, seed, env_kwargs, str(tmp_path / "r"))
    assert isinstance(batched, BatchedTreasureHuntVecEnv)
    assert batched.num_envs == ref.num_envs and batched.observation_space == ref.observation_space
    counts = _compare(batched, ref, 300, seed)
    assert counts["truncated"] > 0
    if env_kwargs.get("n_treasures", 5) >= 8:
        assert counts["terminated"] > 0
    batched.close()
    ref.close()
    rows = _monitor_rows(tmp_path / "b" / "0.monitor.csv")
    assert rows and rows == _monitor_rows(tmp_path / "r" / "0.monitor.csv")


def test_treasure_hunt_seed_and_options_like_reference() -> None:
    kwargs = {"observation": "egocentric"}
    batched = make_batched_vec_env(TH, 3, None, kwargs, None)
    ref = make_parameter_sharing_vec_env(parallel_env, 3, None, kwargs, None)
    batched.seed(123)
    ref.seed(123)
    np.testing.assert_array_equal(batched.reset(), ref.reset())
    first = batched.reset()  # no new seed: continues the generators, like the reference
    np.testing.assert_array_equal(first, ref.reset())
    batched.seed(124)
    assert not np.array_equal(np.asarray(batched.reset()), np.asarray(first))
    # agents 0 and 1 both step onto the treasure at (0, 2): only agent 0 (moves first) collects it
    options = {"agents": [(0, 1), (1, 2), (9, 9)], "treasures": [(0, 2), (1, 0), (4, 5), (7, 7), (9, 8)]}
    batched.set_options(options)
    ref.set_options(options)
    np.testing.assert_array_equal(batched.reset(), ref.reset())
    for actions in (np.array([3, 0, 2] * 3), np.array([4, 4, 4] * 3)):
        o_b, r_b, _, i_b = batched.step(actions)
        o_r, r_r, _, i_r = ref.step(actions)
        np.testing.assert_array_equal(o_b, o_r)
        np.testing.assert_array_equal(r_b, r_r)
        assert i_b == i_r
        if actions[0] == 3:
            assert [i["event"] for i in i_b[:3]] == ["treasure", "move", "treasure"]
            assert r_b[:3].tolist() == [19.0, 19.0, 19.0]
    assert i_b[0]["treasures_collected"] == 2


def test_attributes_methods_and_rendering_like_reference() -> None:
    kwargs = {"observation": "egocentric", "render_mode": "rgb_array"}
    batched = make_batched_vec_env(TH, 2, 5, kwargs, None)
    ref = make_parameter_sharing_vec_env(parallel_env, 2, 5, kwargs, None)
    batched.reset()
    ref.reset()
    for actions in np.random.default_rng(0).integers(0, 5, size=(7, 6)):
        batched.step(actions)
        ref.step(actions)
    for name in ("obs_names", "action_names", "positions", "present", "steps", "render_mode"):
        assert batched.get_attr(name) == ref.get_attr(name), name
    assert batched.get_attr("possible_agents", [4]) == ref.get_attr("possible_agents", [4])
    state_b, state_r = batched.env_method("state", indices=[3])[0], ref.env_method("state", indices=[3])[0]
    np.testing.assert_array_equal(state_b, state_r)
    assert batched.env_method("grid_text") == ref.env_method("grid_text")
    for img_b, img_r in zip(batched.get_images(), ref.get_images(), strict=True):
        np.testing.assert_array_equal(img_b, img_r)
    assert batched.env_is_wrapped(Monitor) == ref.env_is_wrapped(Monitor)
    with pytest.raises(NotImplementedError):
        batched.env_method("reset")
    grid = make_batched_vec_env(GW, 2, 0, {"render_mode": "rgb_array"}, None)
    grid_ref = make_vec_env(GW, n_envs=2, seed=0, env_kwargs={"render_mode": "rgb_array"})
    for vec in (grid, grid_ref):
        vec.reset()
        vec.step(np.array([1, 3]))
    assert grid.get_attr("obs_names") == grid_ref.get_attr("obs_names") == [("cell",), ("cell",)]
    assert grid.get_attr("agent") == grid_ref.get_attr("agent") == [(1, 0), (0, 1)]
    np.testing.assert_array_equal(grid.render(), grid_ref.render())
    assert grid.env_is_wrapped(Monitor) == grid_ref.env_is_wrapped(Monitor) == [True, True]


def test_invalid_actions_and_unknown_ids_raise() -> None:
    for env_id, n_actions in ((GW, 4), (TH, 5)):
        vec = make_batched_vec_env(env_id, 2, 0, {}, None)
        vec.reset()
        for bad in (n_actions, -1):
            actions = np.zeros(vec.num_envs, dtype=np.int64)
            actions[1] = bad
            with pytest.raises(ValueError, match="actions must be"):
                vec.step(actions)
    with pytest.raises(ValueError, match="no batched VecEnv"):
        make_batched_vec_env("CartPole-v1", 2, 0, {}, None)


def test_ppo_trains_on_batched_envs() -> None:
    torch.set_num_threads(1)
    for env_id, kwargs in ((GW, {}), (TH, {"observation": "egocentric"})):
        vec = make_batched_vec_env(env_id, 4, 0, kwargs, None)
        model = PPO("MlpPolicy", vec, n_steps=32, batch_size=64, n_epochs=1, seed=0,
                    policy_kwargs={"net_arch": [16]})
        model.learn(256)
        assert model.num_timesteps >= 256
        assert model.ep_info_buffer is not None and (len(model.ep_info_buffer) > 0 or env_id == TH)
