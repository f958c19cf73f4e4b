"""TransparencyCSVCallback: rows per step, header, raw obs/rewards, interruption, appending, multi-agent."""

from __future__ import annotations

import csv
import gzip
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from stable_baselines3 import DQN, PPO, SAC
from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

import sbagents  # noqa: F401  (registers the env ids)
from sbagents.callbacks import TransparencyCSVCallback
from sbagents.envs.gridworld import GridWorldEnv
from sbagents.envs.smart_home import SmartHomeEnv

torch.set_num_threads(1)
def net() -> dict[str, Any]:
    return {"net_arch": [16, 16]}


class InterruptAfter(BaseCallback):
    """Raises KeyboardInterrupt (as Ctrl-C would) at its ``n``-th step."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n

    def _on_step(self) -> bool:
        if self.n_calls >= self.n:
            raise KeyboardInterrupt
        return True


def read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    opener: Any = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", newline="") as fh:
        text = fh.read()
    assert text.count("\n") == len(text.splitlines())  # every row complete
    reader = csv.DictReader(text.splitlines())
    rows = list(reader)
    return list(reader.fieldnames or []), rows


def test_gridworld_rows_match_steps_and_replay(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    env = make_vec_env("sbagents/GridWorld-v0", n_envs=3, seed=0)
    cb = TransparencyCSVCallback(path)
    model = PPO("MlpPolicy", env, n_steps=40, batch_size=60, n_epochs=1, seed=0, policy_kwargs=net())
    model.learn(240, callback=cb)
    header, rows = read(path)
    assert header == ["env", "episode", "step", "cell", "move", "reward", "terminated", "truncated", "event"]
    assert len(rows) == model.num_timesteps == 240
    assert cb.rows_written == 240
    # Replay every env's rows through a fresh GridWorld: the logged cell is the one the action was taken in.
    sim = GridWorldEnv()
    for e in range(3):
        own = [r for r in rows if r["env"] == str(e)]
        assert [int(r["step"]) for r in own[:3]] == [0, 1, 2] and own[0]["cell"] == "0"
        for cur, nxt in zip(own, own[1:], strict=False):
            sim.reset()
            sim.agent, sim.steps = sim.to_cell(int(cur["cell"])), int(cur["step"])
            obs, reward, term, trunc, _ = sim.step(int(cur["move"]))
            assert float(cur["reward"]) == reward
            assert cur["terminated"] == str(term) and cur["truncated"] == str(trunc)
            if term or trunc:
                assert (int(nxt["episode"]), nxt["step"], nxt["cell"]) == (int(cur["episode"]) + 1, "0", "0")
            else:
                expected = (cur["episode"], sim.steps, obs)
                assert (nxt["episode"], int(nxt["step"]), int(nxt["cell"])) == expected


def test_smart_home_vecnormalize_raw_values_and_book_header(tmp_path: Path) -> None:
    path = tmp_path / "s.csv"
    env = VecNormalize(make_vec_env(SmartHomeEnv, n_envs=2, seed=1))
    model = PPO("MlpPolicy", env, n_steps=110, batch_size=110, n_epochs=1, seed=0, policy_kwargs=net())
    model.learn(220, callback=TransparencyCSVCallback(path, info_keys="temperature,light_level,comfortable"))
    header, rows = read(path)
    assert header[:9] == ["env", "episode", "step", "Temperature", "Light_Level", "Time", "Preferred_Temp",
                          "Preferred_Light", "Action_Temp"]
    assert header[-3:] == ["temperature", "light_level", "comfortable"] and len(rows) == 220
    for r in rows:  # raw observation (not normalized) and the unnormalized book reward
        assert 17 <= float(r["Temperature"]) <= 29 and 0 <= int(float(r["Time"])) <= 23
        a_t, a_l = float(r["Action_Temp"]), float(r["Action_Light"])
        expected = (-abs(float(r["temperature"]) - float(r["Preferred_Temp"]))
                    - 0.5 * abs(float(r["light_level"]) - float(r["Preferred_Light"]))
                    - 0.1 * (abs(a_t) + 0.05 * abs(a_l)))
        assert float(r["reward"]) == pytest.approx(expected, rel=1e-5, abs=1e-4)
    done = [r for r in rows if r["truncated"] == "True"]
    assert len(done) == 2 and all(r["step"] == "99" and r["Time"] != "" for r in done)

    book = tmp_path / "book.csv"
    single = make_vec_env(SmartHomeEnv, n_envs=1, seed=2)
    PPO("MlpPolicy", single, n_steps=32, batch_size=32, n_epochs=1, policy_kwargs=net()).learn(
        32, callback=TransparencyCSVCallback(book, book_header=True)
    )
    lines = book.read_text().splitlines()
    assert lines[0] == ("Episode,Step,Temperature,Light_Level,Time,Preferred_Temp,Preferred_Light,"
                        "Action_Temp,Action_Light,Reward")
    assert len(lines) == 33 and lines[1].startswith("0,0,")


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
def test_keyboard_interrupt_leaves_complete_file_and_training_appends(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"log{suffix}"
    env = make_vec_env("sbagents/GridWorld-v0", n_envs=2, seed=0)
    model = DQN("MlpPolicy", env, learning_starts=20, seed=0, policy_kwargs=net())
    cb = TransparencyCSVCallback(path)
    with pytest.raises(KeyboardInterrupt):
        model.learn(10_000, callback=[cb, InterruptAfter(37)])
    header, rows = read(path)  # the callback object is still alive: nothing may wait in a buffer
    assert len(rows) == 37 * 2
    assert not {"collect_rollouts", "train"} & set(model.__dict__)  # hooks removed, model saves cleanly
    model.save(tmp_path / "m.zip")

    # A new callback on the same path (e.g. train -i): appended, one header, episodes continue.
    last_episode = max(int(r["episode"]) for r in rows)
    model.learn(20, callback=TransparencyCSVCallback(path), reset_num_timesteps=True)
    header2, rows2 = read(path)
    assert header2 == header and len(rows2) == 74 + model.num_timesteps
    assert all(int(r["episode"]) > last_episode for r in rows2[74:])
    opener: Any = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        assert sum(line.startswith("env,") for line in fh) == 1


def test_checkpoint_during_training_and_subproc_stock_env(tmp_path: Path) -> None:
    path = tmp_path / "p.csv"
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    try:
        model = SAC("MlpPolicy", env, learning_starts=10, seed=0, policy_kwargs=net())
        ckpt = CheckpointCallback(10, str(tmp_path), name_prefix="ck")
        model.learn(60, callback=[TransparencyCSVCallback(path, every=2), ckpt])
    finally:
        env.close()
    header, rows = read(path)
    assert header == ["env", "episode", "step", "obs_0", "obs_1", "obs_2", "action_0", "reward", "terminated",
                      "truncated"]
    assert len(rows) == 30  # every 2nd of 30 vec steps, 2 envs
    assert [r["step"] for r in rows[:4]] == ["1", "1", "3", "3"]
    assert all(abs(float(r["action_0"])) <= 2.0 for r in rows)
    assert list(tmp_path.glob("ck_*.zip"))


def test_cartpole_dummy_and_header_mismatch(tmp_path: Path) -> None:
    path = tmp_path / "c.csv"
    env = DummyVecEnv([lambda: __import__("gymnasium").make("CartPole-v1")] * 4)
    model = PPO("MlpPolicy", env, n_steps=16, batch_size=64, n_epochs=1, seed=0, policy_kwargs=net())
    model.learn(64, callback=TransparencyCSVCallback(path))
    _, rows = read(path)
    assert len(rows) == 64 and {r["env"] for r in rows} == {"0", "1", "2", "3"}
    with pytest.raises(ValueError, match="another header"):
        model.learn(64, callback=TransparencyCSVCallback(path, info_keys=["x"]))


def test_multi_agent_agent_column(tmp_path: Path) -> None:
    from sbagents.envs import treasure_hunt_v0
    from sbagents.multiagent import parameter_sharing as multiagent

    venv = multiagent.make_parameter_sharing_vec_env(treasure_hunt_v0.parallel_env, n_envs=2, seed=0)
    n_agents = venv.n_agents
    path = tmp_path / "m.csv"
    model = PPO("MlpPolicy", venv, n_steps=60, batch_size=60, n_epochs=1, seed=0, policy_kwargs=net())
    model.learn(60 * venv.num_envs, callback=TransparencyCSVCallback(path))
    header, rows = read(path)
    assert header[:4] == ["env", "agent", "episode", "step"]
    assert len(rows) == 60 * 2 * n_agents
    assert [r["agent"] for r in rows[:n_agents]] == list(venv.possible_agents)
    assert {r["env"] for r in rows} == {"0", "1"}
    ends = [r for r in rows if r["truncated"] == "True" or r["terminated"] == "True"]
    assert len(ends) % n_agents == 0 and ends  # all agents of an env end together (50-step episodes)
    assert np.all([int(r["step"]) < 50 for r in rows])
