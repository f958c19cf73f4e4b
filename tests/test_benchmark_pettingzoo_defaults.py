"""``pettingzoo-defaults`` (:mod:`benchmarks.learning.pettingzoo_defaults`) and its scripted references
(:mod:`benchmarks.learning.mpe_references`): the scripts beat random play side by side, a tiny run of the benchmark
gives results its ``render`` turns into the section, the saved section is what ``render`` makes of the saved
results, and the ``pettingzoo`` default entry trains through the CLI on an mpe2 env nobody tuned."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import torch
from cli_helpers import checked_cli, section_text

from benchmarks.harness import registry

pytest.importorskip("mpe2")

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "pettingzoo_defaults.json"


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


@pytest.mark.parametrize("env", ["mpe2.simple_reference_v3", "mpe2.simple_push_v3", "mpe2.simple_adversary_v3"])
def test_scripted_sides_beat_random(env: str) -> None:
    """Each side played by its script scores more than the same side played randomly, against random opponents."""
    from benchmarks.learning.mpe_references import SIDES, side_summary

    agents = [a for members in SIDES[env].values() for a in members]
    for side, members in SIDES[env].items():
        scripted = side_summary(env, {a: "scripted" if a in members else "random" for a in agents}, 12, 10_000)
        random = side_summary(env, dict.fromkeys(agents, "random"), 12, 10_000)
        assert scripted["sides"][side] > random["sides"][side], (env, side, scripted["sides"], random["sides"])


def test_mixed_actor_refuses_unknown_players() -> None:
    from benchmarks.learning.mpe_references import side_summary

    with pytest.raises(ValueError, match="model, random or scripted"):
        side_summary("mpe2.simple_push_v3", {"adversary_0": "greedy", "agent_0": "random"}, 1, 0)


def test_tiny_run_renders(monkeypatch: pytest.MonkeyPatch) -> None:
    """Search (one candidate) and final run on one env at a tiny budget; the section shows both tables."""
    from benchmarks.learning import pettingzoo_defaults as bench

    monkeypatch.setattr(bench, "cli", checked_cli)
    monkeypatch.setitem(bench.CANDIDATES, "tiny", ("n_envs:2", "n_steps:16", "batch_size:32", "n_epochs:1"))
    argv = ["--seeds", "0", "--envs", "mpe2.simple_push_v3", "-n", "64", "--eval-episodes", "2",
            "--search-budget", "64", "--search-episodes", "2", "--candidates", "tiny"]
    results: dict[str, Any] = json.loads(json.dumps(registry()["pettingzoo-defaults"].run(argv)))
    assert results["command"] == "python -m benchmarks run pettingzoo-defaults " + " ".join(argv)
    found = results["search"]
    assert found["best"] == "tiny" and set(found["rows"]["tiny"]) == {"mpe2.simple_push_v3"}
    row = results["final"]["mpe2.simple_push_v3"]["runs"][0]
    assert set(row["ours"]) == set(row["random"]) == set(row["scripted"]) == {"adversary", "good"}
    section = registry()["pettingzoo-defaults"].render(results)
    assert "| mpe2.simple_push_v3 | good |" in section and "| tiny | `n_envs:2" in section
    assert results["commands"] == [results["command"]] and f"Command: `{results['command']}`" in section
    added = registry()["pettingzoo-defaults"].render({**results, "commands": ["first --seeds 0", "then --seeds 1"]})
    assert "Commands (each added its seeds' runs): `first --seeds 0`; then `then --seeds 1`" in added


def test_normalized_score() -> None:
    from benchmarks.learning.pettingzoo_defaults import normalized_score

    row = {"ours": {"a": -10.0, "b": 5.0}, "random": {"a": -20.0, "b": 0.0}, "scripted": {"a": 0.0, "b": 10.0}}
    assert normalized_score(row) == 0.5
    assert normalized_score({"ours": {"a": 1.0}, "random": {"a": 2.0}, "scripted": {"a": 2.0}}) != 0.0  # nan


def test_section_matches_saved_results() -> None:
    """BENCHMARKS.md's section is what ``render`` makes of the saved results; the shipped entry learned every side
    above random on every seed (the section's claim)."""
    if not RESULTS.exists():
        pytest.skip("no saved results yet")
    saved = json.loads(RESULTS.read_text())
    bench = registry()["pettingzoo-defaults"]
    assert bench.render(saved).strip() == section_text((ROOT / "BENCHMARKS.md").read_text(),
                                                       "pettingzoo-defaults").strip()
    for env in saved["envs"]:
        for run in saved["final"].get(env, {"runs": []})["runs"]:
            assert all(run["ours"][side] > run["random"][side] for side in run["ours"]), (env, run)
    search = saved["search"]  # the chosen candidate learned every side of every env above random (README's claim)
    assert search["mean_score"][search["best"]] == max(search["mean_score"].values())
    for env, row in search["rows"][search["best"]].items():
        assert all(row["ours"][side] > row["random"][side] for side in row["ours"]), (env, row)


@pytest.mark.parametrize(("env", "policies", "agents"), [
    ("simple_crypto_v3", None, {"eve_0", "bob_0", "alice_0"}),
    ("simple_adversary_v3", "per_group", {"adversary_0", "agent_0", "agent_1"}),
])
def test_default_entry_trains_an_unseen_env(env: str, policies: str | None, agents: set[str], tmp_path: Path) -> None:
    """An mpe2 env with no entry gets the ``pettingzoo`` entry: one shared policy over padded observations with an
    agent type (``simple_crypto``: three agents, two observation sizes), or one model per group on request."""
    from benchmarks.learning.pettingzoo_defaults import entry_settings
    from sbagents.core.zoo_config import load_yaml
    from sbagents.train import main

    extra = [f"policies:{policies}"] if policies else []
    main(["--algo", "ppo", "--env", f"mpe2.{env}", "-n", "64", "-f", str(tmp_path), "--seed", "0",
          "-params", "n_envs:2", "n_steps:16", "batch_size:32", "n_epochs:1", *extra, "--eval-freq", "-1",
          "--final-eval-episodes", "2", "--verbose", "0"])
    run_dir = tmp_path / "ppo" / f"{env}_1"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["eval"]["n_episodes"] == 2
    assert set(summary["eval"]["metrics"]["per_agent_return"]) == agents
    config = load_yaml(run_dir / env / "config.yml")
    entry = entry_settings()
    assert config["policies"] == (policies or entry["policies"]) and entry["policies"] == "shared"
    assert config["gamma"] == entry["gamma"] and config["policy_kwargs"] == entry["policy_kwargs"]
