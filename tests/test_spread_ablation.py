"""The ``spread-ablation`` benchmark on a tiny budget (CLI commands in-process), and its section."""

from __future__ import annotations

import pytest
from cli_helpers import checked_cli

from benchmarks.learning import pettingzoo_learning, spread_ablation


def test_variants_train_evaluate_and_render(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pettingzoo_learning, "cli", checked_cli)
    results = spread_ablation.run(["--variants", "pairwise", "shipped", "-n", "64", "--eval-episodes", "2"])
    rows = {r["variant"]: r for r in results["rows"]}
    assert [r["variant"] for r in results["rows"]] == ["shipped", "pairwise"]  # the table's order, not argv's
    assert rows["shipped"]["params"] == [] and "PairwiseDistanceFeatures" in rows["pairwise"]["params"][0]
    for row in rows.values():
        assert row["n_timesteps"] >= 64 and row["train_s"] > 0
        assert -200 < row["mean_return"] < 0 and 0 <= row["landmarks_covered"] <= 3 and row["collisions"] >= 0
    section = spread_ablation.render(results)
    line = next(x for x in section.splitlines() if x.startswith("| pairwise |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[2] == f"{rows['pairwise']['mean_return']:.2f}"
    assert cells[3] == f"{rows['pairwise']['mean_return'] - rows['shipped']['mean_return']:+.2f}"
    assert cells[4] == f"{2 * rows['pairwise']['mean_return'] - 75:.1f}"
    assert results["command"] == "python -m benchmarks run spread-ablation --variants pairwise shipped -n 64 " \
                                 "--eval-episodes 2"


def test_every_variant_is_a_valid_override_of_the_entry() -> None:
    from sbagents.core.env_names import resolve_env
    from sbagents.core.experiment import build_experiment
    from sbagents.core.options import TrainSpec
    from sbagents.core.zoo_config import parse_overrides

    for variant in spread_ablation.VARIANTS:
        overrides = parse_overrides(list(variant.params))
        exp = build_experiment(TrainSpec("ppo", spread_ablation.ENV, hyperparams=overrides),
                               resolve_env(spread_ablation.ENV))
        extractor = exp.algo_kwargs["policy_kwargs"].get("features_extractor_class")
        name = getattr(extractor, "__name__", None)
        if variant.name in ("mlp", "previous"):
            assert name is None, variant.name
        elif variant.name == "pairwise":
            assert name == "PairwiseDistanceFeatures"
        elif variant.name != "centralized":
            assert name == "EntityAttentionFeatures", variant.name
        if variant.name in ("previous", "16x100"):
            assert exp.n_envs == 16 and exp.algo_kwargs["n_steps"] == 100
