"""The user PettingZoo env package ``tests/user_envs/tiny_marl_pkg``: ``relay_v0`` follows the PettingZoo API and
its own rules (scout leaves early, workers truncated, reward = cue match, global state, ``correct`` infos), and
importing the package registers the short name ``relay_v0``.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils import wrappers

from sbagents.registration import PETTINGZOO_ENVS

USER_ENVS = Path(__file__).resolve().parent / "user_envs"
AGENTS = ["scout_0", "worker_0", "worker_1"]

Policy = Callable[[str, np.ndarray], int]


def _forget_package() -> None:
    for name in [m for m in sys.modules if m == "tiny_marl_pkg" or m.startswith("tiny_marl_pkg.")]:
        del sys.modules[name]


@pytest.fixture(scope="module")
def relay() -> Iterator[ModuleType]:
    """``tiny_marl_pkg.relay_v0``, imported with ``tests/user_envs`` on ``sys.path`` for this module only."""
    saved = dict(PETTINGZOO_ENVS)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(USER_ENVS))
        yield importlib.import_module("tiny_marl_pkg.relay_v0")
    _forget_package()
    PETTINGZOO_ENVS.clear()
    PETTINGZOO_ENVS.update(saved)


def oracle(agent: str, obs: np.ndarray) -> int:
    """The optimal action: the index of the cue."""
    return int(np.argmax(obs[:3]))


def contrarian(agent: str, obs: np.ndarray) -> int:
    """Always wrong: the index after the cue."""
    return (oracle(agent, obs) + 1) % 3


def play(env: Any, policy: Policy, seed: int = 0) -> list[tuple[Any, ...]]:
    """Play one episode with ``policy``.

    :return: per step ``(obs_before, actions, obs, rewards, terminations, truncations, infos, agents, state)``.
    """
    obs, _ = env.reset(seed=seed)
    steps: list[tuple[Any, ...]] = []
    while env.agents:
        actions = {a: policy(a, obs[a]) for a in env.agents}
        before = obs
        obs, rewards, terms, truncs, infos = env.step(actions)
        steps.append((before, actions, obs, rewards, terms, truncs, infos, list(env.agents), env.state()))
    return steps


def test_parallel_api_test_passes_without_warnings(relay: ModuleType) -> None:
    par = relay.parallel_env()
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # e.g. "Live agent was not given observation"
        parallel_api_test(par, num_cycles=50)
    assert par.agents == [] and par.steps == par.max_cycles


def test_aec_api_test_passes(relay: ModuleType) -> None:
    aec = relay.env()
    assert isinstance(aec, wrappers.OrderEnforcingWrapper) and isinstance(aec.unwrapped, relay.Relay)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        # heterogeneous observations are the point of this env
        warnings.filterwarnings("ignore", "Agents have different observation space sizes|Observations are different")
        api_test(aec, num_cycles=50)
    assert aec.possible_agents == AGENTS


def test_same_seed_same_episode_other_seed_other_cues(relay: ModuleType) -> None:
    parallel_seed_test(relay.parallel_env)
    first, second, other = (play(relay.parallel_env(), contrarian, seed) for seed in (7, 7, 8))
    assert len(first) == len(second) == 10
    for a, b in zip(first, second, strict=True):
        assert a[1] == b[1] and all(np.array_equal(a[2][k], b[2][k]) for k in a[2])
        assert np.array_equal(a[8], b[8])
    cues = [np.concatenate([s[0][k] for k in s[0]]) for s in first]
    other_cues = [np.concatenate([s[0][k] for k in s[0]]) for s in other]
    assert not all(np.array_equal(x, y) for x, y in zip(cues, other_cues, strict=True))


def test_spaces_are_heterogeneous_observations_and_one_shared_action_space(relay: ModuleType) -> None:
    par = relay.parallel_env()
    assert par.possible_agents == AGENTS
    assert par.observation_space("scout_0") == spaces.Box(0.0, 1.0, (4,), np.float32)
    for worker in AGENTS[1:]:
        assert par.observation_space(worker) == spaces.Box(0.0, 1.0, (3,), np.float32)
    assert all(par.action_space(a) == spaces.Discrete(3) for a in AGENTS)
    assert par.observation_space("worker_0") is par.observation_space("worker_0")
    assert par.state_space == spaces.Box(0.0, 1.0, (10,), np.float32)
    obs, infos = par.reset(seed=3)
    assert set(obs) == set(infos) == set(AGENTS) and par.agents == AGENTS
    for agent in AGENTS:
        assert par.observation_space(agent).contains(obs[agent])
        assert obs[agent][:3].sum() == 1.0  # one-hot cue
    assert obs["scout_0"][3] == 1.0  # full lifetime left
    assert par.metadata["info_metrics"] == {"correct": "sum"} and par.metadata["name"] == "relay_v0"


@pytest.mark.parametrize(("scout_steps", "max_cycles"), [(5, 10), (2, 4), (3, 3)])
def test_scout_terminates_then_is_gone_workers_truncated_at_max_cycles(
    relay: ModuleType, scout_steps: int, max_cycles: int
) -> None:
    steps = play(relay.parallel_env(scout_steps=scout_steps, max_cycles=max_cycles), oracle)
    assert len(steps) == max_cycles
    for t, (_, actions, obs, _, terms, truncs, _, agents, _) in enumerate(steps, start=1):
        assert ("scout_0" in actions) == (t <= scout_steps) and ("scout_0" in obs) == (t <= scout_steps)
        if t <= scout_steps:
            assert terms["scout_0"] == (t == scout_steps) and not truncs["scout_0"]
            assert obs["scout_0"][3] == pytest.approx((scout_steps - t) / scout_steps)
        else:
            assert "scout_0" not in terms and "scout_0" not in truncs
        assert ("scout_0" in agents) == (t < scout_steps)
        for worker in AGENTS[1:]:
            assert not terms[worker] and truncs[worker] == (t == max_cycles)
        assert [a for a in agents if a != "scout_0"] == (AGENTS[1:] if t < max_cycles else [])


@pytest.mark.parametrize(("policy", "expected"), [(oracle, 1), (contrarian, 0)])
def test_reward_and_correct_info_are_the_cue_match(relay: ModuleType, policy: Policy, expected: int) -> None:
    steps = play(relay.parallel_env(), policy)
    returns = dict.fromkeys(AGENTS, 0.0)
    for _, actions, _, rewards, _, _, infos, _, _ in steps:
        assert set(rewards) == set(infos) == set(actions)
        for agent, reward in rewards.items():
            assert reward == float(expected) and infos[agent]["correct"] == expected
            returns[agent] += reward
    assert returns == ({"scout_0": 5.0, "worker_0": 10.0, "worker_1": 10.0} if expected else dict.fromkeys(AGENTS, 0.0))


def test_a_constant_action_is_right_about_a_third_of_the_time(relay: ModuleType) -> None:
    """Cues are uniform: always answering 0 earns ~1/3 of the optimal return (the oracle earns all of it)."""
    par = relay.parallel_env()
    rewards = [r for seed in range(30) for step in play(par, lambda agent, obs: 0, seed) for r in step[3].values()]
    assert len(rewards) == 30 * (5 + 10 + 10)
    assert 0.28 < float(np.mean(rewards)) < 0.39


def test_state_holds_cues_and_step_fraction_and_zeros_once_the_scout_left(relay: ModuleType) -> None:
    par = relay.parallel_env()
    obs, _ = par.reset(seed=5)
    state = par.state()
    assert state.shape == (10,) and par.state_space.contains(state)
    expected = np.concatenate([obs["scout_0"][:3], obs["worker_0"], obs["worker_1"], [0.0]])
    assert np.array_equal(state, expected)
    for t, (_, _, obs, _, _, _, _, agents, state) in enumerate(play(par, oracle, seed=5), start=1):
        assert par.state_space.contains(state) and state[-1] == pytest.approx(t / 10)
        scout_part = obs["scout_0"][:3] if "scout_0" in agents else np.zeros(3)
        assert np.array_equal(state[:3], scout_part)
        for i, worker in enumerate(AGENTS[1:], start=1):
            worker_part = obs[worker] if worker in agents else np.zeros(3)
            assert np.array_equal(state[3 * i : 3 * i + 3], worker_part)
    assert np.array_equal(state[:9], np.zeros(9))


def test_ansi_render_shows_step_cues_and_actions(relay: ModuleType) -> None:
    par = relay.parallel_env(render_mode="ansi")
    obs, _ = par.reset(seed=2)
    cue = oracle("worker_1", obs["worker_1"])
    par.step({a: 2 if a == "worker_1" else 0 for a in par.agents})
    line = par.render()
    assert isinstance(line, str) and "\n" not in line and line.startswith("step 1/10")
    assert f"worker_1 cue={cue} action=2" in line and "scout_0 cue=" in line
    quiet = relay.parallel_env()
    quiet.reset(seed=2)
    assert quiet.render() is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scout_steps": 0}, "scout_steps must be >= 1"),
        ({"scout_steps": 6, "max_cycles": 5}, "max_cycles must be >= scout_steps"),
        ({"render_mode": "human"}, "render_mode must be"),
    ],
)
def test_bad_kwargs_raise_value_error(relay: ModuleType, kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        relay.parallel_env(**kwargs)


def test_unknown_kwarg_is_a_type_error_naming_the_accepted_ones(relay: ModuleType) -> None:
    with pytest.raises(TypeError, match="max_cycle.*accepted: scout_steps, max_cycles, render_mode"):
        relay.parallel_env(max_cycle=3)
    with pytest.raises(TypeError, match="unknown keyword"):
        relay.env(n_agents=2)


def test_step_rejects_missing_invalid_and_late_actions(relay: ModuleType) -> None:
    par = relay.parallel_env(scout_steps=1, max_cycles=1)
    with pytest.raises(RuntimeError, match="reset"):
        par.step(dict.fromkeys(AGENTS, 0))
    par.reset(seed=0)
    with pytest.raises(ValueError, match="one action for each live agent"):
        par.step({"scout_0": 0, "worker_0": 0})
    with pytest.raises(ValueError, match="invalid action 3 for worker_1"):
        par.step({"scout_0": 0, "worker_0": 0, "worker_1": 3})
    par.step(dict.fromkeys(AGENTS, 0))
    assert par.agents == []
    with pytest.raises(RuntimeError, match="no live agents"):
        par.step({})


def test_importing_the_package_registers_relay_v0_without_importing_the_env(
    relay: ModuleType, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in ("tiny_marl_pkg", "tiny_marl_pkg.relay_v0"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    monkeypatch.delitem(PETTINGZOO_ENVS, "relay_v0", raising=False)
    importlib.import_module("tiny_marl_pkg")
    assert PETTINGZOO_ENVS["relay_v0"] == "tiny_marl_pkg.relay_v0"
    assert "tiny_marl_pkg.relay_v0" not in sys.modules
    built = importlib.import_module(PETTINGZOO_ENVS["relay_v0"]).parallel_env()
    assert type(built).__name__ == "Relay" and built.metadata["name"] == "relay_v0"
