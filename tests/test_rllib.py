"""The Ray RLlib backend: ``python -m sbagents.train --backend rllib`` on TreasureHunt, and evaluate on its run dir.

The flag checks run everywhere; the training tests need Ray (``pip install -e ".[test,distributed]"``, which
``.ci/run`` does in a venv of its own, with ``SBAGENTS_REQUIRE_RAY=1`` so that a missing Ray fails instead of
skipping) and start a local Ray instance (2 env runners, or sampling in the driver).
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import cli, last_json, popen, summary

from sbagents.errors import UsageError
from sbagents.rllib import CHECKPOINT_DIR, NEEDS_RAY, PROGRESS_FILE, is_rllib_run, ray_available

RUN = "treasure_hunt_v0"
SMALL = ["-params", "train_batch_size_per_learner:1000", "minibatch_size:256", "num_envs_per_env_runner:2"]
needs_ray = pytest.mark.skipif(
    not ray_available() and not os.environ.get("SBAGENTS_REQUIRE_RAY"),
    reason="needs Ray RLlib: pip install -e '.[test,distributed]' (.ci/run runs these in a venv of their own)",
)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--address", "auto"], "need --backend rllib"),
        (["--num-env-runners", "2"], "need --backend rllib"),
        (["--backend", "rllib", "--algo", "ppo", "--env", RUN, "--num-env-runners", "-1"], ">= 0"),
        (["--backend", "rllib", "--algo", "dqn", "--env", RUN], "supports --algo ppo"),
        (["--backend", "rllib", "--algo", "ppo", "--env", RUN, "--address", "127.0.0.1:1"], "cannot reach the Ray"),
        (["--backend", "rllib", "--algo", "ppo", "--env", RUN, "--safety", "-i", "x.zip"],
         "-i/--trained-agent, --safety not supported"),
        (["--backend", "rllib", "--algo", "ppo", "--env", RUN, "--vec-env", "dummy", "--log-interval", "5"],
         "--vec-env, --log-interval not supported with --backend rllib"),
    ],
)
def test_bad_flag_combinations_are_one_line_errors(args: list[str], message: str) -> None:
    result = cli("train", *args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr


@needs_ray
def test_non_pettingzoo_env_is_rejected_before_ray_starts() -> None:
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", "sbagents/GridWorld-v0")
    assert result.returncode == 2 and "trains PettingZoo envs (e.g. treasure_hunt_v0" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_without_ray_the_backend_says_how_to_install_it(tmp_path: Path) -> None:
    fake = tmp_path / "site" / "ray"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('no ray here')\n")
    env = {**os.environ, "PYTHONPATH": f"{tmp_path / 'site'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    # a subprocess on purpose: Ray must be missing (a fake package first on PYTHONPATH), which a process that has
    # imported it cannot simulate
    result = subprocess.run([sys.executable, "-m", "sbagents.train", "--backend", "rllib", "--algo", "ppo", "--env",
                             RUN, "-f", str(tmp_path)], capture_output=True, text=True, env=env, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip() == f"python -m sbagents.train: error: {NEEDS_RAY}"
    assert not (tmp_path / "ppo").exists()


@needs_ray
def test_zoo_entry_is_validated_and_lr_schedule_resolved() -> None:
    from sbagents.rllib.experiment import resolve_entry

    exp = resolve_entry("ppo", RUN, {"n_timesteps": 1000, "lr": "lin_0.003", "policies": "per_agent"}, "f.yml")
    assert exp.training["lr"] == [[0, 0.003], [1000, 0.0]] and exp.policies == "per_agent"
    with pytest.raises(UsageError, match=r"f\.yml: unknown key\(s\) learning_rate; accepted: n_timesteps"):
        resolve_entry("ppo", RUN, {"learning_rate": 0.1}, "f.yml")
    with pytest.raises(UsageError, match="unknown model key"):
        resolve_entry("ppo", RUN, {"model": {"net_arch": [64]}}, "f.yml")
    with pytest.raises(UsageError, match="policies must be one of shared, per_agent"):
        resolve_entry("ppo", RUN, {"policies": "mixed"}, "f.yml")


@needs_ray
def test_shipped_rllib_configs_resolve() -> None:
    from sbagents.core.zoo_config import load_yaml
    from sbagents.rllib.experiment import resolve_entry

    paths = sorted((Path(__file__).resolve().parents[1] / "zoo_configs").glob("rllib_*.yml"))
    assert paths
    for path in paths:
        for env_id, entry in load_yaml(path).items():
            exp = resolve_entry(path.stem.removeprefix("rllib_"), env_id, dict(entry), str(path))
            assert exp.n_timesteps > 0 and exp.model.get("vf_share_layers") is False, (path, env_id)


def _progress(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / PROGRESS_FILE).open() as f:
        return list(csv.DictReader(f))


@needs_ray
@pytest.mark.slow  # a local Ray cluster (~13 s here)
def test_local_cluster_two_env_runners_run_dir_and_evaluation(tmp_path: Path) -> None:
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", RUN, "-n", "3000", "--num-env-runners",
                 "2", "-f", str(tmp_path), "--seed", "3", "--eval-freq", "2000", "--save-freq", "1000", "--verbose",
                 "0", *SMALL)
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    assert is_rllib_run(run_dir)
    for name in ("command.txt", "summary.json", PROGRESS_FILE, f"{RUN}/config.yml", f"{RUN}/args.yml",
                 f"{CHECKPOINT_DIR}/learner_group/learner/rl_module/shared/module_state.pkl"):
        assert (run_dir / name).exists(), name
    s = summary(run_dir)
    assert s["backend"] == "rllib" and s["num_env_runners"] == 2 and s["seed"] == 3 and s["policies"] == "shared"
    assert s["interrupted"] is False and s["n_timesteps"] >= 3000 and s["n_agent_steps"] == 3 * s["n_timesteps"]
    fps = s["n_timesteps"] / s["train_seconds"]
    assert s["iterations"] == 3 and s["fps"] == pytest.approx(fps, rel=1e-3, abs=0.06)  # fps is rounded to 0.1
    assert s["eval"]["n_episodes"] == 10
    assert set(s["eval"]["metrics"]) == {"treasures_collected", "per_agent_return", "episode_length"}
    rows = _progress(run_dir)
    assert [int(r["env_steps"]) for r in rows] == [1000, 2000, 3000]
    assert rows[1]["eval_treasures_collected"] != "" and math.isfinite(float(rows[-1]["shared/policy_loss"]))
    # --save-freq 1000: a module checkpoint after 1000 and 2000 env steps (3000 is the final rllib_checkpoint)
    assert [r["checkpoint"] for r in rows] == ["checkpoint_1000", "checkpoint_2000", ""]
    assert sorted(p.name for p in run_dir.glob("checkpoint_*")) == ["checkpoint_1000", "checkpoint_2000"]
    seconds = [float(r["train_seconds"]) for r in rows]
    assert 0 < seconds[0] < seconds[1] < seconds[2] <= s["train_seconds"]
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import EvaluateOptions
    from sbagents.rllib.evaluation import evaluate_checkpoint

    early = evaluate_checkpoint(run_dir / "checkpoint_1000", resolve_env(RUN), "ppo", {"observation": "egocentric"},
                                None, EvaluateOptions(n_episodes=2, seed=0))
    assert early["n_episodes"] == 2 and math.isfinite(early["mean_return"])
    args = (run_dir / RUN / "args.yml").read_text()
    assert "backend: rllib" in args and "seed: 3" in args
    report = last_json(cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "-n", "4", "--json").stdout)
    assert report["n_episodes"] == 4 and report["env"] == RUN and report["algo"] == "ppo"
    assert all(math.isfinite(report[k]) for k in ("mean_return", "std_return", "mean_length"))
    treasures = report["metrics"]["treasures_collected"]
    assert 0 <= treasures <= 5 and (4 * treasures).is_integer()  # the mean of 4 whole-treasure episodes
    assert sum(report["metrics"]["per_agent_return"].values()) == pytest.approx(report["mean_return"])
    assert report["mean_length"] <= 50
    again = last_json(cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "-n", "4", "--json").stdout)
    assert again == report  # greedy + seeded env: reproducible
    best = cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "--load-best")
    assert best.returncode == 2 and "--load-best not supported for RLlib runs" in best.stderr
    checkpoint = cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "--load-checkpoint", "1000")
    assert checkpoint.returncode == 2 and "--load-checkpoint not supported for RLlib runs" in checkpoint.stderr


@needs_ray
@pytest.mark.slow  # a Ray run in a subprocess (~19 s here)
def test_per_agent_policies_and_sigterm_leave_an_evaluable_checkpoint(tmp_path: Path) -> None:
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import EvaluateOptions
    from sbagents.rllib.evaluation import evaluate_run, load_modules

    # a subprocess on purpose: the run is stopped by SIGTERM mid-training
    proc = popen("train", "--backend", "rllib", "--algo", "ppo", "--env", RUN, "-n", "1000000", "--num-env-runners",
                 "0", "-f", str(tmp_path), "--seed", "1", "--eval-freq", "-1", "--verbose", "0", *SMALL,
                 "policies:per_agent")
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if (run_dir / PROGRESS_FILE).exists() and len(_progress(run_dir)) >= 2:
            break
        time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()[1]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["interrupted"] is True and s["eval"] is None and 2000 <= s["n_timesteps"] < 1_000_000
    assert s["policies"] == "per_agent" and s["num_env_runners"] == 0
    modules = load_modules(run_dir / CHECKPOINT_DIR)
    assert sorted(modules) == ["agent_0", "agent_1", "agent_2"]
    assert "agent_2/policy_loss" in _progress(run_dir)[0]
    report = evaluate_run(run_dir, "ppo", resolve_env(RUN), EvaluateOptions(n_episodes=2, seed=0))
    assert report["n_episodes"] == 2 and math.isfinite(report["mean_return"])


@needs_ray
@pytest.mark.slow  # two Ray runs (~25 s here)
def test_any_pettingzoo_env_per_group_and_shared(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 request: pytest.FixtureRequest) -> None:
    """The user package's heterogeneous relay_v0 (a scout that leaves early) trains one RLModule per group, and
    mpe2.simple_spread_v3 trains with its shipped entry; evaluate reads both like SB3 runs."""
    from sbagents.registration import PETTINGZOO_ENVS
    from sbagents.rllib.evaluation import load_modules

    user_envs = Path(__file__).resolve().parent / "user_envs"
    # in this process the working folder is not on sys.path as with ``python -m``: put the user's package there
    # for this test only, and leave the env registry as it was
    monkeypatch.syspath_prepend(str(user_envs))
    saved = dict(PETTINGZOO_ENVS)
    request.addfinalizer(lambda: (PETTINGZOO_ENVS.clear(), PETTINGZOO_ENVS.update(saved)))
    logs = tmp_path / "logs"
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", "tiny_marl_pkg.relay_v0", "-n", "2000",
                 "--num-env-runners", "0", "-f", str(logs), "--seed", "1", "--eval-freq", "-1", "--verbose", "0",
                 "-params", "policies:per_group", "train_batch_size_per_learner:1000", "minibatch_size:250",
                 cwd=user_envs)
    assert result.returncode == 0, result.stderr
    run_dir = logs / "ppo" / "relay_v0_1"
    assert sorted(load_modules(run_dir / CHECKPOINT_DIR)) == ["scout", "worker"]
    report = last_json(cli("evaluate", "--algo", "ppo", "--env", "tiny_marl_pkg.relay_v0", "-f", str(logs), "-n",
                           "6", "--json", cwd=user_envs).stdout)
    metrics = report["metrics"]
    assert set(metrics["per_group_return"]) == {"scout", "worker"} and metrics["episode_length"] == 10
    assert 0 <= metrics["per_agent_return"]["scout_0"] <= 5 and 0 <= metrics["per_agent_return"]["worker_0"] <= 10
    assert metrics["correct"] == pytest.approx(report["mean_return"])  # one correct action = reward 1

    spread = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-n", "3200",
                 "--num-env-runners", "0", "-f", str(logs), "--seed", "2", "--eval-freq", "-1", "--verbose", "0")
    assert spread.returncode == 0, spread.stderr
    s = summary(logs / "ppo" / "simple_spread_v3_1")
    assert s["policies"] == "shared" and s["n_agent_steps"] == 3 * s["n_timesteps"] >= 3 * 3200
    report = last_json(cli("evaluate", "--algo", "ppo", "--env", "mpe2.simple_spread_v3", "-f", str(logs), "-n",
                           "3", "--json").stdout)
    assert report["mean_length"] == 25 and sorted(report["metrics"]["per_agent_return"]) == [
        "agent_0", "agent_1", "agent_2"]


@pytest.mark.parametrize("env", ["mpe2.simple_spread_v3", "treasure_hunt_v0"])
def test_rllib_benchmark_sections_match_their_results(env: str) -> None:
    """BENCHMARKS.md's RLlib sections are what ``python -m benchmarks render rllib-<env>`` makes of the results
    (no Ray needed), and every recorded seed ran to the end."""
    from benchmarks.harness import registry
    from benchmarks.learning.rllib_learning import env_name

    bench = registry()[f"rllib-{env_name(env)}"]
    result = bench.load(bench.results_path)
    assert bench.render(result) in (Path(__file__).resolve().parent.parent / "BENCHMARKS.md").read_text()
    assert len(result["runs"]) == 3 and all(not r["interrupted"] for r in result["runs"])


@needs_ray
def test_lean_env_runner_samples_what_rllib_samples() -> None:
    """LeanMultiAgentEnvRunner (the backend's env runner) returns the episodes and step counts RLlib's own
    MultiAgentEnvRunner returns for the same config and seed, numpy-ized; no Ray instance is needed."""
    import numpy as np
    from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner

    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import TrainSpec
    from sbagents.rllib.env_runner import LeanMultiAgentEnvRunner
    from sbagents.rllib.experiment import build_config, build_experiment

    ref = resolve_env("mpe2.simple_spread_v3")
    exp = build_experiment(TrainSpec("ppo", ref.env_id, 1000, {"num_envs_per_env_runner": 4}), ref, 0)
    config, _ = build_config(exp, ref, seed=5)
    assert config.env_runner_cls is LeanMultiAgentEnvRunner

    def sample(cls: type) -> tuple[list, dict]:
        runner = cls(config=config)
        try:  # 4 envs x 30 steps a call: the second call continues the episodes the first one cut
            episodes = runner.sample(num_timesteps=120) + runner.sample(num_timesteps=120)
            return episodes, runner.get_metrics()
        finally:
            runner.stop()

    theirs, their_metrics = sample(MultiAgentEnvRunner)
    ours, our_metrics = sample(LeanMultiAgentEnvRunner)
    assert len(ours) == len(theirs) == 16 and all(e.is_numpy for e in ours)
    for mine, ref_episode in zip(ours, theirs, strict=True):
        assert mine.env_t_started == ref_episode.env_t_started and mine.env_t == ref_episode.env_t
        for aid, agent_episode in ref_episode.agent_episodes.items():
            for get in ("get_observations", "get_actions", "get_rewards"):
                assert np.array_equal(getattr(mine.agent_episodes[aid], get)(), getattr(agent_episode, get)())
    counted = ("num_env_steps_sampled", "num_env_steps_sampled_lifetime", "num_episodes", "num_episodes_lifetime",
               "num_agent_steps_sampled_lifetime", "num_module_steps_sampled_lifetime")
    assert {k: str(our_metrics[k]) for k in counted} == {k: str(their_metrics[k]) for k in counted}
    assert our_metrics["num_env_steps_sampled_lifetime"].peek() == 240
    assert our_metrics["num_module_steps_sampled_lifetime"]["shared"].peek() == 720
