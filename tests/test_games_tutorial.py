"""PettingZoo's SB3 action-mask tutorial rebuilt (benchmarks/learning/games_tutorial.py): the wrapper's semantics, the
reward-perspective flaw, and a short training run of the recipe usable by our game players."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from sb3_contrib import MaskablePPO

from benchmarks.learning.games_tutorial import (
    TUTORIAL_STEPS,
    FixedSB3ActionMaskWrapper,
    SB3ActionMaskWrapper,
    eval_tutorial_recipe,
    make_game,
    make_tutorial_env,
    train_tutorial_recipe,
)
from sbagents.games.players import ModelPlayer

C4 = "pettingzoo.classic.connect_four_v3"
TTT = "pettingzoo.classic.tictactoe_v3"
# player_0 stacks column 0 four times while player_1 plays column 1: player_0 wins on the 7th move.
P0_WINS = [0, 1, 0, 1, 0, 1, 0]
# player_0 plays columns 0, 2, 4, 6 (no line); player_1 stacks column 1: player_1 wins on the 8th move.
P1_WINS = [0, 1, 2, 1, 4, 1, 6, 1]


def _play(variant: str, moves: list[int]) -> tuple[list[tuple[float, bool, bool]], dict[str, float]]:
    env = make_tutorial_env(C4, variant=variant)
    env.reset(seed=0)
    outcomes = [tuple(env.step(move)[1:4]) for move in moves]
    return outcomes, dict(env.unwrapped.rewards)  # type: ignore[attr-defined]


def test_constants_and_spaces() -> None:
    assert TUTORIAL_STEPS == 20_480
    env = make_tutorial_env(C4)
    wrapper = env.env
    assert type(wrapper) is SB3ActionMaskWrapper
    assert type(make_tutorial_env(C4, variant="fixed").env) is FixedSB3ActionMaskWrapper
    game = make_game(C4)
    assert env.observation_space == game.observation_space("player_0")["observation"]
    assert env.observation_space.dtype == np.int8 and env.observation_space.shape == (6, 7, 2)
    assert env.action_space == game.action_space("player_0")
    for module in (TTT, "pettingzoo.classic.texas_holdem_v4"):
        other = make_tutorial_env(module)
        obs, info = other.reset(seed=1)
        assert info == {} and other.observation_space.contains(obs)
        assert other.action_masks().shape == (other.action_space.n,)
    with pytest.raises(ValueError, match="variant"):
        make_tutorial_env(C4, variant="nope")  # type: ignore[arg-type]


@pytest.mark.parametrize("variant", ["original", "fixed"])
def test_reset_and_step_show_the_agent_to_move(variant: str) -> None:
    """reset/step return the observation (mask stripped) of the agent to move; masks are its AEC masks."""
    env = make_tutorial_env(C4, variant=variant)
    wrapper, game = env.env, make_game(C4)
    rng = np.random.default_rng(3)
    for episode in range(3):
        obs, info = env.reset(seed=episode)
        game.reset(seed=episode)
        assert info == {}
        done = False
        while not done:
            seen = game.observe(game.agent_selection)
            assert wrapper.agent_selection == game.agent_selection
            np.testing.assert_array_equal(obs, seen["observation"])
            np.testing.assert_array_equal(env.action_masks(), seen["action_mask"])
            mover = game.agent_selection
            move = int(rng.choice(np.flatnonzero(seen["action_mask"])))
            obs, reward, terminated, truncated, _ = env.step(move)
            game.step(move)
            assert game.agent_selection != mover  # the returned observation is the other seat's view
            np.testing.assert_array_equal(obs, game.observe(game.agent_selection)["observation"])
            done = terminated or truncated
        assert all(game.terminations.values())


def test_original_step_scores_the_winning_move_with_the_opponents_reward() -> None:
    """The flaw: after the learner's move SB3 sees the NEXT agent's reward, so a winning move is scored -1."""
    outcomes, rewards = _play("original", P0_WINS)
    assert rewards == {"player_0": 1, "player_1": -1}  # player_0 won with the last move ...
    assert outcomes[-1] == (-1, True, False)  # ... and SB3 scores that move -1 (player_1's reward)
    assert all(o == (0, False, False) for o in outcomes[:-1])
    # whoever wins, the episode's return is -1: SB3 cannot tell a win from a loss
    outcomes, rewards = _play("original", P1_WINS)
    assert rewards == {"player_0": -1, "player_1": 1}
    assert sum(r for r, _, _ in outcomes) == -1 and outcomes[-1][1]


def test_fixed_step_scores_the_winning_move_but_never_the_loss() -> None:
    """PettingZoo PR #1203: the winning move is scored +1, yet every decisive game has return +1, and the loser's
    last move 0."""
    for moves in (P0_WINS, P1_WINS):
        outcomes, rewards = _play("fixed", moves)
        assert sorted(rewards.values()) == [-1, 1]
        assert outcomes[-1] == (1, True, False)
        assert outcomes[-2] == (0, False, False)
        assert sum(r for r, _, _ in outcomes) == 1


@pytest.fixture(scope="module")
def ttt_model() -> MaskablePPO:
    return train_tutorial_recipe(TTT, steps=512, seed=0)


def _positions(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` tic-tac-toe positions (observation of the seat to move, mask) from random play."""
    game, rng, out = make_game(TTT), np.random.default_rng(seed), []
    while len(out) < n:
        game.reset(seed=int(rng.integers(1000)))
        for _ in range(int(rng.integers(0, 7))):
            mask = game.observe(game.agent_selection)["action_mask"]
            game.step(int(rng.choice(np.flatnonzero(mask))))
            if any(game.terminations.values()):
                break
        if not any(game.terminations.values()):
            seen = game.observe(game.agent_selection)
            out.append((seen["observation"], seen["action_mask"]))
    return out


def test_recipe_trains_a_model_our_players_can_use(ttt_model: MaskablePPO) -> None:
    assert isinstance(ttt_model, MaskablePPO)
    assert ttt_model.num_timesteps >= 512
    assert ttt_model.observation_space.dtype == np.int8 and ttt_model.observation_space.shape == (3, 3, 2)
    assert torch.get_num_threads() == 1
    player = ModelPlayer(ttt_model, deterministic=True)
    assert player.masked
    for obs, mask in _positions(8, seed=0):
        action = player(obs, mask)  # float32 batch of the int8 observation
        assert mask[action] == 1
        native, _ = ttt_model.predict(obs, action_masks=mask, deterministic=True)  # the tutorial's own call
        assert int(native) == action
        # only the illegal moves are masked: a single legal move is always chosen
        only = np.zeros_like(mask)
        only[np.flatnonzero(mask)[-1]] = 1
        assert player(obs, only) == int(np.flatnonzero(mask)[-1])


def test_recipe_is_deterministic_for_a_seed(ttt_model: MaskablePPO) -> None:
    again = train_tutorial_recipe(TTT, steps=512, seed=0)
    other = train_tutorial_recipe(TTT, steps=512, seed=1)
    params = [p.detach() for p in ttt_model.policy.parameters()]
    for a, b in zip(params, again.policy.parameters(), strict=True):
        assert torch.equal(a, b.detach())
    assert not all(torch.equal(a, b.detach()) for a, b in zip(params, other.policy.parameters(), strict=True))
    positions = _positions(6, seed=1)
    first = [ModelPlayer(ttt_model, True)(obs, mask) for obs, mask in positions]
    assert first == [ModelPlayer(again, True)(obs, mask) for obs, mask in positions]


def test_tutorial_evaluation_counts_every_game(ttt_model: MaskablePPO) -> None:
    result = eval_tutorial_recipe(ttt_model, TTT, num_games=6)
    assert result["wins"] + result["draws"] + result["losses"] == result["n_games"] == 6
    decisive = sum(result["scores"].values())
    assert decisive == result["wins"] + result["losses"]
    assert result["winrate"] == (result["wins"] / decisive if decisive else 0.0)
    assert result == eval_tutorial_recipe(ttt_model, TTT, num_games=6)  # seeded games
