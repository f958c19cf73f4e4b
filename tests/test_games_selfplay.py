"""Turn-based games from one seat: the self-play env against the AEC game, opponents, pools, matches, Elo."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.classic import connect_four_v3, tictactoe_v3
from sb3_contrib import MaskablePPO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sbagents.core.selfplay_options import SelfPlayOptions
from sbagents.errors import UsageError
from sbagents.games.elo import fit_elo
from sbagents.games.matches import match_summary, play_games
from sbagents.games.players import RandomPlayer, load_player
from sbagents.games.pool import OpponentPool, SnapshotCallback, snapshots
from sbagents.games.selfplay import SelfPlayEnv, make_selfplay_env

C4 = "pettingzoo.classic.connect_four_v3"
TTT = "pettingzoo.classic.tictactoe_v3"
HOLDEM = "pettingzoo.classic.texas_holdem_v4"


@pytest.mark.parametrize("source", [C4, TTT, HOLDEM])
def test_selfplay_env_passes_gymnasium_and_sb3_checks(source: str) -> None:
    check_env(make_selfplay_env(source), skip_render_check=True)
    sb3_check_env(make_selfplay_env(source), warn=False)


def first_legal(observation: np.ndarray, action_mask: np.ndarray) -> int:
    return int(np.flatnonzero(action_mask)[0])


def test_learner_move_then_opponent_reply_match_the_aec_game() -> None:
    """One learner step is its move plus the opponent's reply; the observation is the learner's view."""
    env = SelfPlayEnv(connect_four_v3.env, opponent=first_legal, seat=0, name="connect_four_v3")
    obs, info = env.reset(seed=3)
    assert info["seat"] == 0 and obs.shape == (6, 7, 2) and obs.dtype == np.float32 and obs.sum() == 0
    obs, reward, terminated, truncated, _ = env.step(3)
    reference = connect_four_v3.env()
    reference.reset()
    reference.step(3)
    reference.step(0)  # the opponent's first legal column
    expected = reference.observe(reference.agent_selection)["observation"]
    np.testing.assert_array_equal(obs, expected)
    assert obs[5, 3, 0] == 1 and obs[5, 0, 1] == 1 and reward == 0 and not terminated and not truncated
    np.testing.assert_array_equal(env.action_masks(), np.ones(7, bool))


def test_win_loss_rewards_outcomes_and_seat_alternation() -> None:
    env = SelfPlayEnv(connect_four_v3.env, opponent=first_legal, name="connect_four_v3")
    seats, outcomes = [], []
    env.reset(seed=0)
    for _ in range(4):
        done, total = False, 0.0
        while not done:  # the learner stacks column 6, the opponent column 0 (or 1): someone wins vertically
            _, reward, terminated, truncated, info = env.step(6)
            total += reward
            done = terminated or truncated
        assert info["game_outcome"] == np.sign(total) == np.sign(info["game_return"])
        assert info["is_success"] == (total > 0) and info["illegal_moves"] == 0
        seats.append(info["seat"])
        outcomes.append(info["game_outcome"])
        env.reset()
    assert sorted(set(seats)) == [0, 1] and seats[0] != seats[1]  # the learner plays first and second
    assert outcomes[seats.index(0)] == 1 and outcomes[seats.index(1)] == -1  # the first to stack four wins


def test_illegal_moves_are_counted_and_lose() -> None:
    env = SelfPlayEnv(tictactoe_v3.env, opponent=first_legal, seat=1, name="tictactoe_v3")
    env.reset(seed=0)
    occupied = int(np.flatnonzero(~env.action_masks())[0])  # the opponent's opening cell
    _, reward, terminated, _, info = env.step(occupied)
    assert info["illegal_moves"] == 1 and env.illegal_moves == 1 and terminated and reward == -1


def test_unplayed_poker_hands_are_reported_at_reset() -> None:
    """A hand the opponent folds before the learner acts is skipped for training but reported for matches."""
    def fold_first(obs: np.ndarray, mask: np.ndarray) -> int:
        return 2 if mask[2] else int(np.flatnonzero(mask)[0])  # texas hold'em action 2: fold

    env = make_selfplay_env(HOLDEM, opponent=fold_first, seat=1)
    unplayed = [game for k in range(20) for game in env.reset(seed=k)[1]["unplayed_games"]]
    assert len(unplayed) >= 5 and all(seat == 1 and reward > 0 for seat, reward in unplayed)


def test_seeded_resets_repeat_games() -> None:
    def play(seed: int) -> list[float]:
        env = make_selfplay_env(C4, opponent="random")
        env.reset(seed=seed)
        rng, trace = np.random.default_rng(1), []
        for _ in range(60):
            obs, reward, terminated, truncated, _ = env.step(rng.choice(np.flatnonzero(env.action_masks())))
            trace.append(float(obs.sum()) + reward)
            if terminated or truncated:
                env.reset()
        return trace

    assert play(5) == play(5) and play(5) != play(6)


def test_match_summary_counts_seats_and_rates() -> None:
    env = make_selfplay_env(TTT, opponent="minimax")
    result = play_games(env, RandomPlayer(np.random.default_rng(0)), 40, seed=0)
    summary = match_summary(result, "tictactoe_v3", "random", "minimax")
    assert summary["n_games"] == 40 and summary["win_rate"] == 0  # nobody beats perfect play
    assert summary["draw_rate"] + summary["loss_rate"] == pytest.approx(1)
    assert {s: v["n_games"] for s, v in summary["per_seat"].items()} == {"player_1": 20, "player_2": 20}
    assert summary["illegal_moves"] == 0 and summary["opponent_illegal_moves"] == 0
    lo, hi = summary["reward_ci95"]
    assert lo < summary["mean_reward"] < hi


def test_load_player_specs_and_errors(tmp_path: Path) -> None:
    mask = np.array([0, 1, 1, 0, 0, 0, 0, 0, 0], np.int8)
    obs = np.zeros((3, 3, 2), np.int8)
    for spec in ("random", "minimax", "tests.user_envs.game_players:lowest_legal"):
        assert mask[load_player(spec, "tictactoe_v3", np.random.default_rng(0))(obs, mask)] == 1
    assert load_player("tests.user_envs.game_players:lowest_legal", "tictactoe_v3")(obs, mask) == 1
    bad = {"heuristic": "no built-in 'heuristic' opponent for tictactoe_v3", "nothing": "is not an opponent",
           str(tmp_path / "missing.zip"): "no such model file", "tests.user_envs.game_players:nope": "cannot import",
           str(tmp_path): "no model zip"}
    for spec, message in bad.items():
        with pytest.raises(UsageError, match=message):
            load_player(spec, "tictactoe_v3")
    for spec in ("heuristic", "minimax", "opportunist"):  # two-seat built-ins in a three-seat game
        with pytest.raises(UsageError, match=f"the {spec} opponent plays two-seat games.*has 3 seats"):
            load_player(spec, "texas_holdem_v4", n_seats=3)
    assert load_player("random", "texas_holdem_v4", np.random.default_rng(0), n_seats=3)(obs, mask) in (1, 2)


def test_snapshot_pool_draws_latest_uniform_and_mixed(tmp_path: Path) -> None:
    env = make_selfplay_env(TTT)
    model = MaskablePPO("MlpPolicy", env, n_steps=64, batch_size=64, seed=0)
    pool_dir = tmp_path / "opponents"
    callback = SnapshotCallback(pool_dir, snapshot_freq=64)
    model.learn(192, callback=callback)
    steps = [s for s, _ in snapshots(pool_dir)]
    assert steps[0] == 0 and steps == sorted(steps) and len(steps) >= 3
    assert not list(pool_dir.glob(".partial*"))
    rng = np.random.default_rng(0)
    latest = OpponentPool(pool_dir, SelfPlayOptions(opponents="latest"), "tictactoe_v3")
    assert len({id(latest.draw(rng).model) for _ in range(10)}) == 1  # type: ignore[attr-defined]
    uniform = OpponentPool(pool_dir, SelfPlayOptions(opponents="uniform", last_k=2), "tictactoe_v3")
    assert len({id(uniform.draw(rng).model) for _ in range(30)}) == 2  # type: ignore[attr-defined]
    mixed = OpponentPool(pool_dir, SelfPlayOptions(mix={"minimax": 0.5}), "tictactoe_v3")
    kinds = [type(mixed.draw(rng)).__name__ for _ in range(400)]
    assert 0.4 < kinds.count("BuiltinPlayer") / 400 < 0.6 and set(kinds) == {"BuiltinPlayer", "ModelPlayer"}
    empty = OpponentPool(tmp_path / "none", SelfPlayOptions(), "tictactoe_v3")
    assert isinstance(empty.draw(rng), RandomPlayer)


@pytest.mark.parametrize("bad", [{"opponents": "best"}, {"last_k": 0}, {"mix": {"random": 0.7, "minimax": 0.6}},
                                 {"mix": [1]}, {"colour": 1}, {"elo_games": -1}])
def test_self_play_options_refuse_bad_values(bad: dict[str, object]) -> None:
    with pytest.raises(UsageError, match="self_play"):
        SelfPlayOptions.from_mapping(bad)


def test_fit_elo_orders_players_and_anchors_random() -> None:
    scores = {("a", "random"): (9.0, 10), ("b", "random"): (6.0, 10), ("a", "b"): (7.0, 10)}
    ratings = fit_elo(scores)
    assert ratings["random"] == 0 and ratings["a"] > ratings["b"] > 0
    even = fit_elo({("a", "random"): (5.0, 10)})
    assert abs(even["a"]) < 1e-6
    perfect = fit_elo({("a", "random"): (100.0, 100)})
    assert 400 < perfect["a"] < 2000  # finite: one virtual draw per pairing


@pytest.mark.parametrize("activation", ["tanh", "relu"])
def test_numpy_actor_matches_the_torch_policy(activation: str) -> None:
    import torch as th

    from sbagents.core.experiment import ACTIVATIONS
    from sbagents.games.numpy_policy import numpy_actor

    env = make_selfplay_env(C4, opponent="random")
    model = MaskablePPO("MlpPolicy", env, seed=0, policy_kwargs={"net_arch": [32, 16],
                                                                 "activation_fn": ACTIVATIONS[activation]})
    actor = numpy_actor(model.policy)
    assert actor is not None
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(40):
        mask = env.action_masks()
        dist = model.policy.get_distribution(th.as_tensor(obs[None]), action_masks=mask[None])
        assert isinstance(dist.distribution, th.distributions.Categorical)
        expected = dist.distribution.probs.detach().numpy()[0]
        logits = np.where(mask, actor.logits(obs), -np.inf)
        probs = np.exp(logits - logits.max())
        np.testing.assert_allclose(probs / probs.sum(), expected, atol=1e-5)
        greedy = actor.act(obs, mask, True, rng)
        assert greedy == int(model.predict(obs[None], action_masks=mask[None], deterministic=True)[0][0])
        obs, _, terminated, truncated, _ = env.step(actor.act(obs, mask, False, rng))
        if terminated or truncated:
            obs, _ = env.reset()
    samples = [actor.act(obs, env.action_masks(), False, rng) for _ in range(300)]
    assert all(env.action_masks()[a] for a in samples) and len(set(samples)) > 1


def test_numpy_actor_declines_other_architectures() -> None:
    from sbagents.games.numpy_policy import numpy_actor

    env = make_selfplay_env(TTT)
    model = MaskablePPO("MlpPolicy", env, seed=0, policy_kwargs={"net_arch": [8],
                                                                 "activation_fn": __import__("torch").nn.GELU})
    assert numpy_actor(model.policy) is None
