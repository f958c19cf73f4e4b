"""The ``deterministic_eval`` zoo key: every evaluation of a run (periodic, final, ``evaluate``, ``record_video``)
acts greedily unless the run's config says ``deterministic_eval: false``; ``--deterministic``/``--stochastic``
override it. Checked on what the evaluation code is asked to do (spies on SB3's ``evaluate_policy`` as the periodic
evaluation calls it, and on the episode runner's ``model_actor`` as the final, ``evaluate`` and team evaluations call
it), for a single-agent run and a PettingZoo team run,
and on the config's validation."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import stable_baselines3.common.callbacks as sb3_callbacks

import sbagents.multiagent.team_eval as team_eval
import sbagents.pipeline.evaluation as evaluation
from sbagents.api import EvalOptions, ExecOptions, OutputOptions, RunRef, TrainSpec, evaluate, train
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.options import EvaluateOptions
from sbagents.errors import UsageError

GRID = "sbagents/GridWorld-v0"
GRID_PARAMS = {"n_envs": 2, "n_steps": 32, "batch_size": 64, "n_epochs": 1}
PURSUIT = "pettingzoo.sisl.pursuit_v5"
PURSUIT_PARAMS = {"n_envs": 1, "n_steps": 16, "batch_size": 48, "n_epochs": 1,
                  "env_kwargs": {"x_size": 6, "y_size": 6, "n_evaders": 2, "n_pursuers": 3, "max_cycles": 8}}


def test_the_key_is_validated() -> None:
    ref = resolve_env(GRID)
    assert build_experiment(TrainSpec("ppo", GRID), ref).deterministic_eval is True
    assert build_experiment(TrainSpec("ppo", GRID, hyperparams={"deterministic_eval": False}), ref
                            ).deterministic_eval is False
    with pytest.raises(UsageError, match="deterministic_eval must be true or false, got 'sometimes'"):
        build_experiment(TrainSpec("ppo", GRID, hyperparams={"deterministic_eval": "sometimes"}), ref)
    shipped = build_experiment(TrainSpec("ppo", PURSUIT), resolve_env(PURSUIT))
    assert shipped.deterministic_eval is False  # pursuit's memoryless pursuers must wander


def _spy(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    """Record the ``deterministic`` flag of every evaluation: SB3's ``evaluate_policy`` as the periodic evaluation
    (SB3's ``EvalCallback``) calls it, and ``model_actor`` as :func:`sbagents.pipeline.evaluation.evaluate_model` and
    the team evaluation call it."""
    seen: list[bool] = []
    real_policy, real_actor = sb3_callbacks.evaluate_policy, team_eval.model_actor

    def policy_spy(*args: Any, **kwargs: Any) -> Any:
        seen.append(bool(kwargs["deterministic"]))
        return real_policy(*args, **kwargs)

    def actor_spy(model: Any, deterministic: bool = True) -> Any:
        seen.append(deterministic)
        return real_actor(model, deterministic)

    monkeypatch.setattr(sb3_callbacks, "evaluate_policy", policy_spy)
    monkeypatch.setattr(team_eval, "model_actor", actor_spy)
    monkeypatch.setattr(evaluation, "model_actor", actor_spy)
    return seen


@pytest.mark.parametrize(("env", "params", "n"), [(GRID, GRID_PARAMS, 128), (PURSUIT, PURSUIT_PARAMS, 96)])
@pytest.mark.parametrize("greedy", [True, False])
def test_every_evaluation_follows_the_run_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, env: str,
                                                 params: dict[str, Any], n: int, greedy: bool) -> None:
    seen = _spy(monkeypatch)
    result = train(TrainSpec("ppo", env, n, {**params, "deterministic_eval": greedy}), OutputOptions(tmp_path),
                   EvalOptions(eval_freq=n // 2, eval_episodes=1, final_eval_episodes=1),
                   ExecOptions(seed=0, verbose=0))
    assert not result.interrupted and len(seen) >= 3, seen  # two periodic evaluations and the final one
    assert set(seen) == {greedy}
    run = RunRef("ppo", env, tmp_path)
    for deterministic, expected in [(None, greedy), (True, True), (False, False)]:
        seen.clear()
        summary = evaluate(run, EvaluateOptions(n_episodes=1, deterministic=deterministic))
        assert summary["n_episodes"] == 1 and seen and set(seen) == {expected}, (deterministic, seen)
