"""A feature flag's defaults carry the recipe we publish for it: ``--robust sa`` takes kappa 0.1 and 3 PGD steps, the
entry's ``robust_overrides`` / ``dp_overrides`` apply with ``--robust`` / ``--dp-epsilon`` (``-params`` and ``-n``
still win), and a constrained run says whether its cost limit held. The measured outcomes of these defaults are in
docs/robust.md and docs/private.md (long runs: benchmarks/)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from cli_helpers import summary

from sbagents.api import EvalOptions, ExecOptions, OutputOptions, TrainSpec, train
from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.errors import UsageError
from sbagents.private.options import PrivacyOptions
from sbagents.robust.options import parse_robust

HOME = "sbagents/SmartHome-v0"


def test_robust_sa_defaults_are_the_published_recipe() -> None:
    assert parse_robust("sa:0.2", "td3").model_kwargs() == {"sa_eps": 0.2, "sa_kappa": 0.1, "sa_pgd_steps": 3}
    assert parse_robust("sa:0.2,kappa=1,steps=5", "td3").model_kwargs()["sa_kappa"] == 1.0  # given: as given


@pytest.mark.parametrize(("algo", "features", "hyperparams", "n", "expected"), [
    ("td3", (), {}, None, {"n_timesteps": 8000}),
    ("td3", ("robust_overrides",), {}, None, {"n_timesteps": 16000}),  # docs/robust.md's budget for --robust sa:0.2
    ("td3", ("robust_overrides",), {}, 9000, {"n_timesteps": 9000}),
    ("ddpg", (), {}, None, {"n_timesteps": 8000, "learning_starts": 500, "batch_size": 128}),
    ("ddpg", ("dp_overrides",), {}, None,
     {"n_timesteps": 40000, "learning_starts": 4000, "batch_size": 256, "train_freq": 8}),
    ("ddpg", ("dp_overrides",), {"batch_size": 64}, None, {"n_timesteps": 40000, "batch_size": 64, "train_freq": 8}),
])
def test_shipped_entries_carry_the_flag_recipes(algo: str, features: tuple[str, ...], hyperparams: dict[str, int],
                                                n: int | None, expected: dict[str, int]) -> None:
    exp = build_experiment(TrainSpec(algo, HOME, n, hyperparams), resolve_env(HOME), features)
    assert {key: exp.hyperparams.get(key) for key in expected} == expected


def test_overrides_must_be_a_mapping(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(f"{HOME}:\n  n_timesteps: 100\n  dp_overrides: 5\n")
    with pytest.raises(UsageError, match="dp_overrides must be a mapping of hyperparameters, got 5"):
        build_experiment(TrainSpec("ddpg", HOME, conf_file=conf), resolve_env(HOME), ("dp_overrides",))


def test_train_applies_the_overrides_of_the_flags_given(tmp_path: Path) -> None:
    """A config whose SmartHome entry trains 8,000 steps, 300 with --robust and 320 with DP: each run takes its
    flag's budget (summary.json, config.yml), a plain run the entry's."""
    conf = tmp_path / "conf.yml"
    conf.write_text(yaml.safe_dump({HOME: {
        "n_timesteps": 8000, "learning_starts": 100, "batch_size": 32, "policy_kwargs": {"net_arch": [16]},
        "robust_overrides": {"n_timesteps": 300}, "dp_overrides": {"n_timesteps": 320, "batch_size": 64}}}))
    quiet = (OutputOptions(tmp_path / "logs"), EvalOptions(eval_freq=0, final_eval_episodes=0),
             ExecOptions(seed=0, verbose=0))
    robust = train(TrainSpec("td3", HOME, conf_file=conf), *quiet, features=[parse_robust("sa:0.2")])
    private = train(TrainSpec("ddpg", HOME, conf_file=conf), *quiet, features=[PrivacyOptions(noise=1.0)])
    assert (summary(robust.run_dir)["n_timesteps"], summary(private.run_dir)["n_timesteps"]) == (300, 320)
    config = yaml.safe_load((private.run_dir / "sbagents_SmartHome-v0" / "config.yml").read_text())
    assert (config["n_timesteps"], config["batch_size"]) == (320, 64)
    assert robust.model is not None and (robust.model.sa_kappa, robust.model.sa_pgd_steps) == (0.1, 3)
