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
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import cli, last_json, popen, summary

from sbagents.errors import UsageError
from sbagents.rllib import (
    CHECKPOINT_DIR,
    MODULE_SUBDIR,
    MODULES_FILE,
    NEEDS_RAY,
    PROGRESS_FILE,
    WEIGHTS_FILE,
    is_rllib_run,
    ray_available,
)

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
        (["--backend", "rllib", "--algo", "dqn", "--env", RUN], "trains team envs with --algo ppo, appo, impala"),
        (["--backend", "rllib", "--algo", "a2c", "--env", RUN], "supports --algo ppo, appo, impala, dqn, sac"),
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


def test_a_turn_based_game_is_rejected_before_ray_starts() -> None:
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", "pettingzoo.classic.tictactoe_v3")
    assert result.returncode == 2 and "turn-based game: it trains with --backend sb3" in result.stderr
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
            assert exp.n_timesteps > 0, (path, env_id)
            if path.stem == "rllib_ppo" and env_id != "atari":  # RLlib's Atari recipe shares its CNN trunk
                assert exp.model.get("vf_share_layers") is False, (path, env_id)


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
    for saved in (CHECKPOINT_DIR, "checkpoint_1000", "checkpoint_2000"):  # the modules as plain data
        assert (run_dir / saved / MODULES_FILE).is_file() and (run_dir / saved / WEIGHTS_FILE).is_file()
    assert not list(run_dir.glob(".*"))  # every checkpoint was staged in a hidden folder and renamed into place
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
    modules = load_modules(run_dir / CHECKPOINT_DIR, resolve_env(RUN), {"observation": "egocentric"})
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
    from sbagents.core.env_names import resolve_env
    from sbagents.registration import PETTINGZOO_ENVS
    from sbagents.rllib.evaluation import load_modules

    user_envs = Path(__file__).resolve().parent / "user_envs"
    # in this process the working folder is not on sys.path as with ``python -m``: put the user's package there
    # for this test only, and leave the env registry as it was
    monkeypatch.syspath_prepend(str(user_envs))
    saved = dict(PETTINGZOO_ENVS)
    def restore() -> None:
        PETTINGZOO_ENVS.clear()
        PETTINGZOO_ENVS.update(saved)

    request.addfinalizer(restore)
    logs = tmp_path / "logs"
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", "tiny_marl_pkg.relay_v0", "-n", "2000",
                 "--num-env-runners", "0", "-f", str(logs), "--seed", "1", "--eval-freq", "-1", "--verbose", "0",
                 "-params", "policies:per_group", "train_batch_size_per_learner:1000", "minibatch_size:250",
                 cwd=user_envs)
    assert result.returncode == 0, result.stderr
    run_dir = logs / "ppo" / "relay_v0_1"
    assert sorted(load_modules(run_dir / CHECKPOINT_DIR, resolve_env("tiny_marl_pkg.relay_v0"))) == ["scout", "worker"]
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


@pytest.mark.parametrize("env", ["mpe2.simple_spread_v3", "treasure_hunt_v0", "sbagents/GridWorld-v0",
                                 "sbagents/SmartHome-v0"])
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


# --- RLlib checkpoints: evaluated without unpickling anything, written atomically ----------------------------------
# RLlib's checkpoint files are pickles (class_and_ctor_args.pkl, module_state.pkl, ...). sbagents rebuilds the
# RLModules from plain data (sbagents_modules.json: allow-listed module class, module -> agents, model settings; the
# spaces from the env) and loads only the weights (sbagents_modules.npz, no pickle). Below, every pickle of a trained
# run is replaced by one that creates a marker file when unpickled: evaluation still works and the marker never
# appears. A checkpoint without the plain-data files (an older sbagents) is refused in one line naming --trust-run.

KWARGS = {"observation": "egocentric"}  # the shipped entry's env_kwargs (the modules' observation space)


class _Marker:
    """Unpickling this creates the file ``path`` (what a hostile pickle could do, harmlessly)."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple[Any, ...]:
        return (open, (self.path, "w"))


def poison(folder: Path, marker: Path) -> int:
    """Replace every ``.pkl`` under ``folder`` with a pickle that creates ``marker``; returns how many."""
    found = list(folder.rglob("*.pkl"))
    for path in found:
        path.write_bytes(pickle.dumps(_Marker(marker)))
    return len(found)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small run (sampling in the driver, about 10 s): its log folder."""
    logs = tmp_path_factory.mktemp("rllib")
    result = cli("train", "--backend", "rllib", "--algo", "ppo", "--env", RUN, "-n", "1000", "--num-env-runners", "0",
                 "-f", str(logs), "--seed", "1", "--eval-freq", "-1", "--final-eval-episodes", "0", "--verbose",
                 "0", "-params", "train_batch_size_per_learner:1000", "minibatch_size:256")
    assert result.returncode == 0, result.stderr
    return logs


def copy_run(logs: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the trained log folder (so each test may tamper with it) and its run dir."""
    copy = tmp_path / "logs"
    shutil.copytree(logs, copy, symlinks=True)
    return copy, copy / "ppo" / f"{RUN}_1"


def _outputs(modules: dict[str, Any], obs: np.ndarray) -> dict[str, np.ndarray]:
    import torch
    from ray.rllib.core import Columns

    with torch.no_grad():
        return {m: module.forward_inference({Columns.OBS: torch.as_tensor(obs)})[Columns.ACTION_DIST_INPUTS].numpy()
                for m, module in modules.items()}


@needs_ray
def test_rebuilt_modules_equal_rllibs_own_loader(trained: Path) -> None:
    """The modules rebuilt from plain data compute exactly what RLlib's unpickled checkpoint computes."""
    from sbagents.core.env_names import resolve_env
    from sbagents.rllib.checkpoints import _unpickle, load_modules

    checkpoint = trained / "ppo" / f"{RUN}_1" / CHECKPOINT_DIR
    ours = load_modules(checkpoint, resolve_env(RUN), KWARGS)
    spec = json.loads((checkpoint / MODULES_FILE).read_text())
    assert spec["module_class"] == "DefaultPPOTorchRLModule" and spec["modules"] == {
        "shared": ["agent_0", "agent_1", "agent_2"]}
    # RLlib's own loader (what --trust-run uses for older checkpoints), on the files the fixture's run wrote
    theirs = _unpickle(checkpoint)
    obs = np.random.default_rng(0).uniform(-1, 1, (16, 29)).astype(np.float32)
    mine, reference = _outputs(ours, obs), _outputs(theirs, obs)
    assert list(mine) == list(reference) == ["shared"]
    assert np.array_equal(mine["shared"], reference["shared"])


@needs_ray
def test_record_video_plays_a_team_run_without_unpickling(trained: Path, tmp_path: Path) -> None:
    """``record_video`` on an RLlib team run: every module acts on one team copy; a poisoned pickle stays shut."""
    logs, run_dir = copy_run(trained, tmp_path)
    marker = tmp_path / "unpickled"
    poison(run_dir, marker)
    result = cli("record_video", "--algo", "ppo", "--env", RUN, "-f", str(logs), "-n", "12")
    assert result.returncode == 0, result.stderr
    video = run_dir / "videos" / f"ppo-{RUN}-step-0-to-step-12.mp4"
    assert video.stat().st_size > 0 and f"video: {video}" in result.stdout and not marker.exists()
    best = cli("record_video", "--algo", "ppo", "--env", RUN, "-f", str(logs), "--load-best")
    assert best.returncode == 2 and "--load-best not supported for RLlib runs" in best.stderr
    exported = cli("export", "--algo", "ppo", "--env", RUN, "-f", str(logs))
    assert exported.returncode == 2 and "export takes RLlib runs on Gymnasium envs; treasure_hunt_v0 is a team env" \
        in exported.stderr and len(exported.stderr.strip().splitlines()) == 1


@needs_ray
def test_evaluate_unpickles_nothing(trained: Path, tmp_path: Path) -> None:
    """Every pickle of the run dir replaced by a hostile one: ``evaluate`` gives the same report as before and no
    pickle ran."""
    logs, run_dir = copy_run(trained, tmp_path)
    args = ["--algo", "ppo", "--env", RUN, "-f", str(logs), "-n", "3", "--json"]
    before = last_json(cli("evaluate", *args).stdout)
    marker = tmp_path / "unpickled"
    assert poison(run_dir, marker) >= 5
    result = cli("evaluate", *args)
    assert result.returncode == 0, result.stderr
    assert last_json(result.stdout) == before
    assert not marker.exists()


@needs_ray
def test_an_older_checkpoint_is_refused_without_trust_run(trained: Path, tmp_path: Path) -> None:
    """No plain-data module files: one line naming --trust-run, exit 2, nothing unpickled; trusted, RLlib loads it."""
    from sbagents.core.env_names import resolve_env
    from sbagents.core.options import EvaluateOptions
    from sbagents.rllib.evaluation import evaluate_run

    logs, run_dir = copy_run(trained, tmp_path)
    for name in (MODULES_FILE, WEIGHTS_FILE):
        (run_dir / CHECKPOINT_DIR / name).unlink()
    result = cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(logs), "-n", "2")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "would unpickle" in lines[0] and "--trust-run" in lines[0], result.stderr
    report = evaluate_run(run_dir, "ppo", resolve_env(RUN), EvaluateOptions(n_episodes=2, seed=0), trust=True)
    assert report["n_episodes"] == 2
    marker = tmp_path / "unpickled"
    poison(run_dir, marker)
    with pytest.raises(UsageError, match="--trust-run"):
        evaluate_run(run_dir, "ppo", resolve_env(RUN), EvaluateOptions(n_episodes=2, seed=0))
    assert not marker.exists()


@needs_ray
@pytest.mark.parametrize(
    ("tamper", "message"),
    [
        (lambda spec: spec.update(module_class="os.system"), "is not RLlib's default module of ppo"),
        (lambda spec: spec.update(algo="evil"), "algo 'evil' is not one sbagents rebuilds"),
        (lambda spec: spec["model"].update(custom_model="x"), "model has unknown key(s) custom_model"),
        (lambda spec: spec.update(modules={"shared": ["pirate"]}), "acts for pirate, not agents of"),
        (lambda spec: spec["model"].update(fcnet_hiddens=[32]), "do not fit the module"),
        (lambda spec: spec.update(format=99), "format 1"),
        (lambda spec: spec.update(module_settings={"dueling": True}), "module_settings takes vf_share_layers for ppo"),
        (lambda spec: spec.update(module_settings={"vf_share_layers": {"x": 1}}), "with plain values"),
    ],
)
@needs_ray
def test_tampered_module_files_are_one_line_errors(trained: Path, tmp_path: Path, tamper: Any, message: str) -> None:
    from sbagents.core.env_names import resolve_env
    from sbagents.rllib.checkpoints import load_modules

    _, run_dir = copy_run(trained, tmp_path)
    path = run_dir / CHECKPOINT_DIR / MODULES_FILE
    spec = json.loads(path.read_text())
    tamper(spec)
    path.write_text(json.dumps(spec))
    with pytest.raises(UsageError) as info:
        load_modules(path.parent, resolve_env(RUN), KWARGS)
    assert message in str(info.value) and "\n" not in str(info.value)


@needs_ray
@pytest.mark.parametrize("actions", [{"normalize": "yes"}, {"scale": True}, [True]])
def test_tampered_action_settings_are_one_line_errors(tmp_path: Path, actions: Any) -> None:
    from sbagents.rllib.checkpoints import action_settings

    (tmp_path / MODULES_FILE).write_text(json.dumps({"format": 1, "actions": actions}))
    with pytest.raises(UsageError, match="actions maps normalize and clip to true or false"):
        action_settings(tmp_path)
    (tmp_path / MODULES_FILE).write_text(json.dumps({"format": 1}))  # a team run's file of an older sbagents
    assert action_settings(tmp_path) == {"normalize": True, "clip": False}


@needs_ray
def test_weights_with_object_arrays_are_refused(trained: Path, tmp_path: Path) -> None:
    """An ``.npz`` whose arrays need pickle (object dtype) is refused, and the pickle inside never runs."""
    from sbagents.core.env_names import resolve_env
    from sbagents.rllib.checkpoints import load_modules

    _, run_dir = copy_run(trained, tmp_path)
    marker = tmp_path / "unpickled"
    weights = run_dir / CHECKPOINT_DIR / WEIGHTS_FILE
    with np.load(weights) as data:
        arrays = {k: data[k] for k in data.files}
    first = next(iter(arrays))
    arrays[first] = np.array([_Marker(marker)], dtype=object)
    with weights.open("wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(UsageError, match="is not a plain-array .npz"):
        load_modules(weights.parent, resolve_env(RUN), KWARGS)
    assert not marker.exists()


class _FakeLearnerGroup:
    def __init__(self, fail: bool) -> None:
        self.fail = fail

    def save_to_path(self, path: str) -> None:
        Path(path).mkdir(parents=True)
        (Path(path) / "state.pkl").write_bytes(b"learner")
        if self.fail:
            raise OSError(28, "No space left on device")

    def get_weights(self) -> dict[str, dict[str, np.ndarray]]:
        return {"shared": {"w": np.ones(2, dtype=np.float32)}}


class _FakeAlgo:
    """What :func:`save_checkpoint` uses of an RLlib ``Algorithm``."""

    def __init__(self, version: str, fail: bool = False) -> None:
        from types import SimpleNamespace

        self.version, self.fail = version, fail
        self.learner_group = _FakeLearnerGroup(fail)
        self.config = SimpleNamespace(normalize_actions=True, clip_actions=False,
                                      _model_config_auto_includes={"vf_share_layers": False})

    def save_to_path(self, path: str) -> str:
        (Path(path) / "algorithm_state.pkl").write_text(self.version)
        if self.fail:
            raise OSError(28, "No space left on device")
        return path


@needs_ray
def test_checkpoints_are_staged_and_renamed_into_place(tmp_path: Path) -> None:
    """A save goes to a new hidden folder renamed over the old checkpoint; a save that fails midway leaves the
    previous checkpoint whole and no hidden folder; a symlink at the checkpoint's name is replaced, not followed."""
    from sbagents.rllib.checkpoints import save_checkpoint

    run_dir, outside = tmp_path / "run", tmp_path / "outside"
    run_dir.mkdir()
    outside.mkdir()
    (run_dir / CHECKPOINT_DIR).symlink_to(outside, target_is_directory=True)
    final = run_dir / CHECKPOINT_DIR
    assert save_checkpoint(_FakeAlgo("one"), final, "ppo", {}, {"shared": ["a"]}) == final
    assert not final.is_symlink() and not list(outside.iterdir())
    assert (final / "algorithm_state.pkl").read_text() == "one"
    assert json.loads((final / MODULES_FILE).read_text())["modules"] == {"shared": ["a"]}
    with pytest.raises(UsageError, match="No space left on device; nothing was replaced"):
        save_checkpoint(_FakeAlgo("two", fail=True), final, "ppo", {}, {"shared": ["a"]})
    assert (final / "algorithm_state.pkl").read_text() == "one"
    save_checkpoint(_FakeAlgo("three"), final, "ppo", {}, {"shared": ["a"]})
    assert (final / "algorithm_state.pkl").read_text() == "three"
    module = run_dir / "checkpoint_1000"
    save_checkpoint(_FakeAlgo("m"), module, "ppo", {}, {"shared": ["a"]}, learner_only=True)
    assert sorted(p.name for p in module.iterdir()) == ["learner_group", MODULES_FILE, WEIGHTS_FILE]
    assert (module / "learner_group" / "state.pkl").read_bytes() == b"learner"
    assert sorted(p.name for p in run_dir.iterdir()) == sorted([CHECKPOINT_DIR, "checkpoint_1000"])


@needs_ray
def test_module_subdir_layout_is_what_the_trusted_loader_reads(trained: Path) -> None:
    """RLlib still writes its own files (``--trust-run`` and RLlib tools read them)."""
    run_dir = trained / "ppo" / f"{RUN}_1"
    assert (run_dir / CHECKPOINT_DIR).joinpath(*MODULE_SUBDIR, "shared", "module_state.pkl").is_file()
