"""``benchmarl-spread``: budgets, the venv script's arguments, the evaluation episodes (against sbagents' team
VecEnv with the same seeds), checkpoint picking and the section rendered from a results dict; the BenchMARL venv's
own train and eval on a tiny budget when ``.venv-benchmarl/`` exists (skipped otherwise)."""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.learning import benchmarl_side as side
from benchmarks.learning import benchmarl_spread as bs
from benchmarks.learning import benchmarl_venv as bv
from benchmarks.learning import spread_ours as ours
from benchmarks.learning.seed_table import stats_of
from benchmarks.learning.team_baselines import spread_assignment_actor
from sbagents.callbacks.episodes import stateless
from sbagents.core.team_options import TeamOptions
from sbagents.multiagent.factory import ParallelEnvFactory
from sbagents.multiagent.groups import team_vec_envs
from sbagents.multiagent.team_eval import run_team_episodes


def test_frame_budget_is_the_first_batch_past_the_agent_steps() -> None:
    assert side.frame_budget(1_000_000) == 336_000  # 333,334 env steps -> 56 batches of 6,000
    assert side.frame_budget(4_000_000) == 1_338_000
    assert side.frame_budget(900, 300) == 300
    with pytest.raises(ValueError, match="positive"):
        side.frame_budget(0)


def test_mappo_scale() -> None:
    assert side.team_to_mappo(-22.5) == -120.0


def test_train_args_carry_frame_and_second_budgets(tmp_path: Path) -> None:
    args = side.benchmarl_train_args("ippo", 3, tmp_path, [1_000_000], [300.0, 600.0], 900.0)
    assert args[:5] == ["train", "--algo", "ippo", "--seed", "3"]
    assert args[args.index("--frame-budgets") + 1] == "336000"
    assert args[args.index("--second-budgets") + 1:args.index("--max-seconds")] == ["300", "600"]
    assert "--frames-per-batch" not in args
    assert side.benchmarl_train_args("mappo", 0, tmp_path, [900], [1.0], 5.0, 300)[-2:] == ["--frames-per-batch", "300"]


def test_overrides_pick_discrete_actions_and_no_periodic_evaluation() -> None:
    o = bv.experiment_overrides("out")
    assert o["prefer_continuous_actions"] is False and o["evaluation"] is False and o["loggers"] == []
    assert "on_policy_collected_frames_per_batch" not in o  # BenchMARL's default batch
    assert bv.experiment_overrides("out", 300)["on_policy_minibatch_size"] == 300


def test_spread_episodes_are_the_team_vecenv_episodes_with_the_same_seeds() -> None:
    """The venv script's episode loop and sbagents' team VecEnv (as our runs are evaluated) play the same episodes:
    the scripted controller gets the same team return in each."""
    actor = spread_assignment_actor(3)
    mine = bv.spread_episodes(lambda obs: actor(obs.reshape(-1, obs.shape[-1])).reshape(len(obs), 3), 3, 10_000,
                              batch=2)  # a batch of 2, then 1
    factory = ParallelEnvFactory("mpe2.simple_spread_v3", (), {}, [])
    venvs = team_vec_envs(factory, 1, TeamOptions("shared"))
    try:
        policies = dict.fromkeys(venvs, stateless(actor))
        theirs = [run_team_episodes(venvs, policies, 1, 10_000 + k)[0].ret for k in range(3)]
    finally:
        next(iter(venvs.values())).close()
    np.testing.assert_allclose(mine, theirs, rtol=1e-6)
    assert len(set(mine)) == 3  # three different episodes
    still = bv.spread_episodes(lambda obs: np.zeros(obs.shape[:2], dtype=np.int64), 2, 10_000)
    assert np.mean(mine) > np.mean(still)  # the controller covers landmarks better than standing still


def _ours_run(final: bool) -> dict[str, Any]:
    return {"summary": {"n_timesteps": 4_003_200, "train_seconds": 410.0} if final else {},
            "final": final, "checkpoints": {1_000_000 + 800 * i: 100.0 * i for i in range(5)}}


def test_pick_checkpoints_and_fitted_budget() -> None:
    run = _ours_run(True)
    kept = {k["label"]: k for k in ours.pick_checkpoints(run, [1_000_000, 4_000_000], [300.0])}
    assert kept["agent_steps1000000"]["checkpoint"] == 1_000_000
    assert kept["agent_steps4000000"]["checkpoint"] is None  # the final model
    assert kept["seconds300"]["checkpoint"] == 1_002_400 and kept["seconds300"]["train_s"] == 300.0
    assert ours.pick_checkpoints(_ours_run(True), [], [600.0])[0]["checkpoint"] is None  # the whole run fit
    assert "agent_steps4000000" not in {k["label"] for k in ours.pick_checkpoints(_ours_run(False), [4_000_000], [])}
    assert ours.fitted_budget(run, 600.0, 100_000) == 5_800_000
    assert ours.fitted_budget(run, 300.0, 100_000) is None


def _results() -> dict[str, Any]:
    kept = [{"label": "frames336000", "budget": "agent_steps1000000", "frames": 336_000, "agent_steps": 1_008_000,
             "train_s": 700.0, "collection_s": 500.0, "team_return": -30.0, "std_return": 5.0},
            {"label": "seconds300", "frames": 120_000, "agent_steps": 360_000, "train_s": 290.0,
             "collection_s": 200.0, "team_return": -40.0, "std_return": 5.0},
            {"label": "capped", "frames": 400_000, "agent_steps": 1_200_000, "train_s": 900.0,
             "collection_s": 640.0, "team_return": -28.0, "std_return": 5.0}]
    ours = {"seed": 0, "runs": [{"n_timesteps": 4_003_200, "train_s": 410.0, "fps": 9763.9, "interrupted": False,
                                 "load_start": [2.0, 2.0, 2.0], "load_end": [2.5, 2.0, 2.0],
                                 "kept": [{"label": "agent_steps1000000", "agent_steps": 1_000_800, "train_s": 101.0,
                                           "checkpoint": 1_000_800, "team_return": -33.0, "std_return": 6.0,
                                           "cli_team_return": -33.2}]}]}
    result = {"env": side.ENV, "agent_budgets": [1_000_000, 4_000_000], "second_budgets": [300.0, 600.0],
              "n_eval": 1000, "eval_seed": 10_000, "seeds": [0], "max_seconds": 900.0,
              "machine": {"cpu": "CPU", "cores": 2, "torch": "2.13.0", "stable_baselines3": "2.8"},
              "command": "python -m benchmarks run benchmarl-spread", "benchmarl_settings": side.BENCHMARL_SETTINGS,
              "benchmarl_versions": {"benchmarl": "1.5.2"},
              "benchmarl": [{"algo": "mappo", "seed": 0, "kept": kept, "load_start": [3.0], "load_end": [3.1],
                             "total": {"frames": 400_000, "agent_steps": 1_200_000, "train_s": 900.0,
                                       "collection_s": 640.0, "capped": True}}],
              "ours": [ours], "ours_entry": {"n_envs": 16, "normalize": False, "team": {"critic": "local"},
                                             "hyperparams": {"n_steps": 100, "batch_size": 1200, "n_epochs": 10,
                                                             "gamma": 0.95, "target_kl": 0.02}}}
    result["stats"] = [[g, b, stats_of(v)] for (g, b), v in bs.seed_values(result).items()]
    return result


def test_render_from_a_results_dict() -> None:
    result = _results()
    text = bs.render(json.loads(json.dumps(result)))
    assert text == bs.render(result)
    assert "| BenchMARL MAPPO | 0 | 1.008M agent steps |" not in text  # budgets are labelled by the budget
    assert "| BenchMARL MAPPO | 0 | 1M agent steps | 1,008,000 | 700 | -30.00 | -135.0 | - | 2,016 | 1,440 |" in text
    assert "| BenchMARL MAPPO | 0 | 5 min | 360,000 | 290 | -40.00 |" in text
    assert "| BenchMARL MAPPO | 0 | time cap | 1,200,000 | 900 | -28.00 |" in text
    assert "| ours PPO (shipped entry) | 0 | 1M agent steps | 1,000,800 | 101 | -33.00 | -141.0 | -33.20 |" in text
    assert "stopped at its time cap (--max-seconds 900)" in text and "1 seed" in text
    assert "Shared machine." not in text and "Shared machine." in bs.render({**result, "note": "Shared machine."})
    assert "| critic input |" in text and "target_kl: 0.02" in text and "0.95 / 0.95" in text


VENV = side.REPO / ".venv-benchmarl"


@pytest.mark.skipif(not side.venv_python(VENV).exists(), reason="BenchMARL's venv (.venv-benchmarl) is absent")
def test_benchmarl_venv_trains_keeps_and_evaluates(tmp_path: Path) -> None:
    """The venv script on a tiny budget: two 300-frame batches, then the kept policies on 3 episodes."""
    python = str(side.venv_python(VENV))
    args = side.benchmarl_train_args("mappo", 0, tmp_path, [900, 1800], [1e-3], 120.0, 300)
    subprocess.run([python, str(side.VENV_SCRIPT), *args], check=True, capture_output=True, text=True)
    train = json.loads((tmp_path / "train.json").read_text())
    assert [k["label"] for k in train["kept"]] == ["frames300", "frames600"]
    assert train["kept"][1]["agent_steps"] == 1800 and train["settings"]["continuous_actions"] is False
    out = subprocess.run([python, str(side.VENV_SCRIPT), "eval", "--algo", "mappo", "--policies",
                          str(tmp_path / "policy_frames600.pt"), "-n", "3"], check=True, capture_output=True,
                         text=True).stdout
    evals = side.last_json(out)
    assert evals["policy_frames600.pt"]["n_episodes"] == 3 and evals["policy_frames600.pt"]["mean_return"] < 0


def test_run_rejects_bad_budgets() -> None:
    with pytest.raises(SystemExit, match="positive"):
        bs.run(["--agent-budgets", "0", "--no-ours", "--no-benchmarl"])
    assert isinstance(bs.build_parser().parse_args([]), argparse.Namespace)
