"""Ctrl-C / SIGTERM during learning: the first one stops training between two steps (no file cut short mid-save),
a second one interrupts at once; a signal the process ignores stays ignored."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.core.lifecycle import LearningClock
from sbagents.pipeline.training import StopOnRequestCallback


@pytest.fixture(autouse=True)
def python_sigint_handler() -> Iterator[None]:
    """Python's own Ctrl-C handler for each test: a suite started in the background (``cmd &``) inherits an ignored
    SIGINT, which LearningClock rightly leaves ignored."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_first_signal_requests_a_stop_second_interrupts(sig: signal.Signals) -> None:
    before = signal.getsignal(sig)
    clock = LearningClock(graceful=True)
    with clock:
        os.kill(os.getpid(), sig)
        assert clock.stop_requested
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), sig)
    assert clock.interrupted
    assert signal.getsignal(sig) == before


def test_ignored_signal_stays_ignored() -> None:
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        clock = LearningClock(graceful=True)
        with clock:
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGINT)
        assert not clock.interrupted and not clock.stop_requested
    finally:
        signal.signal(signal.SIGINT, before)


class _SignalThenSave(BaseCallback):
    """At step ``at``: a Ctrl-C arrives, then (in the same step, as EvalCallback's best-model save would) a save."""

    def __init__(self, at: int, path: Path) -> None:
        super().__init__()
        self.at, self.path = at, path

    def _on_step(self) -> bool:
        if self.n_calls == self.at:
            os.kill(os.getpid(), signal.SIGINT)
            self.model.save(self.path)
        return True


def test_learning_stops_after_the_step_and_the_save_completes(tmp_path: Path) -> None:
    model = PPO("MlpPolicy", gym.make("CartPole-v1"), n_steps=64, batch_size=64, seed=0)
    clock = LearningClock(graceful=True)
    with clock:
        model.learn(10_000, callback=[StopOnRequestCallback(clock), _SignalThenSave(100, tmp_path / "mid.zip")])
    assert clock.interrupted
    assert model.num_timesteps == 101  # stopped at the next poll, the step after the signal
    assert PPO.load(tmp_path / "mid.zip").num_timesteps == 100
