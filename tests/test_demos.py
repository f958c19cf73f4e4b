"""``train --demos DATASET``: demonstrations kept in an off-policy model's replay buffer and sampled at a set share of
every batch (relabelled by HER in goal envs), with behaviour cloning behind a Q-filter (actor-critic) or DQfD's margin
loss (DQN); the demonstrations are never saved with the run's buffer, a continued run reads them again, and bad input
is one line (exit 2, no run dir left)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_helpers import check_error, collect_expert, run_main
from stable_baselines3 import DQN, SAC
from stable_baselines3.common.envs import BitFlippingEnv
from stable_baselines3.common.vec_env import DummyVecEnv

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.datasets.demo_losses import margin_loss, q_filtered_cloning_loss
from sbagents.datasets.demos import (
    DemoDictReplayBuffer,
    DemoHerReplayBuffer,
    DemoReplayBuffer,
    demo_buffer,
    demo_buffer_class,
)
from sbagents.datasets.reading import Episode
from sbagents.errors import UsageError

minari = pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")
QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "5", "--seed", "0")
N_BITS = 4


def run_summary(logs: Path) -> dict[str, object]:
    (summary,) = logs.rglob("summary.json")
    item: dict[str, object] = json.loads(summary.read_text())
    return item


# --- the buffers ------------------------------------------------------------------------------------------------
def bit_flipping_model(algo: type = DQN) -> DQN:
    env = DummyVecEnv([lambda: BitFlippingEnv(n_bits=N_BITS, continuous=algo is SAC, max_steps=N_BITS)])
    return algo("MultiInputPolicy", env, learning_starts=0, batch_size=64, seed=0,  # type: ignore[no-any-return]
                replay_buffer_class=DemoHerReplayBuffer,
                replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future"})


def flipping_episode(start: np.ndarray, goal: np.ndarray) -> Episode:
    """The shortest episode from ``start`` to ``goal``: flip each differing bit once (reward 0 at the goal, else -1)."""
    bits = start.copy()
    observations = [np.concatenate([bits, goal])]
    actions, rewards = [], []
    for index in np.flatnonzero(start != goal):
        bits[index] = goal[index]
        actions.append(index)
        rewards.append(0.0 if np.array_equal(bits, goal) else -1.0)
        observations.append(np.concatenate([bits, goal]))
    stacked = np.stack(observations).astype(np.int8)
    obs = {"observation": stacked[:, :N_BITS], "achieved_goal": stacked[:, :N_BITS],
           "desired_goal": stacked[:, N_BITS:]}
    n = len(actions)
    return Episode(obs, np.asarray(actions), np.asarray(rewards, dtype=np.float32),
                   np.arange(n) == n - 1, np.zeros(n, dtype=bool))


DEMOS = [flipping_episode(np.zeros(N_BITS, np.int8), np.ones(N_BITS, np.int8)),
         flipping_episode(np.asarray([1, 0, 1, 0], np.int8), np.asarray([0, 0, 1, 1], np.int8))]


def test_batches_hold_the_set_share_of_demonstrations_relabelled_by_her() -> None:
    """A third of each batch comes from the demonstrations' buffer, whose HER samples take goals achieved later in
    the same demonstration; the model's own transitions make up the rest."""
    model = bit_flipping_model()
    model.learn(40)  # the model's own episodes
    buffer = model.replay_buffer
    assert isinstance(buffer, DemoHerReplayBuffer)
    own = buffer.pos
    demos = demo_buffer(model, DEMOS)
    assert demos.size() == 6 and type(demos).__name__ == "HerReplayBuffer"
    buffer.attach_demos(demos, 1 / 3)
    assert buffer.demo_count(60) == 20 and buffer.pos == own  # the model's own buffer is untouched
    batch = buffer.sample(60, env=None)
    assert batch.observations["observation"].shape == (60, N_BITS) and batch.actions.shape == (60, 1)
    demo_obs = batch.observations["observation"][40:].numpy()
    demo_states = {tuple(row) for e in DEMOS for row in e.observations["observation"][:-1]}
    assert {tuple(row) for row in demo_obs} <= demo_states  # the last 20 are demonstration states
    reached = {tuple(row) for e in DEMOS for row in e.observations["achieved_goal"][1:]}
    assert {tuple(row) for row in batch.observations["desired_goal"][40:].numpy()} <= reached | {(1, 1, 1, 1),
                                                                                                  (0, 0, 1, 1)}
    buffer.attach_demos(demos, 1.0)
    only = buffer.sample(16, env=None)
    assert {tuple(row) for row in only.observations["observation"].numpy()} <= demo_states


def test_the_demo_class_follows_the_buffer_the_model_would_use() -> None:
    from gymnasium import spaces
    from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
    from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

    from sbagents.private.replay import PoissonReplayBuffer

    assert demo_buffer_class(None) is DemoReplayBuffer and demo_buffer_class(ReplayBuffer) is DemoReplayBuffer
    assert demo_buffer_class(DictReplayBuffer) is DemoDictReplayBuffer
    assert demo_buffer_class(HerReplayBuffer) is DemoHerReplayBuffer
    with pytest.raises(UsageError, match="not PoissonReplayBuffer"):
        demo_buffer_class(PoissonReplayBuffer)
    box = spaces.Box(-1, 1, (2,))
    assert type(DemoReplayBuffer(8, spaces.Dict({"a": box}), box)) is DemoDictReplayBuffer  # as SB3 picks the class
    assert type(DemoReplayBuffer(8, box, box)) is DemoReplayBuffer
    assert type(copy.deepcopy(DemoReplayBuffer(8, box, box))) is DemoReplayBuffer


def test_the_q_filter_keeps_only_demonstrations_the_critic_values_higher() -> None:
    model = bit_flipping_model(SAC)
    obs, _ = model.policy.obs_to_tensor(DEMOS[0].observation(0))
    obs = {k: v.repeat(8, 1) for k, v in obs.items()}
    actor = model.actor
    taken = actor(obs, deterministic=True).detach()
    loss, kept = q_filtered_cloning_loss(model, obs, taken)  # the actor's own actions: Q equal, nothing kept
    assert kept == 0.0 and float(loss.detach()) == 0.0
    loss, kept = q_filtered_cloning_loss(model, obs, torch.clamp(-taken, -1, 1))
    assert 0.0 <= kept <= 1.0 and (float(loss.detach()) > 0) == (kept > 0)
    loss, kept = q_filtered_cloning_loss(model, obs, taken, q_filter=False)  # before the filter starts: all count
    assert kept == 1.0 and float(loss.detach()) == 0.0


def test_the_margin_loss_is_zero_only_when_the_demonstrated_action_leads_by_the_margin() -> None:
    model = bit_flipping_model()
    obs, _ = model.policy.obs_to_tensor(DEMOS[0].observation(0))
    with torch.no_grad():
        greedy = model.q_net(obs).argmax(dim=1)
    loss, greedy_share = margin_loss(model, obs, greedy)
    assert greedy_share == 1.0 and float(loss.detach()) >= 0
    optimizer = torch.optim.Adam(model.q_net.parameters(), lr=1e-2)
    action = (greedy + 1) % N_BITS  # teach another action
    for _ in range(300):
        loss, _ = margin_loss(model, obs, action)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert float(loss.detach()) < 1e-3 and margin_loss(model, obs, action)[1] == 1.0


# --- the command ------------------------------------------------------------------------------------------------
def test_dqn_with_demonstrations_and_the_margin_loss_solves_the_grid(datasets: Path, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    collect_expert("GridWorld-v0", "sbagents/grid-expert-v0", 10)
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "dqn", "--env", "GridWorld-v0", "--demos", "sbagents/grid-expert-v0",
                    "--demo-bc", "1", "-n", "2000", "-f", str(logs), *QUIET) == 0
    out = capsys.readouterr().out
    assert "demonstrations: 10 episodes (80 transitions) of sbagents/grid-expert-v0, 0.25 of every batch, margin " \
           "loss weight 1" in out
    summary = run_summary(logs)
    demos = summary["demos"]
    assert isinstance(demos, dict) and demos["transitions"] == 80 and demos["loss_steps"] > 0
    assert summary["eval"]["mean_return"] == 93.0  # type: ignore[index]


def test_sac_with_demonstrations_continues_with_its_buffer_and_evaluates(datasets: Path, tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """SmartHome's expert as demonstrations with the Q-filtered BC loss; the saved buffer holds only the model's own
    transitions (its file names SB3's class, so a run continues with it with or without ``--demos``); ``-i``
    continues with the demonstrations read again and the Q-filter on (it counts the model's gradient steps, not the
    continued run's), refuses ``--pretrain``, and ``evaluate`` loads the model."""
    collect_expert("SmartHome-v0", "sbagents/home-expert-v0", 3)
    logs = tmp_path / "logs"
    common = ("--algo", "sac", "--env", "SmartHome-v0", "--demos", "sbagents/home-expert-v0", "--demo-bc", "0.5",
              "--demo-ratio", "0.5", "--demo-filter-after", "100", "-params", "learning_starts:100", "batch_size:32",
              "-f", str(logs), *QUIET)
    assert run_main("train", *common, "-n", "300", "--save-replay-buffer") == 0
    first = run_summary(logs)
    demos = first["demos"]
    assert isinstance(demos, dict) and demos["ratio"] == 0.5
    assert demos["loss_steps"] == 100  # one per SAC gradient step: 200 steps after learning starts, train_freq 2
    assert demos["loss_kept"] == 1.0  # the filter starts after the model's 100th gradient step: not yet
    (run_dir,) = (p.parent for p in logs.rglob("summary.json"))
    with np.load(run_dir / "replay_buffer.npz") as saved:
        settings = json.loads(str(saved["__settings__"]))
    assert settings["class"] == "ReplayBuffer" and settings["pos"] == 300  # the demonstrations are not in it
    model = str(run_dir / "sbagents_SmartHome-v0.zip")
    capsys.readouterr()
    check_error(run_main("train", *common, "-n", "200", "-i", model, "--pretrain", "sbagents/home-expert-v0"),
                capsys.readouterr().err, "--pretrain clones into a new model; -i continues a trained one")
    assert run_main("train", *common, "-n", "200", "-i", model) == 0
    resumed = json.loads(sorted(logs.rglob("summary.json"))[-1].read_text())
    assert resumed["demos"]["loss_steps"] == 100 and 0.0 <= resumed["demos"]["loss_kept"] < 1.0  # filtered at once
    assert resumed["replay_buffer"]["loaded_transitions"] == 300
    plain = [a for a in common if a not in ("--demos", "sbagents/home-expert-v0", "--demo-bc", "0.5", "--demo-ratio",
                                            "0.5", "--demo-filter-after", "100")]
    assert run_main("train", *plain, "-n", "100", "-i", model) == 0  # the same buffer file, without demonstrations
    dropped = json.loads(sorted(logs.rglob("summary.json"))[-1].read_text())
    assert "demos" not in dropped and dropped["replay_buffer"]["loaded_transitions"] == 300
    assert run_main("evaluate", "--algo", "sac", "--env", "SmartHome-v0", "-f", str(logs), "-n", "2",
                    "--exp-id", "1") == 0


def test_bad_demonstrations_are_one_line_and_leave_no_run(datasets: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    collect_expert("GridWorld-v0", "sbagents/grid-expert-v0", 2)
    logs = tmp_path / "logs"
    common = ("-n", "64", "-f", str(logs), *QUIET)
    capsys.readouterr()
    for args, expected in (
            (("--algo", "ppo", "--demos", "sbagents/grid-expert-v0"), "--demos trains sac, tqc, td3"),
            (("--algo", "dqn", "--demo-ratio", "0.5"), "--demo-ratio, --demo-bc and --demo-filter-after apply to"),
            (("--algo", "dqn", "--demos", "sbagents/grid-expert-v0", "--demo-ratio", "1.5"), "must be in [0, 1]"),
            (("--algo", "dqn", "--demos", "sbagents/none-v0"), "--demos sbagents/none-v0: cannot load the dataset"),
            (("--algo", "dqn", "--demos", "sbagents/grid-expert-v0", "-params", "n_steps:3"), "n_steps > 1"),
    ):
        check_error(run_main("train", "--env", "GridWorld-v0", *args, *common), capsys.readouterr().err, expected)
    collect_expert("SmartHome-v0", "sbagents/home-expert-v0", 1)
    check_error(run_main("train", "--algo", "sac", "--env", "SmartHome-v0", "--demos", "sbagents/home-expert-v0",
                         "--constraint", "lagrangian", "--cost-limit", "1", *common), capsys.readouterr().err,
                "nor a flag that sets it, such as --demos, with --constraint")
    check_error(run_main("train", "--algo", "dqn", "--env", "HazardGridWorld-v0", "--demos",
                         "sbagents/grid-expert-v0", *common), capsys.readouterr().err,
                "--demos sbagents/grid-expert-v0: its observation space Discrete(25) is not the env's Discrete(35)")
    (datasets / "sbagents" / "grid-expert-v0" / "data" / "main_data.hdf5").write_bytes(b"not hdf5")  # damaged
    check_error(run_main("train", "--algo", "dqn", "--env", "GridWorld-v0", "--demos", "sbagents/grid-expert-v0",
                         *common), capsys.readouterr().err, "--demos sbagents/grid-expert-v0: cannot")
    assert not logs.exists() or not any(logs.rglob("*.yml"))  # no run dir was left behind


@pytest.mark.parametrize(("algo", "env", "expert"), [("tqc", "SmartHome-v0", "home"), ("td3", "SmartHome-v0", "home"),
                                                     ("ddpg", "SmartHome-v0", "home"),
                                                     ("qrdqn", "GridWorld-v0", "grid")])
def test_every_declared_algorithm_learns_with_demonstrations_and_its_loss(algo: str, env: str, expert: str,
                                                                          datasets: Path, tmp_path: Path) -> None:
    """TQC's quantile critics, TD3's and DDPG's twin or single critic behind the Q-filter; QR-DQN's quantiles in the
    margin loss (with DQN's GridWorld entry: QR-DQN's own file has Atari entries only)."""
    collect_expert(env, f"sbagents/{expert}-expert-v0", 2)
    logs = tmp_path / "logs"
    config = ("-conf", str(Path(sbagents.__file__).parent / "zoo_configs" / "dqn.yml")) if algo == "qrdqn" else ()
    assert run_main("train", "--algo", algo, "--env", env, *config, "--demos", f"sbagents/{expert}-expert-v0",
                    "--demo-bc", "1", "--demo-filter-after", "10", "-n", "300", "-params", "learning_starts:100",
                    "batch_size:32", "-f", str(logs), *QUIET) == 0
    demos = run_summary(logs)["demos"]
    assert isinstance(demos, dict) and demos["loss_steps"] > 10 and 0 <= demos["loss_kept"] <= 1
