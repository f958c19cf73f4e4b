"""A team in a dataset and a team cloned from one: ``collect`` records each agent's part of every team episode as an
episode of its own (the layout the dataset's description states), and ``train --pretrain`` clones the team's shared
policy from it."""

from __future__ import annotations

import json
from pathlib import Path

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
