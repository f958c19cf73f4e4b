"""``python -m sbagents.collect``: episodes of a baseline or of a finished run, recorded as a Minari dataset that
Minari itself loads (T + 1 observations, T actions, the env's own rewards, the infos that matter, reference scores
where the env has an expert), written atomically; misuse is one line and writes nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import check_error, run_main

minari = pytest.importorskip("minari", reason="needs Minari: pip install -e '.[test]' (or the data extra)")


def test_the_experts_episodes_load_with_minari(datasets: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run_main("collect", "--env", "HazardGridWorld-v0", "--policy", "scripted", "--episodes", "3", "--dataset",
                    "sbagents/hazard-expert-v0", "--ref-episodes", "3") == 0
    assert "dataset sbagents/hazard-expert-v0: 3 episodes" in capsys.readouterr().out
    dataset = minari.load_dataset("sbagents/hazard-expert-v0")
    assert dataset.total_episodes == 3 and dataset.total_steps == 3 * 14
    meta = dataset.storage.metadata
    assert (meta["algorithm_name"], meta["ref_max_score"], meta["env_spec"] is not None) == ("scripted", 87.0, True)
    assert meta["ref_min_score"] < 0  # random play never reaches the goal in 50 steps here
    for episode in dataset.iterate_episodes():
        assert len(episode.observations) == len(episode.actions) + 1 == 15
        assert episode.rewards.sum() == 87.0 and episode.terminations[-1] and not episode.truncations.any()
        assert episode.observations[0] == 28 and episode.observations[-1] == 34  # start (4, 0), goal (4, 6)
        assert episode.infos["is_success"][-1] and not episode.infos["is_success"][:-1].any()
        assert (episode.infos["cost"] == 0).all()  # the safe path
    assert sorted(p.name for p in (datasets / "sbagents").iterdir()) == ["hazard-expert-v0"]
    assert not [p for p in datasets.iterdir() if p.name.startswith(".")]  # no staging folder left


def test_random_play_records_costs_truncations_and_violations(datasets: Path) -> None:
    assert run_main("collect", "--env", "HazardGridWorld-v0", "--policy", "random", "--episodes", "4", "--dataset",
                    "sbagents/hazard-random-v0", "--seed", "3") == 0
    episodes = list(minari.load_dataset("sbagents/hazard-random-v0").iterate_episodes())
    assert [e.id for e in episodes] == [0, 1, 2, 3]
    costs = np.concatenate([e.infos["cost"] for e in episodes])
    violations = np.concatenate([e.infos["violation"] for e in episodes])
    assert costs.sum() > 0 and set(violations[costs > 0]) == {b"hazard"} and set(violations[costs == 0]) == {b""}
    assert any(e.truncations[-1] for e in episodes)  # random play runs out of its 50 steps


def test_a_runs_episodes_are_recorded(datasets: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = tmp_path / "logs"
    assert run_main("train", "--algo", "ppo", "--env", "SmartHome-v0", "-n", "256", "-f", str(logs), "--verbose", "0",
                    "--eval-freq", "-1", "--final-eval-episodes", "0", "-params", "n_steps:64", "batch_size:64",
                    "n_envs:2") == 0  # the SmartHome entry normalizes: the statistics reach the policy's input only
    assert run_main("collect", "--env", "SmartHome-v0", "--algo", "ppo", "-f", str(logs), "--episodes", "2",
                    "--dataset", "sbagents/smarthome-ppo-v0") == 0
    dataset = minari.load_dataset("sbagents/smarthome-ppo-v0")
    assert dataset.storage.metadata["algorithm_name"].startswith("ppo (")
    episode = next(dataset.iterate_episodes())
    assert episode.observations.shape == (101, 5) and episode.actions.shape == (100, 2)
    assert episode.observations[:, 0].min() > 10  # raw temperatures (degrees C), not normalized ones
    assert episode.truncations[-1] and not episode.terminations.any()


def test_bad_input_is_one_line_and_writes_nothing(datasets: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ("--env", "GridWorld-v0", "--episodes", "1")
    assert run_main("collect", *base, "--policy", "random", "--dataset", "sbagents/grid-v0") == 0
    capsys.readouterr()
    for args, expected in [
        ((*base, "--policy", "random", "--dataset", "sbagents/grid-v0"), "dataset sbagents/grid-v0 exists"),
        ((*base, "--policy", "random", "--dataset", "grid"), "a dataset id is namespace/name-vN"),
        (("--env", "GridWorld-v0", "--episodes", "0", "--policy", "random", "--dataset", "sbagents/g-v1"),
         "--episodes must be >= 1"),
        (("--env", "pettingzoo.classic.tictactoe_v3", "--episodes", "1", "--policy", "random", "--dataset",
          "sbagents/t-v0", "--group", "x"), "--group applies to teams of several groups; tictactoe_v3 is not a team"),
        ((*base, "--policy", "random", "--dataset", "sbagents/g-v4", "--opponent", "random"),
         "--opponent applies to turn-based games; sbagents/GridWorld-v0 is not one"),
        ((*base, "--policy", "random", "--dataset", "x/g-v0"), "a namespace of 2 characters or more"),
        ((*base, "--dataset", "sbagents/g-v2"), "who acts: --policy random|scripted, a run with --algo ALGO"),
        ((*base, "--policy", "random", "--algo", "ppo", "--dataset", "sbagents/g-v3"), "give one of them"),
        (("--env", "CartPole-v1", "--episodes", "1", "--policy", "scripted", "--dataset", "sbagents/c-v0"),
         "CartPole-v1 has no scripted expert"),
    ]:
        check_error(run_main("collect", *args), capsys.readouterr().err, expected)
    assert sorted(p.name for p in (datasets / "sbagents").iterdir()) == ["grid-v0"]


def test_a_failed_write_leaves_no_dataset(datasets: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(minari, "create_dataset_from_buffers", broken)
    code = run_main("collect", "--env", "GridWorld-v0", "--episodes", "1", "--policy", "random", "--dataset",
                    "sbagents/grid-v0")
    check_error(code, capsys.readouterr().err, "disk full")
    assert not (datasets / "sbagents").exists() and not list(datasets.iterdir())
