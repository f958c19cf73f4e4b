"""Learning benchmarks of ``benchmarks/learning`` (games, federated homes, private, robust and constrained agents):
each one's ``run`` on a tiny budget gives results its ``render`` turns into the section's rows, and the saved
results back the claims their sections make."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import torch
from cli_helpers import checked_cli, section_text

from benchmarks.harness import registry

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


@pytest.fixture(autouse=True)
def _one_thread_and_a_short_bootstrap(monkeypatch: pytest.MonkeyPatch) -> None:
    """One torch thread; 200 bootstrap resamples instead of 20,000 (2 s per metric): the tiny runs check the
    tables, not the intervals."""
    import benchmarks.stats
    from benchmarks.stats import seed_stats

    torch.set_num_threads(1)
    monkeypatch.setattr(benchmarks.stats, "seed_stats", partial(seed_stats, reps=200))


def _cells(section: str) -> list[list[str]]:
    """The cells of every Markdown table row in ``section`` (header and body rows; separator rows dropped)."""
    rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in section.splitlines()
            if line.startswith("|")]
    return [r for r in rows if not all(set(c) <= set("-: ") for c in r)]


def _stats_rows(section: str) -> dict[tuple[str, str], list[str]]:
    """The over-seeds table's rows by (group, metric): seeds, per seed, mean +- std, IQM [95% CI]."""
    return {(r[0], r[1]): r[2:] for r in _cells(section) if len(r) == 6 and r[1] != "metric"}


def _run(name: str, argv: list[str]) -> tuple[dict[str, Any], str]:
    bench = registry()[name]
    results = json.loads(json.dumps(bench.run(argv)))  # what the harness saves and loads back
    return results, bench.render(results)


@pytest.mark.parametrize("task", ["tictactoe", "connect4", "holdem", "tutorial"])
def test_games_sections_match_their_results(task: str) -> None:
    """BENCHMARKS.md's game sections are what ``render`` makes of the saved results; every recorded run played
    without an illegal move and is judged by the bar its section shows."""
    from benchmarks.learning import games_learning as games

    saved = json.loads((RESULTS / f"games_{task}.json").read_text())
    section = registry()[f"games-{task}"].render(saved)
    if task == "tutorial":
        rows = [r for game_rows in saved["games"].values() for r in game_rows]
        assert {n: saved["shipped"][n] for n in games.TUTORIAL_GAMES} == {
            n: json.loads((RESULTS / f"games_{n}.json").read_text())["runs"] for n in games.TUTORIAL_GAMES}
    else:
        rows = saved["runs"]
        _, met = games.BARS[task]
        verdicts = [c[-1] for c in _cells(section)[1:] if c[0].isdigit()]
        assert verdicts == ["yes" if met(r) else "no" for r in rows]
    assert section.strip() == section_text((ROOT / "BENCHMARKS.md").read_text(), f"games-{task}").strip()
    assert sorted({r["seed"] for r in rows}) == [0, 1, 2]
    assert all(vs["illegal_moves"] == 0 for r in rows for vs in r["vs"].values())



def test_games_tictactoe_tiny_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """``--smoke``: train and evaluate play every opponent; the section has a row and an over-seeds row each."""
    from benchmarks.learning import games_learning as games

    monkeypatch.setattr(games, "cli", checked_cli)
    results, section = _run("games-tictactoe", ["--seeds", "0", "--smoke"])
    assert results["command"] == "python -m benchmarks run games-tictactoe --seeds 0 --smoke"
    assert results["elo_plot"] is None and [r["seed"] for r in results["runs"]] == [0]
    assert {o: vs["n_games"] for o, vs in results["runs"][0]["vs"].items()} == {"random": 10, "minimax": 10}
    stats = _stats_rows(section)
    assert set(stats) == {("vs random", "win %"), ("vs minimax", "draw %")}
    assert stats["vs random", "win %"][0] == "1" and stats["vs random", "win %"][3] == "1 seed"
    assert "Ratings of seed 0" not in section and "Command: `python -m benchmarks run games-tictactoe" in section


def test_games_add_keeps_the_stored_seeds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--add`` merges the new seed's row with the stored rows of other seeds (training stubbed)."""
    from benchmarks.learning import games_learning as games

    saved = json.loads((RESULTS / "games_holdem.json").read_text())
    stored = tmp_path / "holdem.json"
    stored.write_text(json.dumps(saved))
    monkeypatch.setattr(games, "train_ours", lambda game, seed, logs, budget: {**saved["runs"][0], "seed": seed})
    results = games.run_game("holdem", ["--seeds", "1", "--add", "--stored", str(stored)])
    assert [r["seed"] for r in results["runs"]] == [0, 1, 2] and results["runs"][1] == {**saved["runs"][0], "seed": 1}
    assert results["command"] == "python -m benchmarks run games-holdem --seeds 1 --add"
    assert "| vs random | chips/hand (big blinds) | 3 |" in games.game_markdown("holdem", results)


def test_games_tutorial_tiny_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The tutorial benchmark on one seed at the smoke budget (the recipe untrained, our CLI run stubbed: the
    tutorial's own tests train it and the game test covers ours)."""
    from sb3_contrib import MaskablePPO
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy

    from benchmarks.learning import games_learning as games
    from benchmarks.learning import games_tutorial

    def untrained(game_module: str, steps: int, seed: int, *, variant: str) -> MaskablePPO:
        env = games_tutorial.make_tutorial_env(game_module, seed=seed, variant=variant)  # type: ignore[arg-type]
        return MaskablePPO(MaskableActorCriticPolicy, env, seed=seed)

    monkeypatch.setattr(games_tutorial, "train_tutorial_recipe", untrained)

    shipped = json.loads((RESULTS / "games_tictactoe.json").read_text())["runs"][0]
    monkeypatch.setattr(games, "TUTORIAL_GAMES", ("tictactoe",))
    monkeypatch.setattr(games, "train_ours", lambda game, seed, logs, budget, steps: {**shipped, "seed": seed,
                                                                                       "n_timesteps": steps})
    (tmp_path / "games_tictactoe.json").write_text(json.dumps({"runs": [shipped]}))
    results = games.run_tutorial(["--seeds", "0", "--smoke", "--stored", str(tmp_path)])
    rows = results["games"]["tictactoe"]
    assert [r["who"] for r in rows] == ["tutorial (fixed)", "tutorial (original)", "sbagents"]
    assert all(r["vs"]["random"]["n_games"] == 10 for r in rows[:2]) and results["shipped"]["tictactoe"] == [shipped]
    section = games.tutorial_markdown(results)
    assert "| tutorial (fixed) | 0 | 256 |" in section and "| sbagents (shipped budget) | 0 | 401,408 |" in section
    assert ("tic-tac-toe: tutorial (original)", "draw % vs minimax") in _stats_rows(section)


def test_federated_section_matches_its_results() -> None:
    """The saved results back the claim made of them: on every seed the federated policy meets the criterion on
    >= 95% of held-out-home steps and home 0's local model does not."""
    saved = json.loads((RESULTS / "federated_homes.json").read_text())
    section = section_text((ROOT / "BENCHMARKS.md").read_text(), "federated-homes")
    assert registry()["federated-homes"].render(saved).strip() == section.strip()
    assert sorted(r["seed"] for r in saved["runs"]) == [0, 1, 2]
    for run in saved["runs"]:
        rows = run["rows"]
        assert rows["federated"]["heldout_share"] >= 0.95 > rows["local only (home 0)"]["heldout_share"]
        assert run["bytes_per_round_per_home"] > 2 * 4 * run["parameters"]  # float32, down and up
        assert {p["kind"] for p in run["personal"]} == {"client", "held-out", "outside the ranges"}


def test_federated_tiny_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """``run`` over two seeds (each seed's trainings stubbed: Flower is an extra) records the command and the
    held-out comfort over seeds."""
    from benchmarks.learning import federated_homes

    saved = json.loads((RESULTS / "federated_homes.json").read_text())["runs"][1]
    monkeypatch.setattr(federated_homes, "run_seed", lambda settings, *a: {**saved, "seed": settings.seed})
    results, section = _run("federated-homes", ["--seeds", "0", "1", "--rounds", "2", "--local-steps", "10"])
    assert results["command"] == "python -m benchmarks run federated-homes --seeds 0 1 --rounds 2 --local-steps 10"
    assert results["settings"] == {"rounds": 2, "local_steps": 10, "strategy": "fedavg"}
    assert _stats_rows(section)["federated", "held-out comfort (%)"][:2] == ["2", "100.0 / 100.0"]
    assert [r[0] for r in _cells(section) if r[1] == "federated"] == ["0", "1"]


def test_private_tiny_run() -> None:
    results, section = _run("private-smarthome", ["--epsilons", "inf", "8", "--seeds", "0", "--episodes", "1",
                                                  "--params", "n_timesteps:200", "learning_starts:100",
                                                  "batch_size:32"])
    assert results["command"].startswith("python -m benchmarks run private-smarthome --epsilons inf 8 --seeds 0")
    assert [r[0] for r in _cells(section)[1:] if r[1] == "0"] == ["inf", "8.0"]
    assert set(_stats_rows(section)) == {(f"epsilon {e}", m) for e in ("inf", "8.0")
                                         for m in ("comfort share (%)", "mean return")}


def test_robust_tiny_run() -> None:
    results, section = _run("robust-smart-home", ["--seeds", "0", "--episodes", "1", "--variants", "vanilla",
                                                  "-n", "200"])
    assert [(r["variant"], r["n_timesteps"]) for r in results["runs"]] == [("vanilla", 200)]
    assert results["runs"][0]["cpu_ratio"] == 1.0 and results["command"].endswith("--variants vanilla -n 200")
    assert [r[:2] for r in _cells(section)[1:] if r[1] in ("0", "**mean**")] == [["vanilla", "0"],
                                                                                ["vanilla", "**mean**"]]
    assert ("vanilla", "PGD 0.2 success") in _stats_rows(section)


def test_constrained_hazard_tiny_run(tmp_path: Path) -> None:
    results, section = _run("constrained-hazard", ["--seeds", "0", "-n", "64", "--episodes", "1", "--methods", "ppo",
                                                   "ppo-lagrangian", "--plot", str(tmp_path / "plot.png")])
    assert results["command"] == ("python -m benchmarks run constrained-hazard --seeds 0 -n 64 --episodes 1 "
                                  "--methods ppo ppo-lagrangian")
    assert (tmp_path / "plot.png").stat().st_size > 0
    assert [r[0] for r in _cells(section)[1:] if r[1].startswith("`")] == ["ppo", "ppo-lagrangian"]
    assert ("ppo-lagrangian", "mean episode cost") in _stats_rows(section)
