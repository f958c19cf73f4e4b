"""TreasureHunt through the same train/evaluate CLIs as the single-agent envs."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import cli, last_json, summary

RUN = "treasure_hunt_v0"


def test_train_and_evaluate_team(tmp_path: Path) -> None:
    result = cli("train", "--algo", "ppo", "--env", RUN, "-n", "4000", "-f", str(tmp_path), "--seed", "0",
                 "--verbose", "0", "--env-kwargs", "max_cycles:30")
    assert result.returncode == 0, result.stderr
    run_dir = tmp_path / "ppo" / f"{RUN}_1"
    assert (run_dir / "evaluations.npz").exists() and (run_dir / "0.monitor.csv").exists()
    s = summary(run_dir)
    assert s["eval"]["mean_length"] <= 30
    assert set(s["eval"]["metrics"]) == {"treasures_collected", "per_agent_return", "episode_length"}
    assert s["eval"]["metrics"]["episode_length"] == s["eval"]["mean_length"]
    report = last_json(cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "-n", "4", "--json").stdout)
    assert report["n_episodes"] == 4 and report["env"] == RUN
    treasures = report["metrics"]["treasures_collected"]
    assert 0 <= treasures <= 5 and (4 * treasures).is_integer()  # the mean of 4 whole-treasure episodes
    assert sum(report["metrics"]["per_agent_return"].values()) == pytest.approx(report["mean_return"])
    again = last_json(cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "-n", "4", "--json").stdout)
    assert again == report
    rendered = cli("evaluate", "--algo", "ppo", "--env", RUN, "-f", str(tmp_path), "-n", "1", "--render")
    assert rendered.returncode == 0 and "A0" in rendered.stdout and " X " in rendered.stdout
    blocks = rendered.stdout.split("\n\n")
    labels = [b.splitlines()[0] for b in blocks if b.startswith("episode ")]
    steps = [label for label in labels if ", step " in label]
    assert labels[0] == "episode 1, start" and len(steps) == len(set(steps))  # each state printed once
    assert steps == [f"episode 1, step {k}, reward {label.rsplit(' ', 1)[1]}" for k, label in
                     enumerate(steps, start=1)]
    assert labels[-1].startswith(f"episode 1 truncated after {len(steps)} steps") or \
        labels[-1].startswith(f"episode 1 terminated after {len(steps)} steps")  # ends on the final state
    assert 1 <= len(steps) <= 30 and not any(label.startswith("episode 2") for label in labels)


def test_same_seed_same_team_results(tmp_path: Path) -> None:
    for _ in range(2):
        result = cli("train", "--algo", "ppo", "--env", RUN, "-n", "8000", "-f", str(tmp_path), "--seed", "4",
                     "--verbose", "0", "--eval-freq", "-1")
        assert result.returncode == 0, result.stderr
    first, second = (summary(tmp_path / "ppo" / f"{RUN}_{k}") for k in (1, 2))
    assert first["eval"] == second["eval"]
    monitor = [(tmp_path / "ppo" / f"{RUN}_{k}" / "0.monitor.csv").read_text().splitlines()[2:] for k in (1, 2)]
    strip_time = [[",".join(v for i, v in enumerate(line.split(",")) if i != 2) for line in m] for m in monitor]
    assert strip_time[0] == strip_time[1] and len(strip_time[0]) > 0


def test_wrong_env_kwarg_is_one_line(tmp_path: Path) -> None:
    result = cli("train", "--algo", "ppo", "--env", RUN, "--env-kwargs", "n_agent:5", "-f", str(tmp_path))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert "unknown env kwarg(s) n_agent for treasure_hunt_v0; accepted:" in result.stderr
    assert "n_agents" in result.stderr
