"""Stateful policies through every command: RecurrentPPO (``ppo_lstm``) keeps its LSTM state in evaluation, attacks,
video, ONNX export (state as graph inputs and outputs, parity over whole episodes) and serve (state in the request
and the reply), on a single-agent env and on teams (state per agent slot)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from cli_helpers import run_main
from gymnasium.utils.env_checker import check_env
from sb3_contrib import RecurrentPPO

import sbagents  # noqa: F401 (registers the env ids)
from sbagents.algos import ALGOS
from sbagents.callbacks.episodes import model_actor, play_env_episodes
from sbagents.core.experiment import resolve
from sbagents.core.zoo_config import default_config_path, lookup_entry
from sbagents.deploy.exporting import ExportChecks, export_run
from sbagents.deploy.parity import Recording, check_parity, record_episodes, state_parity
from sbagents.deploy.serving import DecisionLog, Policy, decide
from sbagents.envs.no_velocity import VELOCITY_INDICES

ENV = "sbagents/CartPoleNoVel-v1"
QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "0", "--seed", "0")
TINY = ("-params", "n_steps:16", "batch_size:32", "n_epochs:1", "n_envs:2", "policy_kwargs:{lstm_hidden_size: 16}")


@pytest.fixture(scope="module")
def lstm() -> RecurrentPPO:
    """A small RecurrentPPO on CartPoleNoVel (a few updates: its state matters, its returns do not)."""
    model = RecurrentPPO("MlpLstmPolicy", ENV, n_steps=32, batch_size=32, n_epochs=1, seed=0,
                         policy_kwargs={"lstm_hidden_size": 16})
    return model.learn(256)


def test_cartpole_no_vel_hides_the_velocities_and_keeps_cartpoles_rules() -> None:
    env = gym.make(ENV)
    check_env(env.unwrapped)
    assert env.spec is not None and env.spec.max_episode_steps == 500
    obs, _ = env.reset(seed=0)
    full = gym.make("CartPole-v1")
    full_obs, _ = full.reset(seed=0)
    for _ in range(20):
        assert np.all(obs[list(VELOCITY_INDICES)] == 0.0)
        np.testing.assert_array_equal(obs[[0, 2]], full_obs[[0, 2]])
        obs, reward, term, trunc, _ = env.step(1)
        full_obs, full_reward, full_term, full_trunc, _ = full.step(1)
        assert (reward, term, trunc) == (full_reward, full_term, full_trunc)
        if term:
            break
    assert np.any(full_obs[list(VELOCITY_INDICES)] != 0.0)


def test_ppo_lstm_is_rl_zoos_recurrent_ppo_with_its_cartpole_no_vel_entry() -> None:
    assert ALGOS["ppo_lstm"].cls is RecurrentPPO and ALGOS["ppo_lstm"].recurrent
    entry = lookup_entry(default_config_path("ppo_lstm"), ENV)
    assert entry["policy"] == "MlpLstmPolicy" and entry["n_envs"] == 8 and float(entry["n_timesteps"]) == 1e5
    assert (entry["n_steps"], entry["batch_size"], entry["n_epochs"], entry["gamma"]) == (32, 256, 20, 0.98)
    ppo = lookup_entry(default_config_path("ppo"), ENV)  # the memoryless baseline: the same entry but the LSTM
    differ = ("policy", "policy_kwargs")
    assert {k: v for k, v in ppo.items() if k not in differ} == {k: v for k, v in entry.items() if k not in differ}
    lstm_kwargs = resolve("ppo_lstm", ENV, entry, "ppo_lstm.yml").algo_kwargs["policy_kwargs"]
    ppo_kwargs = resolve("ppo", ENV, ppo, "ppo.yml").algo_kwargs["policy_kwargs"]
    assert {k: v for k, v in lstm_kwargs.items() if k not in ("lstm_hidden_size", "enable_critic_lstm")} == ppo_kwargs


def test_the_policy_protocol_carries_the_lstm_state(lstm: RecurrentPPO) -> None:
    act = model_actor(lstm)
    env = gym.make(ENV)
    obs, _ = env.reset(seed=3)
    batch = obs[None]
    _, state = act(batch, None, np.array([True]))
    assert state is not None and state[0].shape == (1, 1, 16)
    carried, _ = lstm.predict(batch, state=state, episode_start=np.array([False]), deterministic=True)
    same, _ = act(batch, state, np.array([False]))
    np.testing.assert_array_equal(same, carried)
    # an episode start resets the state: the same as a first step from zeros
    reset, _ = act(batch, state, np.array([True]))
    first, _ = lstm.predict(batch, deterministic=True)
    np.testing.assert_array_equal(reset, first)


def test_evaluation_steps_the_lstm_with_its_state(lstm: RecurrentPPO) -> None:
    """play_env_episodes gives exactly the return of a hand-written loop that carries the state."""
    episodes = play_env_episodes(gym.make(ENV), model_actor(lstm), 2, seed=5)
    env = gym.make(ENV)
    for i, record in enumerate(episodes):
        obs, _ = env.reset(seed=5 + i) if i == 0 else env.reset()
        state, start, total, done = None, np.array([True]), 0.0, False
        while not done:
            action, state = lstm.predict(obs, state=state, episode_start=start, deterministic=True)
            start = np.array([False])
            obs, reward, term, trunc, _ = env.step(action)
            total += float(reward)
            done = term or trunc
        assert record.ret == pytest.approx(total)


def test_periodic_evaluation_carries_the_lstm_state(lstm: RecurrentPPO, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The run's periodic evaluation (SB3's EvalCallback, with atomic files) passes the state the LSTM returned back
    to it and marks each episode's first step, as a hand-written loop does."""
    from stable_baselines3.common.env_util import make_vec_env

    from sbagents.callbacks.run_files import AtomicEvalCallback

    calls: list[tuple[bool, list[bool]]] = []
    real = RecurrentPPO.predict

    def spy(self: RecurrentPPO, obs: Any, state: Any = None, episode_start: Any = None,
            deterministic: bool = False) -> Any:
        calls.append((state is not None, [bool(x) for x in np.atleast_1d(episode_start)]))
        return real(self, obs, state=state, episode_start=episode_start, deterministic=deterministic)

    eval_env = make_vec_env(ENV, n_envs=1, seed=3)
    callback = AtomicEvalCallback(eval_env, eval_freq=1, n_eval_episodes=2, log_path=str(tmp_path),
                                  best_model_save_path=str(tmp_path), verbose=0)
    callback.init_callback(lstm)
    monkeypatch.setattr(RecurrentPPO, "predict", spy)
    callback.on_step()
    assert len(calls) > 2 and calls[0] == (False, [True])  # the first step: no state yet, an episode starts
    assert all(carried for carried, _ in calls[1:])  # every later step gets the state back
    assert sum(start == [True] for _, start in calls) == 2  # one start per episode
    assert (tmp_path / "evaluations.npz").is_file() and (tmp_path / "best_model.zip").is_file()


def test_onnx_export_takes_and_gives_the_state_with_parity_over_whole_episodes(lstm: RecurrentPPO,
                                                                               tmp_path: Path) -> None:
    env = gym.make(ENV)
    report = export_run(lstm, tmp_path / "export", ENV, env=env, checks=ExportChecks(n_observations=200,
                                                                                    latency_n=5))
    assert report.parity_fp32 <= 1e-4 and report.parity_state is not None and report.parity_state <= 1e-4
    assert report.n_parity_observations >= 200
    sidecar = json.loads(report.sidecar_path.read_text())
    assert sidecar["recurrent"] == {"state_inputs": ["state_h", "state_c"], "state_outputs": ["state_h_out",
                                    "state_c_out"], "start_input": "episode_start", "n_layers": 1, "hidden": 16}
    recording = record_episodes(gym.make(ENV), lstm, n=150, seed=2)
    starts = recording.starts[:, 0]
    assert starts[0] and starts.sum() >= 2  # several episodes, each from its start
    assert recording_ends_an_episode(recording, lstm)
    assert check_parity(lstm, report.onnx_path, recording) <= 1e-4
    assert state_parity(lstm, report.onnx_path, recording) <= 1e-4
    with pytest.raises(ValueError, match="whole episodes"):
        check_parity(lstm, report.onnx_path, recording.flat())


def recording_ends_an_episode(recording: Recording, model: RecurrentPPO) -> bool:
    """The step after the recording's last one starts a new episode: the recording holds whole episodes."""
    env = gym.make(ENV)
    obs, _ = env.reset(seed=2)
    act, state = model_actor(model), None
    for t in range(len(recording.observations)):
        np.testing.assert_array_equal(obs, recording.observations[t, 0])
        action, state = act(obs[None], state, recording.starts[t])
        obs, _, term, trunc, _ = env.step(int(action[0]))
        if term or trunc:
            obs, _ = env.reset()
            last_ended = True
        else:
            last_ended = False
    return last_ended


def test_serve_carries_the_state_in_requests_and_replies(lstm: RecurrentPPO, tmp_path: Path) -> None:
    """A client feeding each reply's state into its next request gets SB3's actions over whole episodes."""
    report = export_run(lstm, tmp_path / "export", ENV, env=gym.make(ENV),
                        checks=ExportChecks(n_observations=50, latency_n=5))
    policy = Policy(report.onnx_path)
    assert policy.recurrent and policy.state_size == 32
    log = DecisionLog(policy, None)
    recording = record_episodes(gym.make(ENV), lstm, n=120, seed=4)
    act, sb3_state, served_state = model_actor(lstm), None, None
    for obs, start in zip(recording.observations[:, 0], recording.starts[:, 0], strict=True):
        expected, sb3_state = act(obs[None], sb3_state, np.array([start]))
        request = {"obs": obs.tolist(), "state": None if start else served_state}
        ok, reply = decide(policy, json.dumps(request), log)
        assert ok, reply
        answer = json.loads(reply)
        assert answer["action"] == int(expected[0])
        served_state = answer["state"]
        np.testing.assert_allclose(np.asarray(served_state).reshape(2, -1),
                                   np.concatenate([s.reshape(1, -1) for s in sb3_state]), atol=1e-4)
    for bad, expected_error in (([0.0, 0.0, 0.0, 0.0], "this policy is recurrent"),
                                ({"obs": [0.0] * 4, "state": [0.0] * 3}, "state must be the 32 numbers"),
                                ({"obs": [0.0] * 4, "state": [float("nan")] * 32}, "NaN"),
                                ({"obs": [0.0] * 4, "memory": None}, "this policy is recurrent"),
                                ({"obs": [0.0] * 3, "state": None}, "expected 4 values")):
        ok, reply = decide(policy, json.dumps(bad), log)
        assert not ok and expected_error in json.loads(reply)["error"], reply
    ok, _ = decide(policy, json.dumps({"obs": [0.1, 0.0, 0.0, 0.0]}), log)  # no state: an episode starts
    assert ok


def test_ppo_lstm_through_the_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """train, evaluate (rebuilt from plain data, and with attacks), record_video, export and serve on a ppo_lstm
    run."""
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "ppo_lstm", "--env", ENV, "-n", "64", *TINY, "-f", str(logs), *QUIET) == 0
    common = ("--algo", "ppo_lstm", "--env", ENV, "-f", str(logs))
    capsys.readouterr()
    assert run_main("evaluate", *common, "-n", "2", "--json") == 0
    rebuilt = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert run_main("evaluate", *common, "-n", "2", "--json", "--trust-run") == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1]) == rebuilt
    assert run_main("evaluate", *common, "-n", "2", "--attack", "fgsm:0.05 pgd:0.05") == 0
    assert "attack.pgd_0.05.mean_return" in capsys.readouterr().out
    assert run_main("record_video", *common, "-n", "30") == 0
    assert list(logs.rglob("*.mp4"))
    assert run_main("export", *common, "--n-observations", "50") == 0
    out = capsys.readouterr().out
    assert "whole episodes, state carried" in out
    (onnx,) = logs.rglob("policy.onnx")
    from sbagents.deploy.serving import serve

    replies = io.StringIO()
    served, errors = serve(Policy(onnx), io.BytesIO(b'{"obs": [0.01, 0, 0.02, 0], "state": null}\n[1, 2, 3, 4]\n'),
                           replies)
    assert (served, errors) == (1, 1)
    first = json.loads(replies.getvalue().splitlines()[0])
    assert set(first) == {"action", "state"} and len(first["state"]) == 2 * 16


@pytest.mark.parametrize("env,params", [("treasure_hunt_v0", ()), ("mpe2.simple_tag_v3", ("policies:per_group",))])
def test_recurrent_team_runs_train_evaluate_and_export(env: str, params: tuple[str, ...], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """A team's LSTM keeps one state per agent slot (reset where that agent's episode ends); export checks it over
    whole team episodes."""
    logs = tmp_path / "logs"
    code = run_main("train", "--algo", "ppo_lstm", "--env", env, "-n", "64", "-params", "n_steps:8", "batch_size:16",
                    "n_epochs:1", "n_envs:1", "policy_kwargs:{lstm_hidden_size: 8}", *params, "-f", str(logs),
                    *QUIET)
    assert code == 0, capsys.readouterr().err
    common = ("--algo", "ppo_lstm", "--env", env, "-f", str(logs))
    capsys.readouterr()
    assert run_main("evaluate", *common, "-n", "2", "--json") == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["n_episodes"] == 2
    assert run_main("export", *common, "--n-observations", "40") == 0
    sidecars = [json.loads(p.read_text()) for p in logs.rglob("policy.json")]
    assert sidecars and all(s["recurrent"]["hidden"] == 8 for s in sidecars)
    assert all(s["report"]["parity_fp32"] <= 1e-4 and s["report"]["parity_state"] <= 1e-4 for s in sidecars)


def test_smart_home_pref_once_states_the_preferences_at_the_reset_only() -> None:
    env = gym.make("sbagents/SmartHomePrefOnce-v0")
    check_env(env.unwrapped)
    obs, info = env.reset(seed=1)
    np.testing.assert_allclose(obs[3:], [info["preferred_temp"], info["preferred_light"]], rtol=1e-6)
    for _ in range(5):
        obs, _, _, _, info = env.step(env.action_space.sample())
        assert np.all(obs[3:] == 0.0) and info["preferred_temp"] > 0.0
    plain = gym.make("sbagents/SmartHome-v0")
    assert plain.observation_space.low[3] == 18.0  # the book's env keeps its bounds
    obs, _ = plain.reset(seed=1)
    assert np.all(plain.step(plain.action_space.sample())[0][3:] > 0.0)
    with pytest.raises(ValueError, match="preference_steps"):
        gym.make("sbagents/SmartHome-v0", preference_steps=-1)
