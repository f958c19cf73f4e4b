"""Fairness report: Wilson intervals, bucket edges, counts summing to the episodes, files, callback."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import configure
from test_callbacks_safety import ViolationEnv

from sbagents.callbacks import FairnessEvalCallback, fairness_report, wilson_interval
from sbagents.callbacks.fairness import bucket_edges, fairness_from_episodes
from sbagents.callbacks.rollout import EpisodeResult
from sbagents.envs.smart_home import SmartHomeEnv

torch.set_num_threads(1)


def test_wilson_interval_and_edges() -> None:
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-4)
    assert wilson_interval(10, 10)[1] == pytest.approx(1.0)
    lo, hi = wilson_interval(0, 0)
    assert lo != lo and hi != hi  # NaN for an empty bucket
    assert bucket_edges([0.7, 1.2], 2, (0.5, 1.5)).tolist() == [0.5, 1.0, 1.5]
    assert bucket_edges([2.0, 4.0, 3.0], 2).tolist() == [2.0, 3.0, 4.0]


def test_grouping_by_hand() -> None:
    eps = [EpisodeResult(0.0, 10, s, 0, 0.0, {"scale": sc, "mass": m})
           for s, sc, m in [(True, 0.6, 0.2), (False, 0.6, 0.9), (True, 1.4, 0.9), (True, 1.4, 0.95),
                            (False, 0.55, 0.15)]]
    report = fairness_from_episodes(eps, ["scale", "mass"], bins=2,
                                    ranges={"scale": (0.5, 1.5), "mass": (0.1, 1.0)})
    cells = {tuple(b["index"]): (b["n"], b["successes"]) for b in report["buckets"]}
    assert cells == {(0, 0): (2, 1), (0, 1): (1, 0), (1, 0): (0, 0), (1, 1): (2, 2)}
    assert report["worst"]["index"] == [0, 1] and report["gap"] == 1.0 and report["ratio"] == 0.0
    with pytest.raises(ValueError, match="no attribute 'colour'"):
        fairness_from_episodes(eps, ["colour"])


def test_smart_home_heatmap_counts_sum_to_episodes(tmp_path: Path) -> None:
    env = make_vec_env(SmartHomeEnv, n_envs=2, seed=0)
    model = PPO("MlpPolicy", env, n_steps=16, batch_size=32, seed=0, policy_kwargs={"net_arch": [16]})
    report = fairness_report(model, env, "preferred_temp,preferred_light", bins=3, n_episodes=7,
                             out_dir=tmp_path, ranges={"preferred_temp": (20, 26)})
    assert report["metric"] == "success_rate" and report["n_episodes"] == 7
    assert sum(b["n"] for b in report["buckets"]) == 7 and len(report["buckets"]) == 9
    assert report["edges"]["preferred_temp"] == [20.0, 22.0, 24.0, 26.0]
    with open(tmp_path / "fairness.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 9 and sum(int(r["n"]) for r in rows) == 7
    assert {"preferred_temp_low", "preferred_light_high", "success_rate", "ci_low", "ci_high"} <= set(rows[0])
    assert (tmp_path / "fairness.png").stat().st_size > 1000


def test_declared_ranges_mean_return_metric_and_callback(tmp_path: Path) -> None:
    class NoSuccess(ViolationEnv):
        def step(self, action):  # type: ignore[no-untyped-def]
            obs, r, term, trunc, info = super().step(action)
            info.pop("is_success", None)
            return obs, r, term, trunc, info

    env = make_vec_env(NoSuccess, n_envs=3, seed=0)
    model = PPO("MlpPolicy", env, n_steps=10, batch_size=30, seed=0, policy_kwargs={"net_arch": [16]})
    report = fairness_report(model, env, ["size"], bins=4, n_episodes=10, out_dir=tmp_path)
    assert report["edges"]["size"] == [0.0, 0.25, 0.5, 0.75, 1.0]  # the env's attribute_ranges
    assert report["metric"] == "mean_return" and sum(b["n"] for b in report["buckets"]) == 10

    model.set_logger(configure(str(tmp_path / "log"), ["csv"]))
    cb = FairnessEvalCallback(make_vec_env(ViolationEnv, n_envs=1, seed=1), "group,size", bins=2,
                              eval_freq=10, n_eval_episodes=6, path=tmp_path / "cb")
    model.learn(60, callback=cb)
    assert cb.last_report is not None and cb.last_report["timesteps"] == 60
    assert sum(b["n"] for b in cb.last_report["buckets"]) == 6
    assert (tmp_path / "cb" / "fairness.csv").exists() and (tmp_path / "cb" / "fairness.png").exists()
    with open(tmp_path / "log" / "progress.csv", newline="") as fh:
        logged = list(csv.DictReader(fh))
    assert {"fairness/worst", "fairness/gap", "fairness/overall"} <= set(logged[-1])
