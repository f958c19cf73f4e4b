"""Baselines without a run (``evaluate --policy random|scripted``): the scripted experts of the book's envs reach
their specs' numbers, random play scores any env (single agent, team, game), scripted games play their best
built-in player, and misuse is one line; a team whose agents compete (rewards summing to zero) is named as such."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import gymnasium as gym
import pytest
from cli_helpers import check_error, run_main
from stable_baselines3.common.env_util import make_vec_env

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.baselines.experts import ShortestPath
from sbagents.baselines.policies import ControllerPolicy, RandomPolicy
from sbagents.core.env_names import resolve_env
from sbagents.core.options import EvaluateOptions
from sbagents.errors import UsageError
from sbagents.multiagent.competition import zero_sum_under_random_play
from sbagents.pipeline.evaluation import evaluate_baseline


def baseline(env: str, policy: str, n: int = 5, **kwargs: object) -> dict[str, object]:
    return evaluate_baseline(resolve_env(env), policy, EvaluateOptions(n_episodes=n, seed=0), kwargs or None)


@pytest.mark.parametrize(("env", "ret", "length", "cost"), [
    ("sbagents/GridWorld-v0", 93.0, 8.0, None),  # the spec's shortest path around the diagonal obstacles
    ("sbagents/HazardGridWorld-v0", 87.0, 14.0, 0.0),  # the spec's shortest safe path, over the top row
])
def test_the_grid_experts_walk_the_specs_shortest_paths(env: str, ret: float, length: float,
                                                        cost: float | None) -> None:
    summary = baseline(env, "scripted")
    assert (summary["mean_return"], summary["std_return"], summary["mean_length"]) == (ret, 0.0, length)
    assert summary["success_rate"] == 1.0 and summary.get("mean_cost") == cost and summary["algo"] == "scripted"


def test_without_a_safe_path_the_grid_expert_crosses_the_hazards() -> None:
    env = gym.make("sbagents/HazardGridWorld-v0", hazards=[(r, 3) for r in range(5)])  # a wall of hazards
    expert = ShortestPath(env)
    obs, _ = env.reset(seed=0)
    total, done, cost = 0.0, False, 0.0
    while not done:
        obs, reward, terminated, truncated, info = env.step(expert.act(obs))
        total, cost, done = total + float(reward), cost + info.get("cost", 0.0), terminated or truncated
    assert terminated and total == 95.0 and cost == 1.0  # the 6-step path through one hazard


@pytest.mark.parametrize("env", ["sbagents/SmartHome-v0", "sbagents/SmartHomePrefOnce-v0"])
def test_the_smart_home_expert_keeps_the_user_comfortable(env: str) -> None:
    """It reads the true state and preferences (hidden after the reset in PrefOnce): every step after the warm-up
    is comfortable, and it returns far more than random play."""
    scripted, random = baseline(env, "scripted", n=10), baseline(env, "random", n=10)
    assert scripted["success_rate"] == 1.0 and scripted["metrics"]["criterion_share"] == 1.0
    assert scripted["mean_return"] > -20 > -1000 > random["mean_return"]


@pytest.mark.parametrize("env", ["sbagents/PickAndPlace-v0", "sbagents/KukaPickAndPlace-v0"])
def test_the_kuka_experts_are_their_scripts(env: str) -> None:
    summary = baseline(env, "scripted", n=2)
    assert summary["success_rate"] == 1.0 and summary["mean_cost"] == 0.0


@pytest.mark.parametrize("observation", ["book", "egocentric"])
def test_the_treasure_hunt_team_collects_every_treasure(observation: str) -> None:
    """The greedy team shares the treasures out and walks around the obstacles: all 5 in every episode, well inside
    the 50 steps (PPO's shipped entry collects 4.75-4.90), in either observation mode (it reads the true state)."""
    summary = baseline("treasure_hunt_v0", "scripted", n=10, observation=observation)
    assert summary["success_rate"] == 1.0 and summary["metrics"]["treasures_collected"] == 5.0
    assert summary["mean_length"] < 20 and summary["mean_return"] > 100


def test_random_play_scores_a_team_and_a_game() -> None:
    team = baseline("treasure_hunt_v0", "random", n=3)
    assert team["algo"] == "random" and set(team["metrics"]["per_agent_return"]) == {"agent_0", "agent_1", "agent_2"}
    game = baseline("pettingzoo.classic.tictactoe_v3", "random", n=10)
    assert game["n_games"] == 10 and game["opponent"] == "random"
    assert game["win_rate"] + game["draw_rate"] + game["loss_rate"] == pytest.approx(1.0)


def test_a_scripted_game_plays_its_best_builtin_player() -> None:
    summary = baseline("pettingzoo.classic.tictactoe_v3", "scripted", n=10)  # minimax against random play
    assert summary["loss_rate"] == 0.0 and summary["win_rate"] >= 0.7


def test_the_cli_plays_a_baseline_and_refuses_misuse_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_main("evaluate", "--policy", "random", "--env", "GridWorld-v0", "-n", "3", "--json") == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["algo"] == "random" and summary["n_episodes"] == 3
    for args, expected in [(("--policy", "scripted", "--env", "mpe2.simple_spread_v3"), "simple_spread_v3 has no "
                             "scripted expert"),
                           (("--policy", "random", "--env", "GridWorld-v0", "--algo", "ppo"), "no --algo"),
                           (("--env", "GridWorld-v0",), "--algo and --env name the run to evaluate"),
                           (("--policy", "scripted", "--env", "pettingzoo.classic.rps_v2"), "rps_v2 has no scripted "
                            "expert")]:
        check_error(run_main("evaluate", *args), capsys.readouterr().err, expected)


def test_policies_act_on_batches_and_controllers_need_their_envs() -> None:
    venv = make_vec_env("sbagents/GridWorld-v0", n_envs=3, seed=0)
    obs = venv.reset()
    actions, state = RandomPolicy(venv.action_space, seed=0).predict(obs)
    assert actions.shape == (3,) and state is None and all(venv.action_space.contains(int(a)) for a in actions)
    experts = ControllerPolicy(venv, ShortestPath)
    assert list(experts.predict(obs)[0]) == [1, 1, 1]  # from the start cell: down (right is as short; first wins)
    batched = SimpleNamespace(unwrapped=SimpleNamespace())  # copies that are not gymnasium envs in this process
    with pytest.raises(UsageError, match="scripted policies read their env"):
        ControllerPolicy(batched, ShortestPath)  # type: ignore[arg-type]


def test_competing_agents_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """rps_v2's rewards sum to zero at every step: a shared-policy run warns and names per_agent, the evaluation
    notes it; a cooperative team does not warn. A per_agent run trains one model per player."""
    assert zero_sum_under_random_play(resolve_env("pettingzoo.classic.rps_v2").parallel_env())
    assert not zero_sum_under_random_play(resolve_env("mpe2.simple_spread_v3").parallel_env())
    random = baseline("pettingzoo.classic.rps_v2", "random", n=5)
    assert random["mean_return"] == 0.0 and "its agents compete" in str(random["note"])
    common = ("--algo", "ppo", "--env", "pettingzoo.classic.rps_v2", "-n", "128", "-f", str(tmp_path), "--verbose",
              "0", "--final-eval-episodes", "1", "-params", "n_steps:64", "batch_size:64")
    assert run_main("train", *common) == 0
    err = capsys.readouterr().err
    assert "rps_v2's agents compete" in err and "policies:per_agent" in err
    assert run_main("train", *common, "policies:per_agent") == 0
    out = capsys.readouterr()
    assert "agents compete" not in out.err and "player_0_return" in out.out
    assert run_main("train", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-n", "64", "-f", str(tmp_path),
                    "--verbose", "0", "--final-eval-episodes", "0", "-params", "n_steps:32", "batch_size:32",
                    "n_envs:1") == 0
    assert "agents compete" not in capsys.readouterr().err


def test_one_group_of_per_group_evaluates_with_the_runs_one_model(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """policies: per_group whose prefix grouping gives one group (rps_v2's player_0, player_1) trains one model; its
    final evaluation and evaluate play that model for the group (they once looked it up as 'shared')."""
    assert run_main("train", "--algo", "ppo", "--env", "pettingzoo.classic.rps_v2", "-n", "128", "-f", str(tmp_path),
                    "--verbose", "0", "--final-eval-episodes", "2", "-params", "n_steps:64", "batch_size:64",
                    "policies:per_group") == 0
    capsys.readouterr()
    assert run_main("evaluate", "--algo", "ppo", "--env", "pettingzoo.classic.rps_v2", "-f", str(tmp_path), "-n", "2",
                    "--json") == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["n_episodes"] == 2
