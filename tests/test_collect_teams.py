"""Teams and games in a dataset, and policies cloned from them: ``collect`` records each agent's part of every team
episode as an episode of its own, and a game from the recorded player's seat (the layouts the dataset's description
states); ``train --pretrain`` clones a team's shared policy or a game's player from them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_main

import sbagents  # noqa: F401 (registers the env ids)

minari = pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")


def test_the_greedy_team_is_recorded_per_agent_and_cloned(datasets: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """TreasureHunt's greedy team (3 agents, all 5 treasures in every episode) with the egocentric observation the
    ppo entry trains on: 3 dataset episodes per team episode, whose returns add up to the team's return as
    ``evaluate --policy scripted`` scores it; a shared ppo policy cloned from them collects most treasures before
    RL."""
    kwargs = ("--env-kwargs", "observation:egocentric")
    assert run_main("collect", "--env", "treasure_hunt_v0", "--policy", "scripted", "--episodes", "4", "--dataset",
                    "sbagents/treasure-team-v0", *kwargs) == 0
    assert "dataset sbagents/treasure-team-v0: 12 episodes in" in capsys.readouterr().out
    dataset = minari.load_dataset("sbagents/treasure-team-v0")
    assert "each team episode is 3 consecutive episodes, one per agent in the order agent_0, agent_1, agent_2" in \
        dataset.storage.metadata["description"]
    episodes = list(dataset.iterate_episodes())
    team_returns = [sum(float(e.rewards.sum()) for e in episodes[i:i + 3]) for i in range(0, 12, 3)]
    for seed, team_return in enumerate(team_returns):  # team episode i was reset with seed i
        assert run_main("evaluate", "--policy", "scripted", "--env", "treasure_hunt_v0", "-n", "1", "--seed",
                        str(seed), "--json", *kwargs) == 0
        scored = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert team_return == pytest.approx(scored["mean_return"])
    assert all(len(e.observations) == len(e.actions) + 1 for e in episodes)
    assert all(e.terminations[-1] or e.truncations[-1] for e in episodes)

    logs = tmp_path / "logs"
    assert run_main("collect", "--env", "treasure_hunt_v0", "--policy", "scripted", "--episodes", "30", "--dataset",
                    "sbagents/treasure-team-v1", "--seed", "100", *kwargs) == 0
    assert run_main("train", "--algo", "ppo", "--env", "treasure_hunt_v0", "--pretrain", "sbagents/treasure-team-v1",
                    "-n", "64", "-f", str(logs), "--eval-freq", "-1", "--final-eval-episodes", "10", "--seed", "0",
                    "--verbose", "0") == 0
    (summary,) = logs.rglob("summary.json")
    pretrain = json.loads(summary.read_text())["pretrain"]
    assert pretrain["eval_return"] > 20  # random play: about -30 (BENCHMARKS.md, baseline-references)


def test_a_game_is_recorded_from_the_players_seat_and_cloned(datasets: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Tic-tac-toe's minimax player against random moves: one episode per game from its seat (the opponent's replies
    inside each step), every recorded move legal by the mask kept with its observation, never a loss; MaskablePPO
    cloned from 200 such games beats random play before RL."""
    game = "pettingzoo.classic.tictactoe_v3"
    assert run_main("collect", "--env", game, "--policy", "scripted", "--episodes", "200", "--dataset",
                    "sbagents/ttt-minimax-v0") == 0
    dataset = minari.load_dataset("sbagents/ttt-minimax-v0")
    assert "one episode per game from the recorded player's seat" in dataset.storage.metadata["description"]
    assert "reset seed 0, then unseeded resets" in dataset.storage.metadata["description"]
    episodes = list(dataset.iterate_episodes())
    assert len(episodes) == 200 and all(e.rewards.sum() >= 0 for e in episodes)  # minimax never loses
    assert sum(e.rewards.sum() > 0 for e in episodes) > 150
    for e in episodes:
        masks = e.infos["action_mask"]
        assert masks.shape == (len(e.actions) + 1, 9) and e.observations.shape == (len(e.actions) + 1, 3, 3, 2)
        assert masks[np.arange(len(e.actions)), e.actions].all()  # each move legal in its position
    first_moves = {int(e.observations[0].sum()) for e in episodes}
    assert first_moves == {0, 1}  # seats alternate: an empty board, or one opponent mark already there

    logs = tmp_path / "logs"
    capsys.readouterr()
    assert run_main("train", "--algo", "ppo_mask", "--env", game, "--pretrain", "sbagents/ttt-minimax-v0", "-n", "64",
                    "-f", str(logs), "--eval-freq", "-1", "--final-eval-episodes", "2", "--seed", "0",
                    "--verbose", "0") == 0
    (summary,) = logs.rglob("summary.json")
    pretrain = json.loads(summary.read_text())["pretrain"]
    assert pretrain["eval_return"] > 0.3  # random play: -0.06 over 200 games (evaluate --policy random)
