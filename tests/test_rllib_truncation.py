"""RLlib's multi-agent episodes keep time-limit truncation apart from termination (:mod:`sbagents.rllib.truncation`).

The user package's relay_v0 terminates its scout after 5 steps and truncates the workers after 10. An env runner of
the RLlib backend, built from the backend's own config and run in this process (no Ray instance), must hand the
learner a terminated scout and truncated, not terminated, workers: only then does PPO bootstrap ``V(s_T)``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import pytest

from sbagents.rllib import ray_available

pytestmark = pytest.mark.skipif(
    not ray_available() and not os.environ.get("SBAGENTS_REQUIRE_RAY"),
    reason="needs Ray RLlib: pip install -e '.[test,distributed]' (.ci/run runs these in a venv of their own)",
)
USER_ENVS = Path(__file__).resolve().parent / "user_envs"


@pytest.fixture
def relay_config(monkeypatch: pytest.MonkeyPatch) -> Any:
    """The RLlib backend's PPO config for tiny_marl_pkg.relay_v0 (one module per group), sampling in-process."""
    monkeypatch.syspath_prepend(str(USER_ENVS))
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import TrainSpec
    from sbagents.rllib.experiment import build_config, build_experiment

    ref = resolve_env("tiny_marl_pkg.relay_v0")
    experiment = build_experiment(TrainSpec("ppo", ref.env_id, 1000, {"policies": "per_group"}), ref)
    config, _ = build_config(experiment, ref, seed=0)
    yield config.copy(copy_frozen=False).env_runners(num_env_runners=0, num_envs_per_env_runner=1)
    for name in [m for m in sys.modules if m.startswith("tiny_marl_pkg")]:
        del sys.modules[name]


def _episode_flags(config: Any, episodes: int = 2) -> list[dict[str, tuple[bool, bool, int]]]:
    """Agent -> (is_terminated, is_truncated, length) of every sampled episode, with random actions."""
    from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner

    runner = MultiAgentEnvRunner(config=config)
    try:
        sampled = runner.sample(num_episodes=episodes, random_actions=True)
    finally:
        runner.stop()
    return [{a: (e.is_terminated, e.is_truncated, len(e)) for a, e in ep.agent_episodes.items()} for ep in sampled]


def test_backend_keeps_truncated_agents_truncated(relay_config: Any) -> None:
    flags = _episode_flags(relay_config)
    assert len(flags) == 2
    for episode in flags:
        assert episode == {"scout_0": (True, False, 5), "worker_0": (False, True, 10), "worker_1": (False, True, 10)}


def test_rllib_alone_marks_truncated_agents_terminated(relay_config: Any) -> None:
    """What the fix is for: without the callback, RLlib (2.60) marks the truncated workers terminated as well. If
    this test fails after a Ray upgrade, RLlib fixed it and :mod:`sbagents.rllib.truncation` may go."""
    for episode in _episode_flags(relay_config.callbacks(on_sample_end=None)):
        assert episode["worker_0"][:2] == episode["worker_1"][:2] == (True, True)
        assert episode["scout_0"][:2] == (True, False)


class _BothFlags:
    """A parallel env whose only agent is reported terminated and truncated at its first step."""

    possible_agents = agents = ["a"]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        return {"a": 0}, {"a": {}}

    def step(self, actions: dict[str, Any]) -> Any:
        return {"a": 1}, {"a": 0.0}, {"a": True}, {"a": True}, {"a": {}}

    def observation_space(self, agent: str) -> Any:
        from gymnasium import spaces

        return spaces.Discrete(2)

    action_space = observation_space


def test_env_wrapper_lets_termination_win() -> None:
    from sbagents.rllib.truncation import PettingZooEnv

    env = PettingZooEnv(_BothFlags())
    _, _, terminateds, truncateds, _ = env.step({"a": 0})
    assert terminateds == {"a": True, "__all__": True} and truncateds == {"a": False, "__all__": False}
