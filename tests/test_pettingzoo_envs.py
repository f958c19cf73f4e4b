"""External PettingZoo envs through the library with their shipped zoo entries (shrunk to a few hundred steps):
MPE (``mpe2``), SISL pursuit, Butterfly KAZ, an env with no entry of its own (the ``pettingzoo`` default), off-policy
algorithms on a shared policy, TreasureHunt's competitive mode with one model per agent, and videos and ONNX exports
of runs with one model per group. Learning on these envs is measured in ``benchmarks/learning/pettingzoo_learning.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import onnxruntime as ort
import pytest

from sbagents.api import (
    EvalOptions,
    ExecOptions,
    OutputOptions,
    RunRef,
    TrainSpec,
    evaluate,
    export_groups,
    record_video,
    train,
)
from sbagents.core.env_names import resolve_env

TINY = {"n_envs": 1, "n_steps": 16, "batch_size": 16, "n_epochs": 1}


def quick_run(folder: Path, algo: str, env: str, n: int, params: dict[str, Any] | None = None,
              env_kwargs: dict[str, Any] | None = None) -> Any:
    return train(TrainSpec(algo, env, n, params if params is not None else TINY, env_kwargs=env_kwargs or {}),
                 OutputOptions(folder), EvalOptions(eval_freq=-1, final_eval_episodes=1),
                 ExecOptions(seed=0, verbose=0))


@pytest.mark.parametrize(
    ("env", "env_kwargs", "groups"),
    [
        ("mpe2.simple_spread_v3", {}, ["shared"]),
        ("mpe2.simple_tag_v3", {}, ["adversary", "agent"]),
        ("pettingzoo.sisl.pursuit_v5", {"max_cycles": 20, "n_evaders": 5}, ["shared"]),
        ("pettingzoo.butterfly.knights_archers_zombies_v11", {"max_cycles": 40}, ["archer", "knight"]),
        ("mpe2.simple_adversary_v3", {}, ["shared"]),  # no entry: the pettingzoo default, padded observations
    ],
    ids=["spread", "tag", "pursuit", "kaz", "adversary-default"],
)
def test_shipped_entries_train_and_evaluate(tmp_path: Path, env: str, env_kwargs: dict[str, Any],
                                            groups: list[str]) -> None:
    result = quick_run(tmp_path, "ppo", env, 64, env_kwargs=env_kwargs)
    assert list(result.models or {"shared": result.model}) == groups
    name = resolve_env(env).env_id
    assert result.run_dir.name == f"{name}_1"
    summary = evaluate(RunRef("ppo", env, tmp_path))
    agents = summary["metrics"]["per_agent_return"]
    assert summary["mean_return"] == pytest.approx(sum(agents.values()), abs=1e-6)
    assert summary["metrics"]["episode_length"] >= 1
    if len(groups) > 1:
        assert set(summary["metrics"]["per_group_return"]) == set(groups)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_off_policy_algorithms_share_one_policy(tmp_path: Path, algo: str) -> None:
    params = {"n_envs": 2, "learning_starts": 50, "batch_size": 32, "buffer_size": 1000}
    result = quick_run(tmp_path, algo, "mpe2.simple_spread_v3", 300, params, {"continuous_actions": True})
    assert result.model.action_space.shape == (5,)
    assert result.model.replay_buffer.observations.shape[1] == 2 * 3  # 2 copies x 3 agents in one buffer
    assert np.isfinite(evaluate(RunRef(algo, "mpe2.simple_spread_v3", tmp_path))["mean_return"])


def test_treasure_hunt_competitive_mode_trains_one_model_per_agent(tmp_path: Path) -> None:
    params = {**TINY, "policies": "per_agent", "n_envs": 2}
    result = quick_run(tmp_path, "ppo", "treasure_hunt_v0", 96, params, {"reward_mode": "individual"})
    assert sorted(result.models) == ["agent_0", "agent_1", "agent_2"]
    summary = evaluate(RunRef("ppo", "treasure_hunt_v0", tmp_path))
    assert set(summary["metrics"]["per_group_return"]) == {"agent_0", "agent_1", "agent_2"}
    assert "treasures_collected" in summary["metrics"]


@pytest.fixture(scope="module")
def tag_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    logs = tmp_path_factory.mktemp("tag")
    quick_run(logs, "ppo", "mpe2.simple_tag_v3", 64)
    return logs


def test_a_video_of_a_run_with_one_model_per_group(tag_logs: Path, tmp_path: Path) -> None:
    path = record_video(RunRef("ppo", "mpe2.simple_tag_v3", tag_logs), n_steps=30, output_dir=tmp_path)
    frames = iio.imread(path)
    assert frames.shape[0] == 31 and frames.shape[-1] == 3  # every group acted: the team stepped 30 times
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 0


def test_an_export_of_a_run_with_one_model_per_group(tag_logs: Path) -> None:
    reports = export_groups(RunRef("ppo", "mpe2.simple_tag_v3", tag_logs), n_observations=100)
    assert set(reports) == {"adversary", "agent"}
    widths = {g: ort.InferenceSession(str(r.onnx_path)).get_inputs()[0].shape[1] for g, r in reports.items()}
    assert widths == {"adversary": 16, "agent": 14}  # each group's own observation
    assert all(r.parity_fp32 <= 1e-5 for r in reports.values())
