"""Training any PettingZoo env through the library, on the user env package ``tests/user_envs/tiny_marl_pkg``
(``relay_v0``: a scout with a 4-number observation that leaves after 5 steps, two workers with 3 numbers, all in
``Discrete(3)``; reward 1 per step for acting on one's cue, so the optimal team return is 5 + 10 + 10 = 25 and
random play gets a third of it).

Every policy mode learns (shared with padding, per_group, per_agent; PPO and A2C; DQN shared; the centralized
critic), the run dir holds one model per group and exports one ONNX policy per group, absent agents take no
learning signal (the masked buffers), the copies can run in worker processes with identical results, and the trust
callbacks count present agents only.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import pytest
from cli_helpers import check_error, run_main
from gymnasium import spaces
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.api import (
    EvalOptions,
    ExecOptions,
    OutputOptions,
    RunRef,
    Sb3Options,
    TrainSpec,
    evaluate,
    export_groups,
    train,
)
from sbagents.callbacks.extension import TrustOptions
from sbagents.core.team_options import TeamOptions
from sbagents.extensions import TrainingExtension, register_extension, unregister_extension
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs
from sbagents.multiagent.masking import ActedMaskCallback, MaskedReplayBuffer, MaskedRolloutBuffer
from sbagents.registration import PETTINGZOO_ENVS

USER_ENVS = Path(__file__).resolve().parent / "user_envs"
RELAY = "tiny_marl_pkg.relay_v0"
OPTIMAL = 25.0
PPO_PARAMS = {"n_envs": 4, "n_steps": 32, "batch_size": 128, "n_epochs": 4, "learning_rate": 3e-3,
              "policy_kwargs": {"net_arch": [32]}}
A2C_PARAMS = {"n_envs": 4, "n_steps": 8, "learning_rate": 3e-3, "policy_kwargs": {"net_arch": [32]}}
DQN_PARAMS = {"n_envs": 4, "learning_starts": 500, "buffer_size": 20000, "batch_size": 64, "learning_rate": 1e-3,
              "train_freq": 1, "gradient_steps": 1, "target_update_interval": 250, "exploration_fraction": 0.3,
              "policy_kwargs": {"net_arch": [32]}}
PARAMS = {"ppo": PPO_PARAMS, "a2c": A2C_PARAMS, "dqn": DQN_PARAMS}


@pytest.fixture(scope="module", autouse=True)
def user_envs() -> Iterator[None]:
    """``tests/user_envs`` on ``sys.path`` for this module (the user's package, importable by name)."""
    saved = dict(PETTINGZOO_ENVS)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(USER_ENVS))
        yield
    PETTINGZOO_ENVS.clear()
    PETTINGZOO_ENVS.update(saved)


def quiet(folder: Path, seed: int = 0, episodes: int = 20) -> tuple[Any, ...]:
    return OutputOptions(folder), EvalOptions(eval_freq=-1, final_eval_episodes=episodes), \
        ExecOptions(seed=seed, verbose=0)


def relay_run(folder: Path, algo: str, n: int = 7500, **team: Any) -> Any:
    """A relay run on ``n`` agent steps (every mode reached the optimal 25 at 4,000 here: about a 2x margin)."""
    return train(TrainSpec(algo, RELAY, n, {**PARAMS[algo], **team}), *quiet(folder))


@pytest.fixture(scope="module")
def relay_runs(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, str], tuple[Path, Any]]:
    """Train once, read many: each (algo, policies) relay run trained at most once for this module; a test that
    writes into a run copies its folder first."""
    runs: dict[tuple[str, str], tuple[Path, Any]] = {}

    def get(algo: str, policies: str) -> tuple[Path, Any]:
        if (algo, policies) not in runs:
            folder = tmp_path_factory.mktemp(f"relay_{algo}_{policies}")
            runs[algo, policies] = folder, relay_run(folder, algo, policies=policies)
        return runs[algo, policies]

    return get


@pytest.mark.parametrize(("algo", "policies"), [("ppo", "shared"), ("ppo", "per_group"), ("ppo", "per_agent"),
                                                ("a2c", "shared"), ("a2c", "per_group"), ("a2c", "per_agent"),
                                                ("dqn", "shared")])
def test_every_policy_mode_learns_the_relay(relay_runs: Callable[[str, str], tuple[Path, Any]], algo: str,
                                            policies: str) -> None:
    folder, result = relay_runs(algo, policies)
    files = sorted(p.name for p in result.run_dir.glob("relay_v0*.zip"))
    expected = {"shared": ["relay_v0.zip"], "per_group": ["relay_v0.scout.zip", "relay_v0.worker.zip"],
                "per_agent": ["relay_v0.scout_0.zip", "relay_v0.worker_0.zip", "relay_v0.worker_1.zip"]}
    assert files == expected[policies]
    summary = evaluate(RunRef(algo, RELAY, folder))
    assert summary["mean_return"] >= OPTIMAL - 1, summary
    per_agent = summary["metrics"]["per_agent_return"]
    assert per_agent["scout_0"] <= 5 and per_agent["worker_0"] <= 10  # real steps only: the scout acts 5 times
    assert summary["metrics"]["episode_length"] == 10
    assert summary["metrics"]["correct"] == pytest.approx(summary["mean_return"])  # the declared info metric
    if policies == "per_group":
        assert set(summary["metrics"]["per_group_return"]) == {"scout", "worker"}


def test_centralized_critic_learns_and_exports_its_actor(tmp_path: Path) -> None:
    result = relay_run(tmp_path, "ppo", critic="centralized", agent_id=True)
    model = result.model
    assert isinstance(model.observation_space, spaces.Dict)
    obs_dim, state_dim = model.observation_space["obs"].shape[0], model.observation_space["state"].shape[0]
    assert (obs_dim, state_dim) == (4 + 2 + 3, 10 + 3)  # padded obs + space one-hot + agent id; state + agent id
    assert model.policy.mlp_extractor.policy_net[0].in_features == obs_dim
    assert model.policy.mlp_extractor.value_net[0].in_features == state_dim
    assert result.summary["eval"]["mean_return"] >= OPTIMAL - 1
    report = export_groups(RunRef("ppo", RELAY, tmp_path), n_observations=200)["shared"]
    assert report.parity_fp32 <= 1e-6
    session = ort.InferenceSession(str(report.onnx_path), providers=["CPUExecutionProvider"])
    assert session.get_inputs()[0].shape[1] == obs_dim  # the actor alone: no state needed to act
    sidecar = json.loads(report.sidecar_path.read_text())
    assert sidecar["observation_space"]["shape"] == [obs_dim]


def test_each_group_of_a_run_is_recorded_and_cloned_into_its_own_model(
        relay_runs: Callable[[str, str], tuple[Path, Any]], datasets: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``collect --group`` records one group's agents of a run of one model per group (every group acts, each with
    its own model and spaces); ``train --pretrain GROUP=DATASET`` clones each group's model from its dataset, and the
    cloned team plays about as well as the run it was recorded from before RL changes it (learning rate 1e-6)."""
    folder, _ = relay_runs("ppo", "per_group")
    for group in ("scout", "worker"):
        assert run_main("collect", "--algo", "ppo", "--env", RELAY, "-f", str(folder), "--group", group,
                        "--episodes", "20", "--dataset", f"sbagents/relay-{group}-v0") == 0
    out = capsys.readouterr().out  # 20 team episodes: one scout, two workers each
    assert "relay-scout-v0: 20 episodes in" in out and "relay-worker-v0: 40 episodes in" in out
    logs = tmp_path / "logs"
    params = ("-params", "policies:per_group", "n_envs:4", "n_steps:32", "batch_size:128", "learning_rate:1e-6")
    quiet_flags = ("--eval-freq", "-1", "--final-eval-episodes", "10", "--seed", "1", "--verbose", "0")
    assert run_main("train", "--algo", "ppo", "--env", RELAY, *params, "--pretrain", "scout=sbagents/relay-scout-v0",
                    "--pretrain", "worker=sbagents/relay-worker-v0", "-n", "256", "-f", str(logs), *quiet_flags) == 0
    summary = json.loads(next(logs.rglob("summary.json")).read_text())
    by_group = summary["by_group"]
    assert {g: by_group[g]["pretrain"]["n_train"] + by_group[g]["pretrain"]["n_holdout"] for g in by_group} == {
        "scout": 100, "worker": 400}  # 20 x 5 scout steps, 20 x 2 x 10 worker steps
    assert summary["eval"]["mean_return"] >= OPTIMAL - 2  # random play: about a third of 25
    capsys.readouterr()
    for args, expected in [
        (("--pretrain", "boss=sbagents/relay-scout-v0", *params), "boss is not one of this run's (relay_v0: its "
                                                                  "groups are scout, worker)"),
        (("--pretrain", "scout=sbagents/relay-scout-v0"), "relay_v0: it trains one model"),
        (("--pretrain", "sbagents/relay-scout-v0", "--pretrain", "sbagents/relay-worker-v0", *params),
         "--pretrain takes one DATASET for every model, and GROUP=DATASET once per group"),
        (("--pretrain", "worker=sbagents/relay-scout-v0", *params), "is not the env's"),
    ]:
        check_error(run_main("train", "--algo", "ppo", "--env", RELAY, *args, "-n", "128", "-f",
                             str(tmp_path / "bad"), *quiet_flags), capsys.readouterr().err, expected)
    check_error(run_main("collect", "--algo", "ppo", "--env", RELAY, "-f", str(folder), "--episodes", "1",
                         "--dataset", "sbagents/relay-v9"), capsys.readouterr().err,
                "relay_v0 has the groups scout, worker: --group NAME records one of them")


def test_per_group_run_exports_one_policy_per_group(relay_runs: Callable[[str, str], tuple[Path, Any]],
                                                   tmp_path: Path) -> None:
    shutil.copytree(relay_runs("ppo", "per_group")[0], tmp_path, dirs_exist_ok=True)  # the export writes into it
    reports = export_groups(RunRef("ppo", RELAY, tmp_path), int8=True, n_observations=200)
    assert set(reports) == {"scout", "worker"}
    for group, report in reports.items():
        assert report.onnx_path.parent.name == group and report.onnx_path.exists()
        assert report.parity_fp32 == 0.0 and report.int8_acceptable
    scout = ort.InferenceSession(str(reports["scout"].onnx_path), providers=["CPUExecutionProvider"])
    assert scout.get_inputs()[0].shape[1] == 4  # per_group: each group's own, unpadded observation


def test_subprocess_copies_train_exactly_like_local_ones(tmp_path: Path) -> None:
    runs = []
    for vec_env in ("dummy", "subproc"):
        folder = tmp_path / vec_env
        result = train(TrainSpec("ppo", RELAY, 1024, PPO_PARAMS), *quiet(folder, episodes=5),
                       sb3=Sb3Options(vec_env=vec_env))
        runs.append(result)
    local, remote = (r.model.policy.state_dict() for r in runs)
    assert all(np.array_equal(local[k].numpy(), remote[k].numpy()) for k in local)
    assert runs[0].summary["eval"] == runs[1].summary["eval"]


def _relay_venv(n_envs: int = 2, policies: str = "shared") -> Any:
    factory = ParallelEnvFactory(RELAY, (), {}, [])
    return team_vec_envs(factory, n_envs, TeamOptions(policies), seed=0)


def test_rollout_minibatches_hold_acted_transitions_only() -> None:
    venv = _relay_venv()["shared"]
    model = PPO("MlpPolicy", venv, n_steps=20, batch_size=10, n_epochs=1, seed=0,
                rollout_buffer_class=MaskedRolloutBuffer)
    buffer = model.rollout_buffer
    model.learn(20 * venv.num_envs, callback=ActedMaskCallback())
    assert isinstance(buffer, MaskedRolloutBuffer)
    # slots: (copy 0: scout, worker, worker), (copy 1: ...); 20 steps = two 10-step episodes; the scout acts 5 of 10
    scout_acted = buffer.acted[:, [0, 3]]
    assert scout_acted[:, 0].tolist() == [True] * 5 + [False] * 5 + [True] * 5 + [False] * 5
    assert buffer.acted[:, [1, 2, 4, 5]].all()
    drawn = np.concatenate([s.observations.numpy() for s in buffer.get(batch_size=7)])
    assert len(drawn) == int(buffer.acted.sum()) == 20 * 6 - 2 * 10
    # absent slots carry the all-zero padded observation, with the scout's "agent type" marker at index 4
    assert not np.any((drawn[:, :4].sum(axis=1) == 0) & (drawn[:, 4] == 1))
    venv.close()


def test_replay_samples_never_hold_absent_agents() -> None:
    venv = _relay_venv()["shared"]
    model = DQN("MlpPolicy", venv, learning_starts=10_000, buffer_size=1000, seed=0,
                replay_buffer_class=MaskedReplayBuffer)
    model.learn(60 * venv.num_envs)
    buffer = model.replay_buffer
    assert isinstance(buffer, MaskedReplayBuffer)
    assert buffer.acted[:60, [1, 2, 4, 5]].all() and buffer.acted[:60, 0].sum() == 30
    samples = buffer.sample(2000)
    obs = samples.observations.numpy()
    assert not np.any((obs[:, :4].sum(axis=1) == 0) & (obs[:, 4] == 1))
    venv.close()


def test_per_group_trust_files_count_present_agents_only(tmp_path: Path) -> None:
    trust = TrustOptions(transparency_log="", safety=True)
    result = train(TrainSpec("ppo", RELAY, 1024, {**PPO_PARAMS, "policies": "per_group"}), *quiet(tmp_path),
                   features=[trust])
    with (result.run_dir / "transparency.scout.csv").open() as f:
        scout_rows = list(csv.DictReader(f))
    with (result.run_dir / "transparency.worker.csv").open() as f:
        worker_rows = list(csv.DictReader(f))
    steps = 96  # 1024 agent steps = 86 team steps of 4 copies x 3 agents, rounded up to whole 32-step rollouts
    assert {r["agent"] for r in scout_rows} == {"scout_0"}
    assert len(worker_rows) == 4 * 2 * steps
    assert len(scout_rows) == 4 * (9 * 5 + 5)  # present in steps 0-4 of each 10-step episode (9 done, 1 begun)
    assert {r["step"] for r in scout_rows} == {"0", "1", "2", "3", "4"}
    assert max(int(r["episode"]) for r in scout_rows) == 9  # one scout episode per team episode, not two
    safety = json.loads((result.run_dir / "safety.scout.json").read_text())
    assert safety["total_steps"] == len(scout_rows)
    assert safety["episodes"] == 4 * 9


TEAM_ERRORS = [
    (["--env", "os.path"], "module os.path has no parallel_env(**kwargs)"),
    (["--env", f"{RELAY}:nope"], f"'nope' is neither a Gymnasium ID registered by {RELAY} nor a function in it"),
    (["--env", "tiny_marl_pkg.aec_only_v0"], "is a turn-based env without action masks"),
    (["--env", "tiny_marl_pkg.variants:grid_scout"],
     "the observation spaces of scout_0, worker_0, worker_1 differ; use policies: per_group or per_agent"),
    (["--env", "tiny_marl_pkg.variants:steering_scout"],
     "the action spaces of scout_0, worker_0, worker_1 differ; use policies: per_group or per_agent"),
    (["--env", "tiny_marl_pkg.variants:steering_scout", "-params", "policies:per_group"],
     "dqn cannot learn group scout of tiny_marl_pkg.variants:steering_scout (observation Box, action Box); algos "
     "that can:"),
    (["--env", "tiny_marl_pkg.variants:stateless", "--algo", "ppo", "-params", "critic:centralized"],
     "critic: centralized needs the env's global state()"),
    (["--env", RELAY, "-params", "critic:centralized"], "critic: centralized is for a2c and ppo"),
    (["--env", RELAY, "-params", "policies:everyone"], "policies must be one of shared, per_agent, per_group"),
    (["--env", RELAY, "-params", "agent_id:3"], "agent_id must be true or false, got 3"),
    (["--env", RELAY, "-params", "monitor_kwargs:{}"], "monitor_kwargs apply to Gymnasium envs only"),
    (["--env", RELAY, "-params", "eval_env_kwargs:{max_cycles: 5}"], "eval_env_kwargs apply to Gymnasium envs only"),
    (["--env", RELAY, "--algo", "ppo", "-params", "policies:per_group", "--adversarial-eval", "gaussian:0.1"],
     "--adversarial-eval and --fairness support policies: shared"),
    (["--env", RELAY, "--env-kwargs", "scout_steps:0"],
     "cannot create relay_v0 with env kwargs scout_steps=0: scout_steps must be >= 1"),
    (["--env", RELAY, "--env-kwargs", "speed:2"], "unknown env kwarg(s) speed for relay_v0; accepted: max_cycles"),
    (["--env", RELAY, "--vec-env", "batched"], "--vec-env batched supports"),
]


@pytest.mark.parametrize(("args", "expected"), TEAM_ERRORS, ids=[" ".join(a) for a, _ in TEAM_ERRORS])
def test_bad_team_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str],
                                    expected: str) -> None:
    code = run_main("train", "--algo", "dqn", "-n", "64", "-f", str(tmp_path / "logs"), *args)
    check_error(code, capsys.readouterr().err, expected)
    assert not list((tmp_path / "logs").glob("*/*")), "a run dir was left behind"


def test_a_groups_mapping_must_name_every_agent_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf = tmp_path / "groups.yml"
    conf.write_text(f"{RELAY}:\n  n_timesteps: 64\n  policy: MlpPolicy\n  policies: per_group\n"
                    "  groups: {eyes: [scout_0], hands: [worker_0, worker_9]}\n")
    code = run_main("train", "--algo", "ppo", "--env", RELAY, "-conf", str(conf), "-f", str(tmp_path / "logs"))
    check_error(code, capsys.readouterr().err, "groups must name every agent once (missing: worker_1; unknown: "
                "worker_9); the env's agents: scout_0, worker_0, worker_1")
    assert not list((tmp_path / "logs").glob("*/*"))


def test_group_spaces_are_checked_before_a_run_dir_exists(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    code = run_main("train", "--algo", "dqn", "-n", "64", "-f", str(logs), "--env",
                    "tiny_marl_pkg.variants:steering_scout", "-params", "policies:per_group")
    check_error(code, capsys.readouterr().err, "dqn cannot learn group scout")
    assert not logs.exists()  # refused in the plan: not even the log folder was made


class _SigintAt(BaseCallback):
    """Sends this process a Ctrl-C at the ``at``-th step of the model it runs in, and waits until the main thread
    has handled it (the run's clock has a stop requested), so the step it stops at does not depend on when the main
    thread gets to run."""

    def __init__(self, at: int) -> None:
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.n_calls == self.at:
            clock = signal.getsignal(signal.SIGINT).__self__  # type: ignore[union-attr]  # the run's LearningClock
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(3000):  # at most 30 s
                if clock.stop_requested:
                    break
                time.sleep(0.01)
            assert clock.stop_requested
        return True


def test_a_per_group_run_stops_gracefully_and_saves_every_model(tmp_path: Path) -> None:
    """The first Ctrl-C stops every group's model between two team steps (the graceful clock of every run), and
    each model and its statistics are saved."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # a suite started with & ignores SIGINT
    try:
        result = train(TrainSpec("ppo", RELAY, 100_000, {**PPO_PARAMS, "policies": "per_group", "normalize": True}),
                       *quiet(tmp_path), callbacks=[_SigintAt(40)])
    finally:
        signal.signal(signal.SIGINT, before)
    assert result.interrupted
    summary = json.loads((result.run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["eval"] is None
    assert set(result.models) == {"scout", "worker"}
    # the scout's model stops at its poll in the team step after the signal (step 41 of 4 copies), and the workers'
    # (2 per copy) with it, before they take that step: not after some later Ctrl-C check
    assert {g: m.num_timesteps for g, m in result.models.items()} == {"scout": 41 * 4, "worker": 40 * 8}
    for group, model in result.models.items():
        assert PPO.load(result.run_dir / f"relay_v0.{group}.zip").num_timesteps == model.num_timesteps
        assert (result.run_dir / f"vecnormalize.{group}.npz").is_file()


@dataclass(frozen=True)
class _JudgeSpec:
    """The spec of :class:`_Judge` (no settings)."""


class _Judge(TrainingExtension[_JudgeSpec]):
    """Records what the pipeline hands each model: its group in ``finish`` and the final evaluation it judges."""

    name = "judge-test"
    flags = "--judge-test"
    spec_type = _JudgeSpec

    def finish(self, spec: _JudgeSpec, ctx: Any) -> dict[str, Any]:
        return {"judge": {"group": ctx.group}}

    def judge(self, spec: _JudgeSpec, summary: dict[str, Any], evaluation: Mapping[str, Any]) -> None:
        summary["judge"]["judged_episodes"] = evaluation["n_episodes"]


def test_every_group_model_judges_the_final_evaluation(tmp_path: Path) -> None:
    register_extension(_Judge())
    try:
        result = train(TrainSpec("ppo", RELAY, 1024, {**PPO_PARAMS, "policies": "per_group"}),
                       *quiet(tmp_path, episodes=3), features=[_JudgeSpec()])
    finally:
        unregister_extension(_Judge.name)
    summary = json.loads((result.run_dir / "summary.json").read_text())
    assert summary["by_group"] == {"scout": {"judge": {"group": "scout", "judged_episodes": 3}},
                                   "worker": {"judge": {"group": "worker", "judged_episodes": 3}}}


def test_minus_i_continues_every_group_model_of_a_per_group_run(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """``-i`` with one group's model (final, best or checkpoint) continues every group's model from the files beside
    it, with the VecNormalize statistics saved with each; anything else is refused in one line."""
    params = {**PPO_PARAMS, "policies": "per_group", "normalize": True}
    first = train(TrainSpec("ppo", RELAY, 1024, params), OutputOptions(tmp_path, save_freq=512),
                  EvalOptions(eval_freq=-1, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    before = {g: m.num_timesteps for g, m in first.models.items()}
    stats = {g: np.load(first.run_dir / f"vecnormalize.{g}.npz")["ret_rms/count"] for g in before}
    again = train(TrainSpec("ppo", RELAY, 1024, params, trained_agent=first.run_dir / "relay_v0.worker.zip"),
                  OutputOptions(tmp_path), EvalOptions(eval_freq=-1, final_eval_episodes=0),
                  ExecOptions(seed=0, verbose=0))
    assert again.run_dir != first.run_dir
    for group, model in again.models.items():  # each group's model went on from its own step and statistics
        assert model.num_timesteps > before[group]
        loaded = np.load(again.run_dir / f"vecnormalize.{group}.npz")["ret_rms/count"]
        assert float(loaded) > float(stats[group])
    # fps counts the steps of this run only. fps is rounded to 0.1 and train_seconds to 0.001, so fps x train_seconds
    # is off by up to 0.05 x train_seconds + 0.0005 x fps steps (4 steps at 8000 steps/s: this run takes ~0.25 s)
    s = again.summary
    assert s["n_timesteps"] - s["fps"] * s["train_seconds"] == pytest.approx(
        sum(before.values()), abs=0.05 * s["train_seconds"] + 0.0005 * s["fps"] + 0.01)
    checkpoint = min(first.run_dir.glob("rl_model.scout_*_steps.zip"), key=lambda p: int(p.name.split("_")[-2]))
    steps = {g: int(checkpoint.name.split("_")[-2]) if g == "scout" else
             int(next(first.run_dir.glob("rl_model.worker_*_steps.zip")).name.split("_")[-2]) for g in before}
    assert steps["scout"] < before["scout"]  # an earlier model than the final one
    resumed = train(TrainSpec("ppo", RELAY, 128, params, trained_agent=checkpoint), OutputOptions(tmp_path),
                    EvalOptions(eval_freq=-1, final_eval_episodes=0), ExecOptions(seed=0, verbose=0))
    trained = {g: resumed.models[g].num_timesteps - steps[g] for g in before}
    assert all(0 < trained[g] < again.models[g].num_timesteps - before[g] for g in before), trained
    for bad, expected in [(first.run_dir / "vecnormalize.scout.npz", "--trained-agent"),
                          (first.run_dir / "relay_v0.zip", "this run trains one model per group (scout, worker)")]:
        if bad.name == "relay_v0.zip":
            shutil.copy(first.run_dir / "relay_v0.scout.zip", bad)
        code = run_main("train", "--algo", "ppo", "--env", RELAY, "-f", str(tmp_path), "-i", str(bad),
                        "-params", "policies:per_group", "--verbose", "0")
        check_error(code, capsys.readouterr().err, expected)
