"""Turn-based games through the CLIs: self-play training, evaluate --opponent, ratings, and one-line errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cli, last_json, summary

TTT = "pettingzoo.classic.tictactoe_v3"
SMALL = ["n_envs:2", "n_steps:256", "batch_size:256",
         "self_play:{snapshot_freq: 512, elo_games: 6, elo_freq: 1024, eval_opponent: minimax, "
         "mix: {random: 0.3, minimax: 0.2}}"]


@pytest.fixture(scope="module")
def ttt_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    logs = tmp_path_factory.mktemp("games")
    """One small self-play run (plumbing, not learning) that the tests below only read."""
    done = cli("train", "--algo", "ppo_mask", "--env", TTT, "-n", "2048", "-f", str(logs), "--seed", "1",
               "--eval-freq", "1024", "--eval-episodes", "4", "-params", *SMALL)
    assert done.returncode == 0, done.stderr
    return logs


def run_dir(logs: Path) -> Path:
    return logs / "ppo_mask" / "tictactoe_v3_1"


def test_self_play_run_writes_pool_ratings_and_best_model(ttt_run: Path) -> None:
    rd = run_dir(ttt_run)
    steps = sorted(int(p.stem.split("_")[1]) for p in (rd / "opponents").glob("snapshot_*.zip"))
    assert steps[0] == 0 and len(steps) >= 4  # the start, every 512 steps, and each rating round
    for name in ("best_model.zip", "elo.png", "evaluations.npz", "tictactoe_v3.zip"):
        assert (rd / name).is_file(), name
    rows = list(csv.DictReader((rd / "elo.csv").open()))
    players = {r["player"]: r for r in rows}
    assert {"random", "minimax", "step_1024", "step_2048"} <= set(players)
    assert float(players["random"]["elo"]) == 0 and float(players["minimax"]["elo"]) > 0
    assert all(int(r["games"]) > 0 for r in rows)
    best = max((r for r in rows if r["player"].startswith("step_")), key=lambda r: float(r["elo"]))
    best_snapshot = rd / "opponents" / f"snapshot_{best['timesteps']}.zip"
    assert (rd / "best_model.zip").read_bytes() == best_snapshot.read_bytes()
    assert summary(rd)["illegal_moves"] == 0  # masks drove every training move
    final = summary(rd)["eval"]
    assert final["opponent"] == "minimax" and final["illegal_moves"] == 0 and final["win_rate"] == 0
    assert final["draw_rate"] + final["loss_rate"] == pytest.approx(1)


def evaluate(logs: Path, *args: str) -> dict[str, object]:
    done = cli("evaluate", "--algo", "ppo_mask", "--env", TTT, "-f", str(logs), "--json", *args)
    assert done.returncode == 0, done.stderr
    return last_json(done.stdout)


def test_evaluate_against_each_kind_of_opponent(ttt_run: Path) -> None:
    rd = run_dir(ttt_run)
    specs = ["random", "minimax", str(rd), str(rd / "opponents" / "snapshot_0.zip"),
             "tests.user_envs.game_players:lowest_legal"]
    for spec in specs:
        result = evaluate(ttt_run, "--opponent", spec, "-n", "30")
        assert result["opponent"] == spec and result["n_games"] == 30 and result["illegal_moves"] == 0
        rates = [result["win_rate"], result["draw_rate"], result["loss_rate"]]
        assert sum(rates) == pytest.approx(1)  # type: ignore[arg-type]
        per_seat = result["per_seat"]
        assert isinstance(per_seat, dict) and [v["n_games"] for v in per_seat.values()] == [15, 15]
    again = evaluate(ttt_run, "--opponent", "random", "-n", "30")
    assert again == evaluate(ttt_run, "--opponent", "random", "-n", "30")  # seeded


def test_evaluate_table_shows_the_match(ttt_run: Path) -> None:
    done = cli("evaluate", "--algo", "ppo_mask", "--env", TTT, "-f", str(ttt_run), "-n", "10")
    assert done.returncode == 0 and "win_rate" in done.stdout and "player_1.win/draw/loss" in done.stdout


@pytest.mark.parametrize(("args", "message"), [
    (["train", "--algo", "ppo_mask", "--env", "GridWorld-v0"], "ppo_mask acts with action masks"),
    (["train", "--algo", "ppo", "--env", TTT], "trains with ppo_mask"),
    (["train", "--algo", "ppo_mask", "--env", "tests.user_envs.unmasked_game"], "without action masks"),
    (["train", "--algo", "ppo_mask", "--env", TTT, "-params", "self_play:{mix: {heuristic: 0.5}}"],
     "no built-in 'heuristic' opponent for tictactoe_v3"),
    (["train", "--algo", "ppo_mask", "--env", TTT, "-params", "self_play:{opponents: best}"],
     "self_play.opponents must be one of"),
    (["train", "--algo", "ppo", "--env", "GridWorld-v0", "-params", "self_play:{last_k: 3}"],
     "turn-based games only"),
    (["train", "--algo", "ppo_mask", "--env", TTT, "--backend", "rllib"], "trains with --backend sb3"),
])
def test_bad_game_training_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    done = cli(*args, "-f", str(tmp_path), "-n", "64")
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not any((tmp_path / "ppo_mask").glob("*")) if (tmp_path / "ppo_mask").exists() else True


@pytest.mark.parametrize(("opponent", "message"), [
    ("heuristic", "no built-in 'heuristic' opponent"),
    ("nobody", "is not an opponent"),
    ("missing.zip", "no such model file"),
    ("tests.user_envs.game_players:missing", "cannot import"),
])
def test_bad_opponent_is_one_line(ttt_run: Path, opponent: str, message: str) -> None:
    done = cli("evaluate", "--algo", "ppo_mask", "--env", TTT, "-f", str(ttt_run), "--opponent", opponent)
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_opponent_of_another_game_is_refused(ttt_run: Path, tmp_path: Path) -> None:
    c4 = cli("train", "--algo", "ppo_mask", "--env", "pettingzoo.classic.connect_four_v3", "-n", "256", "-f",
             str(tmp_path), "--eval-freq", "0", "--final-eval-episodes", "0", "-params", "n_envs:1", "n_steps:256",
             "batch_size:64")
    assert c4.returncode == 0, c4.stderr
    other = tmp_path / "ppo_mask" / "connect_four_v3_1"
    done = cli("evaluate", "--algo", "ppo_mask", "--env", TTT, "-f", str(ttt_run), "--opponent", str(other))
    assert done.returncode == 2 and "observes shape (6, 7, 2)" in done.stderr


def test_opponent_on_a_non_game_run_is_refused(tmp_path: Path) -> None:
    done = cli("train", "--algo", "qlearning", "--env", "GridWorld-v0", "-n", "200", "-f", str(tmp_path),
               "--eval-freq", "0")
    assert done.returncode == 0, done.stderr
    done = cli("evaluate", "--algo", "qlearning", "--env", "GridWorld-v0", "-f", str(tmp_path), "--opponent",
               "random")
    assert done.returncode == 2 and "--opponent applies to turn-based games" in done.stderr


def test_export_refuses_masked_game_policies(ttt_run: Path) -> None:
    done = cli("export", "--algo", "ppo_mask", "--env", TTT, "-f", str(ttt_run))
    assert done.returncode == 2 and "needs the action mask as an input" in done.stderr
    assert not (run_dir(ttt_run) / "export").exists()


@pytest.mark.parametrize(("module", "args", "message"), [
    ("record_video", [], "record_video does not record turn-based games"),
    ("evaluate", ["--render"], "--render does not draw turn-based games"),
])
def test_unsupported_game_commands_point_to_play(ttt_run: Path, module: str, args: list[str], message: str) -> None:
    done = cli(module, "--algo", "ppo_mask", "--env", TTT, "-f", str(ttt_run), *args)
    assert done.returncode == 2 and message in done.stderr and "sbagents.play" in done.stderr


@pytest.mark.slow  # learning (~14 s here)
def test_users_own_masked_game_trains_and_is_measured(tmp_path: Path) -> None:
    """A user's module:callable AEC game with masks: self-play finds Nim's winning rule (leave a multiple of 4)."""
    done = cli("train", "--algo", "ppo_mask", "--env", "tests.user_envs.nim_game:nim", "-n", "12288", "-f",
               str(tmp_path), "--seed", "0", "--eval-freq", "0", "--final-eval-episodes", "0", "--env-kwargs",
               "pile:7", "-params", "n_envs:4", "n_steps:128", "batch_size:256", "learning_rate:0.003",
               "self_play:{mix: {random: 0.5}}")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "ppo_mask" / "tests.user_envs.nim_game_nim_1" / "opponents" / "snapshot_0.zip").is_file()
    result = last_json(cli("evaluate", "--algo", "ppo_mask", "--env", "tests.user_envs.nim_game:nim", "-f",
                           str(tmp_path), "--opponent", "random", "-n", "200", "--json").stdout)
    first = result["per_seat"]["first"]  # type: ignore[index]
    # the first seat always wins with the rule: a learned (PPO) policy, so a threshold rather than an exact 1.0
    assert first["win_rate"] >= 0.95 and result["illegal_moves"] == 0
    assert result["win_rate"] > 0.75  # type: ignore[operator]


def test_summary_json_is_plain_data(ttt_run: Path) -> None:
    data = json.loads((run_dir(ttt_run) / "summary.json").read_text())
    assert np.isfinite(data["eval"]["mean_reward"]) and data["eval"]["n_episodes"] > 0


@pytest.mark.slow  # learning (~20 s here)
def test_shipped_tictactoe_entry_learns_on_a_small_budget(tmp_path: Path) -> None:
    """The shipped tic-tac-toe entry on 1/16 of its budget (seeded): already far better than random play."""
    done = cli("train", "--algo", "ppo_mask", "--env", TTT, "-n", "24576", "-f", str(tmp_path), "--seed", "0",
               "--eval-freq", "0", "--final-eval-episodes", "0")
    assert done.returncode == 0, done.stderr
    result = last_json(cli("evaluate", "--algo", "ppo_mask", "--env", TTT, "-f", str(tmp_path), "--opponent",
                           "random", "-n", "400", "--seed", "3", "--json").stdout)
    assert result["win_rate"] > 0.7 and result["loss_rate"] < 0.15  # type: ignore[operator]
    assert result["illegal_moves"] == 0


def test_two_seat_opponents_are_refused_in_a_three_seat_game(tmp_path: Path) -> None:
    """Texas hold'em with 3 players trains and is measured against random play; a two-seat built-in opponent is
    refused in one line (training's ``mix`` goes through the same check: test_games_selfplay)."""
    holdem = ["--env", "pettingzoo.classic.texas_holdem_v4"]
    done = cli("train", "--algo", "ppo_mask", *holdem, "--env-kwargs", "num_players:3", "-n", "256", "-f",
               str(tmp_path), "--eval-freq", "0", "--final-eval-episodes", "0", "-params", "n_envs:1", "n_steps:256",
               "batch_size:64")
    assert done.returncode == 0, done.stderr
    result = last_json(cli("evaluate", "--algo", "ppo_mask", *holdem, "-f", str(tmp_path), "--opponent", "random",
                           "-n", "12", "--json").stdout)
    assert sorted(result["per_seat"]) == ["player_0", "player_1", "player_2"]  # type: ignore[call-overload]
    assert result["illegal_moves"] == 0
    refused = cli("evaluate", "--algo", "ppo_mask", *holdem, "-f", str(tmp_path), "--opponent", "heuristic")
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert "the heuristic opponent plays two-seat games" in refused.stderr and "has 3 seats" in refused.stderr
