"""The faster connect four is PettingZoo's connect four, step for step."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.classic import connect_four_v3
from pettingzoo.test import api_test

from sbagents.games import fast_connect_four
from sbagents.games.aec import make_game
from sbagents.games.selfplay import make_selfplay_env


def trace(env: object, seed: int, n_games: int, illegal_every: int = 0) -> list[object]:
    """Everything observable of ``n_games`` random games (an illegal move every ``illegal_every`` games)."""
    rng, out = np.random.default_rng(seed), []
    for game in range(n_games):
        env.reset(seed=game)  # type: ignore[attr-defined]
        for moves, agent in enumerate(env.agent_iter()):  # type: ignore[attr-defined]
            obs, reward, terminated, truncated, _ = env.last()  # type: ignore[attr-defined]
            out.append((agent, obs["observation"].tobytes(), obs["action_mask"].tobytes(), reward, terminated,
                        truncated, dict(env.rewards)))  # type: ignore[attr-defined]
            if terminated or truncated:
                action = None
            elif illegal_every and game % illegal_every == 0 and moves == 9:
                action = int(np.flatnonzero(obs["action_mask"] == 0)[0]) if not obs["action_mask"].all() else 0
            else:
                action = int(rng.choice(np.flatnonzero(obs["action_mask"])))
            env.step(action)  # type: ignore[attr-defined]
    return out


def test_random_games_are_identical() -> None:
    reference, fast = connect_four_v3.env(), fast_connect_four.env()
    assert trace(fast, 0, 300, illegal_every=7) == trace(reference, 0, 300, illegal_every=7)


def test_fast_env_passes_pettingzoo_api_test() -> None:
    api_test(fast_connect_four.env(), num_cycles=200)


def test_make_game_uses_it_unless_asked_not_to(monkeypatch: pytest.MonkeyPatch) -> None:
    assert isinstance(make_game("pettingzoo.classic.connect_four_v3").unwrapped, fast_connect_four.FastConnectFourRaw)
    monkeypatch.setenv("SBAGENTS_REFERENCE_GAMES", "1")
    assert not isinstance(make_game("pettingzoo.classic.connect_four_v3").unwrapped,
                          fast_connect_four.FastConnectFourRaw)


def test_self_play_runs_are_identical_on_both(monkeypatch: pytest.MonkeyPatch) -> None:
    def play() -> list[float]:
        env = make_selfplay_env("pettingzoo.classic.connect_four_v3", opponent="heuristic")
        env.reset(seed=3)
        rng, out = np.random.default_rng(0), []
        for _ in range(400):
            obs, reward, terminated, truncated, _ = env.step(rng.choice(np.flatnonzero(env.action_masks())))
            out.append(float(obs.sum()) * 10 + reward)
            if terminated or truncated:
                env.reset()
        return out

    fast = play()
    monkeypatch.setenv("SBAGENTS_REFERENCE_GAMES", "1")
    assert play() == fast
