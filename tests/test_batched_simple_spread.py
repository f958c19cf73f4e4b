"""Batched MPE simple spread (:mod:`sbagents.batched.simple_spread`) vs the reference team VecEnv, step by step.

Reference: :func:`sbagents.multiagent.groups.team_vec_envs` with ``policies: shared`` over copies of
``mpe2.simple_spread_v3.parallel_env`` (what ``python -m sbagents.train --env mpe2.simple_spread_v3`` builds without
the batched VecEnv). Random seeds and random actions; observations and rewards within 1e-5 (they are in fact
identical), dones and info keys identical, episode stats and the monitor rows alike, including across auto-resets
and a mid-episode ``reset()``. Also: seeding, the ``--vec-env`` choice and its one-line error through the CLI.
"""

from __future__ import annotations

import csv
import importlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

import sbagents.batched
from sbagents.batched import BatchedSimpleSpreadVecEnv, batched_env_id, make_batched_vec_env, unbatchable_kwargs
from sbagents.batched.spread_metrics import SPREAD_METRICS, spread_metrics_env
from sbagents.cli_common import run
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import TrainSpec
from sbagents.core.team_options import TeamOptions
from sbagents.env_factory import vec_env_kind
from sbagents.errors import UsageError
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs

mpe2_spread = pytest.importorskip("mpe2.simple_spread_v3")

SS = "mpe2.simple_spread_v3"
TOL = 1e-5


def reference(n_envs: int, seed: int | None, kwargs: dict[str, Any], monitor_dir: str | None = None) -> VecEnv:
    """The VecEnv sbagents trains simple spread on without the batched one (one ``shared`` group)."""
    views = team_vec_envs(ParallelEnvFactory(SS, (), kwargs), n_envs, TeamOptions(), seed=seed,
                          monitor_dir=monitor_dir)
    return views["shared"]


def _compare(batched: VecEnv, ref: VecEnv, n_agents: int, n_steps: int, seed: int, reset_at: int | None = None
             ) -> dict[str, int]:
    """Step both with the same random actions and compare everything; count episodes and collision steps."""
    obs_b, obs_r = batched.reset(), ref.reset()
    assert isinstance(obs_b, np.ndarray) and isinstance(obs_r, np.ndarray)
    assert obs_b.dtype == obs_r.dtype == np.float32 and obs_b.shape == obs_r.shape
    np.testing.assert_allclose(obs_b, obs_r, rtol=0, atol=TOL)
    assert batched.reset_infos == ref.reset_infos
    rng = np.random.default_rng(seed)
    counts = {"episodes": 0, "collision_steps": 0}
    for t in range(n_steps):
        if t == reset_at:  # mid-episode: every copy restarts, its generator continued
            np.testing.assert_allclose(np.asarray(batched.reset()), np.asarray(ref.reset()), rtol=0, atol=TOL)
        actions = rng.integers(0, 5, size=ref.num_envs)
        o_b, r_b, d_b, i_b = batched.step(actions)
        o_r, r_r, d_r, i_r = ref.step(actions)
        assert isinstance(o_b, np.ndarray) and isinstance(o_r, np.ndarray)
        assert o_b.dtype == o_r.dtype and r_b.dtype == r_r.dtype and d_b.dtype == d_r.dtype
        np.testing.assert_allclose(o_b, o_r, rtol=0, atol=TOL, err_msg=f"observations differ at step {t}")
        np.testing.assert_allclose(r_b, r_r, rtol=0, atol=TOL, err_msg=f"rewards differ at step {t}")
        np.testing.assert_array_equal(d_b, d_r, err_msg=f"dones differ at step {t}")
        for k, (ib, ir) in enumerate(zip(i_b, i_r, strict=True)):
            assert ib.keys() == ir.keys(), f"info keys differ at step {t}, slot {k}: {ib.keys()} != {ir.keys()}"
            if "terminal_observation" in ir:
                tb, tr = ib["terminal_observation"], ir["terminal_observation"]
                assert type(tb) is type(tr) and tb.dtype == tr.dtype and tb.shape == tr.shape
                np.testing.assert_allclose(tb, tr, rtol=0, atol=TOL)
                assert ib["TimeLimit.truncated"] is ir["TimeLimit.truncated"] is True
            if "episode" in ir:
                eb, er = ib["episode"], ir["episode"]
                assert eb.keys() == er.keys() == {"r", "l", "t", *SPREAD_METRICS}
                assert eb["l"] == er["l"] and abs(eb["r"] - er["r"]) <= TOL
                assert {key: eb[key] for key in SPREAD_METRICS} == {key: er[key] for key in SPREAD_METRICS}
                counts["episodes"] += 1
            rest_b = {key: v for key, v in ib.items() if key not in ("terminal_observation", "episode")}
            assert rest_b == {key: v for key, v in ir.items() if key not in ("terminal_observation", "episode")}
        # a collision penalty makes the rewards of one copy's agents differ
        counts["collision_steps"] += int((np.ptp(r_r.reshape(-1, n_agents), axis=1) > 0).any())
        assert batched.reset_infos == ref.reset_infos
    return counts


def _monitor(path: Path) -> tuple[dict[str, Any], list[dict[str, str]]]:
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#")
    return json.loads(lines[0][1:]), list(csv.DictReader(lines[1:]))


CASES = [
    ({}, 4, 250, None),
    ({"N": 2, "local_ratio": 0.2, "max_cycles": 10}, 5, 120, 33),
    ({"N": 4, "local_ratio": 1.0, "max_cycles": 7, "dynamic_rescaling": False}, 3, 100, None),
]


@pytest.mark.parametrize(("env_kwargs", "n_envs", "n_steps", "reset_at"), CASES)
def test_matches_reference_team_vec_env(env_kwargs: dict[str, Any], n_envs: int, n_steps: int,
                                        reset_at: int | None, tmp_path: Path) -> None:
    seed = 17
    batched = make_batched_vec_env(SS, n_envs, seed, env_kwargs, str(tmp_path / "b"))
    ref = reference(n_envs, seed, env_kwargs, str(tmp_path / "r"))
    assert isinstance(batched, BatchedSimpleSpreadVecEnv)
    assert batched.num_envs == ref.num_envs and batched.observation_space == ref.observation_space
    assert batched.action_space == ref.action_space
    counts = _compare(batched, ref, env_kwargs.get("N", 3), n_steps, seed, reset_at)
    max_cycles = env_kwargs.get("max_cycles", 25)
    after_reset = n_steps - (reset_at or 0)
    assert counts["episodes"] == n_envs * (after_reset // max_cycles + (reset_at or 0) // max_cycles)
    assert counts["collision_steps"] > 0 or env_kwargs.get("N") == 2  # two agents rarely meet by chance
    batched.close()
    ref.close()
    (head_b, rows_b), (head_r, rows_r) = _monitor(tmp_path / "b" / "0.monitor.csv"), _monitor(tmp_path / "r" /
                                                                                            "0.monitor.csv")
    assert head_b.keys() == head_r.keys() and head_b["env_id"] == head_r["env_id"] == "simple_spread_v3"
    assert len(rows_b) == len(rows_r) == counts["episodes"] and rows_b[0].keys() == rows_r[0].keys()
    for row_b, row_r in zip(rows_b, rows_r, strict=True):
        assert row_b["l"] == row_r["l"] and abs(float(row_b["r"]) - float(row_r["r"])) <= TOL


def test_seeding_like_reference() -> None:
    n, n_agents = 3, 3
    batched = make_batched_vec_env(SS, n, None, {}, None)
    ref = reference(n, None, {})
    assert batched.seed(123) == ref.seed(123) == [123 + k // n_agents for k in range(n * n_agents)]
    first = np.asarray(batched.reset())
    np.testing.assert_array_equal(first, np.asarray(ref.reset()))
    for i in range(n):  # copy i starts as a lone env reset with seed + i
        alone, _ = mpe2_spread.parallel_env().reset(seed=123 + i)
        np.testing.assert_array_equal(first.reshape(n, n_agents, -1)[i], np.stack(list(alone.values())))
    second = np.asarray(batched.reset())  # no new seed: the generators continue, as the reference's
    np.testing.assert_array_equal(second, np.asarray(ref.reset()))
    assert not np.array_equal(first, second)
    batched.seed(123)
    np.testing.assert_array_equal(np.asarray(batched.reset()), first)  # same seed, same start
    batched.seed(124)
    assert not np.array_equal(np.asarray(batched.reset()), first)
    unseeded = [np.asarray(make_batched_vec_env(SS, 2, None, {}, None).reset()) for _ in range(2)]
    assert not np.array_equal(unseeded[0], unseeded[1])


def test_attributes_methods_and_errors_like_reference() -> None:
    batched = make_batched_vec_env(SS, 2, 5, {"N": 2}, None)
    ref = reference(2, 5, {"N": 2})
    with pytest.raises(RuntimeError, match="reset"):
        batched.step(np.zeros(4, dtype=np.int64))
    batched.reset()
    ref.reset()
    for actions in np.random.default_rng(0).integers(0, 5, size=(6, 4)):
        batched.step(actions)
        ref.step(actions)
    for name in ("possible_agents", "agents", "render_mode", "metadata"):
        assert batched.get_attr(name) == ref.get_attr(name), name
    for index in (0, 3):
        np.testing.assert_array_equal(batched.env_method("state", indices=[index])[0],
                                      ref.env_method("state", indices=[index])[0])
    assert batched.env_is_wrapped(Monitor) == ref.env_is_wrapped(Monitor) == [False] * 4
    assert batched.render_mode is ref.render_mode is None
    for bad in (5, -1):
        actions = np.zeros(4, dtype=np.int64)
        actions[2] = bad
        with pytest.raises(ValueError, match="actions must be"):
            batched.step(actions)


def test_batchable_kwargs() -> None:
    assert batched_env_id("simple_spread_v3", SS) == batched_env_id("parallel_env", f"{SS}:parallel_env") == SS
    assert batched_env_id("simple_spread_v3", "my_pkg.simple_spread_v3") is None
    assert unbatchable_kwargs(SS, {"N": 5, "local_ratio": 0.0, "max_cycles": 50, "continuous_actions": False,
                                   "dynamic_rescaling": True, "render_mode": None}) == []
    bad = {"continuous_actions": True, "render_mode": "rgb_array", "terminate_on_success": True,
           "num_agent_neighbors": 2}
    assert len(unbatchable_kwargs(SS, bad)) == 4
    with pytest.raises(ValueError, match="continuous_actions=True"):
        BatchedSimpleSpreadVecEnv(2, {"continuous_actions": True})
    ref = resolve_env(SS)
    exp = build_experiment(TrainSpec("ppo", SS), ref)
    assert vec_env_kind("auto", exp, ref, {}) == "batched"
    assert vec_env_kind("auto", exp, ref, {"N": 4, "render_mode": None}) == "batched"
    assert vec_env_kind("auto", exp, ref, {"continuous_actions": True}) == "dummy"
    assert vec_env_kind("auto", exp, ref, {"render_mode": "rgb_array"}) == "dummy"
    assert vec_env_kind("subproc", exp, ref, {}) == "subproc"
    with pytest.raises(UsageError, match="got benchmark_data=True"):
        vec_env_kind("batched", exp, ref, {"benchmark_data": True})
    per_agent = build_experiment(TrainSpec("ppo", SS, hyperparams={"policies": "per_agent"}), ref)
    assert vec_env_kind("auto", per_agent, ref, {}) == "dummy"


def _train(*args: str) -> int:
    """``python -m sbagents.train args`` in this process; returns the exit code."""
    main = importlib.import_module("sbagents.train").main
    with pytest.raises(SystemExit) as exit_info:
        run("python -m sbagents.train", lambda: main(list(args)))
    return int(exit_info.value.code or 0)


def test_cli_picks_batched_and_refuses_unbatchable(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    code = _train("--algo", "ppo", "--env", SS, "--vec-env", "batched", "--env-kwargs", "continuous_actions:True",
                  "-f", str(tmp_path / "refused"))
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert "--vec-env batched supports" in err and SS in err and "got continuous_actions=True" in err
    assert not list((tmp_path / "refused").glob("*/*")), "a run dir was left behind"
    built: list[tuple[str, int]] = []
    original = sbagents.batched.make_batched_vec_env

    def spy(env_id: str, n_envs: int, *rest: Any) -> VecEnv:
        built.append((env_id, n_envs))
        return original(env_id, n_envs, *rest)

    monkeypatch.setattr(sbagents.batched, "make_batched_vec_env", spy)
    rows = {}
    for vec_env in ("auto", "dummy"):
        built.clear()
        code = _train("--algo", "ppo", "--env", SS, "--vec-env", vec_env, "-n", "576", "--seed", "3", "--verbose",
                      "0", "--eval-freq", "-1", "--final-eval-episodes", "0", "-f", str(tmp_path / vec_env),
                      "-params", "n_envs:2", "n_steps:48", "batch_size:96", "n_epochs:1",
                      "--env-kwargs", "max_cycles:12")
        assert code == 0, capsys.readouterr().err
        assert ((SS, 2) in built) == (vec_env == "auto"), built  # the training VecEnv (2 copies)
        _, monitor = _monitor(tmp_path / vec_env / "ppo" / "simple_spread_v3_1" / "0.monitor.csv")
        rows[vec_env] = [(row["r"], row["l"]) for row in monitor]
    assert len(rows["auto"]) == 576 // 3 // 12 and rows["auto"] == rows["dummy"]


# ---------------------------------------------------------------------------------------- the single-copy ParallelEnv
@pytest.mark.parametrize("kwargs", [{}, {"N": 2, "local_ratio": 0.2, "max_cycles": 7}])
def test_parallel_env_equals_mpe2_step_for_step(kwargs: dict[str, Any]) -> None:
    from mpe2 import simple_spread_v3

    from sbagents.batched.spread_env import SimpleSpreadParallelEnv

    # mpe2's env as sbagents builds it: under the observer that adds the team metrics at the last step
    ref, fast = spread_metrics_env(simple_spread_v3.parallel_env(**kwargs)), SimpleSpreadParallelEnv(**kwargs)
    rng = np.random.default_rng(0)
    resets: list[tuple[int | None, int]] = [(3, 60), (None, 40), (None, 5), (11, 30), (None, 30)]  # (seed, steps)
    for seed, steps in resets:  # a reset after a full episode, unseeded resets continuing, a reset mid-episode
        got = [fast.reset(seed=seed), ref.reset(seed=seed)]
        assert_same(got[0], got[1])
        for _ in range(steps):
            if not ref.agents:
                assert not fast.agents
                got = [fast.reset(), ref.reset()]
                assert_same(got[0], got[1])
            actions = {a: int(rng.integers(5)) for a in ref.agents}
            assert_same(fast.step(actions), ref.step(actions))
            assert fast.agents == ref.agents
            np.testing.assert_array_equal(fast.state(), ref.state())
    assert fast.state_space == ref.state_space
    assert all(fast.observation_space(a) == ref.observation_space(a) for a in ref.possible_agents)


def assert_same(a: Any, b: Any) -> None:
    """Equal nested tuples/dicts of arrays and numbers, with equal types of the leaves' numbers."""
    if isinstance(a, tuple | list):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same(x, y)
    elif isinstance(a, dict):
        assert list(a) == list(b)
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b and type(a) is type(b), (a, b)


def test_parallel_env_passes_pettingzoo_api_tests() -> None:
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from sbagents.batched.spread_env import SimpleSpreadParallelEnv

    parallel_api_test(SimpleSpreadParallelEnv(), num_cycles=100)
    parallel_seed_test(SimpleSpreadParallelEnv)
