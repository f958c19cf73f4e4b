"""``train --pretrain DATASET``: behaviour cloning before RL, from a dataset ``collect`` wrote or one Minari wrote by
itself, for on-policy, off-policy and Q-learning algorithms on discrete and continuous actions; it prints the held-out
loss and the cloned policy's return before learning, records them in summary.json, and refuses bad datasets in one
line (exit 2, no run dir left)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from cli_helpers import check_error, collect_expert, run_main

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.baselines.experts import ComfortController

minari = pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")
QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "5", "--seed", "0")


def pretrained(logs: Path, algo: str) -> dict[str, object]:
    (summary,) = (logs / algo).rglob("summary.json")
    item: dict[str, object] = json.loads(summary.read_text())["pretrain"]
    return item


@pytest.mark.parametrize("algo", ["ppo", "dqn"])
def test_cloning_the_grid_expert_reaches_its_return_before_rl(algo: str, datasets: Path, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    collect_expert("GridWorld-v0", "sbagents/grid-expert-v0", 10)
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", algo, "--env", "GridWorld-v0", "--pretrain", "sbagents/grid-expert-v0",
                    "--pretrain-steps", "300", "-n", "64", "-f", str(logs), *QUIET) == 0
    out = capsys.readouterr().out
    assert out.index("pretrained on sbagents/grid-expert-v0") < out.index("run dir:")  # before learning's lines
    item = pretrained(logs, algo)
    assert item["eval_return"] == 93.0 and item["n_train"] + item["n_holdout"] == 80  # 10 episodes of 8 steps
    assert item["holdout_loss"] is not None and float(item["holdout_loss"]) < 0.1  # type: ignore[arg-type]
    args = (next((logs / algo).iterdir()) / "sbagents_GridWorld-v0" / "args.yml").read_text()
    assert "pretrain: sbagents/grid-expert-v0" in args


@pytest.mark.parametrize("algo", ["td3", "sac", "ppo"])
def test_cloning_the_smart_home_expert_keeps_most_of_its_return(algo: str, datasets: Path, tmp_path: Path) -> None:
    """Continuous actions, normalized observations where the entry says so (PPO): the clone's return is far above
    random play's (-1,598) and near the expert's (-6.6 over 100 episodes)."""
    collect_expert("SmartHome-v0", "sbagents/home-expert-v0", 20)
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", algo, "--env", "SmartHome-v0", "--pretrain", "sbagents/home-expert-v0",
                    "--pretrain-steps", "1500", "-n", "64", "-f", str(logs), *QUIET,
                    *(("-params", "learning_starts:1000") if algo != "ppo" else ())) == 0
    assert float(pretrained(logs, algo)["eval_return"]) > -150  # type: ignore[arg-type]


def test_a_dataset_minari_wrote_itself_trains(datasets: Path, tmp_path: Path) -> None:
    """A dataset written by ``minari.create_dataset_from_buffers`` outside sbagents (its own id, no sbagents writer)
    is cloned like ours."""
    from minari.data_collector import EpisodeBuffer

    env = gym.make("sbagents/SmartHome-v0")
    expert, buffers = ComfortController(env), []
    for seed in range(20):
        obs, _ = env.reset(seed=seed)
        expert.reset()
        observations, actions, rewards, terms, truncs, done = [obs], [], [], [], [], False
        while not done:
            action = expert.act(obs)
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(float(reward))
            terms.append(terminated)
            truncs.append(truncated)
            done = terminated or truncated
        buffers.append(EpisodeBuffer(id=seed, seed=seed, observations=np.array(observations),
                                     actions=np.array(actions), rewards=rewards, terminations=terms,
                                     truncations=truncs, infos={}))
    minari.create_dataset_from_buffers("outside/home-expert-v0", buffers, env="sbagents/SmartHome-v0",
                                       algorithm_name="comfort controller")
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "td3", "--env", "SmartHome-v0", "--pretrain", "outside/home-expert-v0",
                    "--pretrain-steps", "1500", "-n", "64", "-f", str(logs), *QUIET,
                    "-params", "learning_starts:1000") == 0
    assert float(pretrained(logs, "td3")["eval_return"]) > -150  # type: ignore[arg-type]


def test_bad_datasets_are_one_line_and_leave_no_run(datasets: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    collect_expert("GridWorld-v0", "sbagents/grid-expert-v0", 2)
    data = datasets / "sbagents" / "grid-expert-v0" / "data" / "main_data.hdf5"
    logs = tmp_path / "logs"
    common = ("-n", "64", "-f", str(logs), *QUIET)
    capsys.readouterr()
    check_error(run_main("train", "--algo", "ppo", "--env", "HazardGridWorld-v0", "--pretrain",
                         "sbagents/grid-expert-v0", *common), capsys.readouterr().err,
                "its observation space Discrete(25) is not the env's Discrete(35)")
    check_error(run_main("train", "--algo", "ppo", "--env", "GridWorld-v0", "--pretrain", "sbagents/none-v0",
                         *common), capsys.readouterr().err, "--pretrain sbagents/none-v0: cannot load the dataset")
    check_error(run_main("train", "--algo", "ars", "--env", "GridWorld-v0", "--pretrain", "sbagents/grid-expert-v0",
                         *common), capsys.readouterr().err, "--pretrain trains a2c, ppo, trpo")
    check_error(run_main("train", "--algo", "ppo", "--env", "GridWorld-v0", "--pretrain-steps", "5", *common),
                capsys.readouterr().err, "--pretrain-steps applies to --pretrain DATASET")
    data.write_bytes(b"not hdf5")  # a damaged dataset
    check_error(run_main("train", "--algo", "ppo", "--env", "GridWorld-v0", "--pretrain", "sbagents/grid-expert-v0",
                         *common), capsys.readouterr().err, "--pretrain sbagents/grid-expert-v0: cannot")
    assert not logs.exists() or not any(logs.rglob("*.yml"))  # no run dir was left behind


def test_qrdqn_clones_its_quantile_network_and_its_target(datasets: Path, tmp_path: Path) -> None:
    """QR-DQN's values live in ``quantile_net`` (not ``q_net``): the cloned greedy policy walks the expert's path, and
    the target network starts as the clone (DQN's GridWorld entry: QR-DQN's own file has Atari entries only)."""
    from sbagents.datasets.cloning import _sync_targets, q_network

    collect_expert("GridWorld-v0", "sbagents/grid-expert-v0", 10)
    logs = tmp_path / "logs"
    config = str(Path(sbagents.__file__).parent / "zoo_configs" / "dqn.yml")
    assert run_main("train", "--algo", "qrdqn", "--env", "GridWorld-v0", "-conf", config, "--pretrain",
                    "sbagents/grid-expert-v0", "--pretrain-steps", "300", "-n", "64", "-f", str(logs), *QUIET) == 0
    assert pretrained(logs, "qrdqn")["eval_return"] == 93.0

    model: Any = SimpleNamespace(quantile_net=torch.nn.Linear(2, 2), quantile_net_target=torch.nn.Linear(2, 2))
    assert q_network(model) is model.quantile_net
    _sync_targets(model)
    assert torch.equal(model.quantile_net.weight, model.quantile_net_target.weight)
