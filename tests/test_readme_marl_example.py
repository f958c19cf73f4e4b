"""README's "Your own PettingZoo env": the ``my_marl/meet_v0.py`` code block is a valid PettingZoo env and trains with
the README's command (from the folder that holds the package) well beyond random play."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from cli_helpers import cli_subprocess, last_json

README = Path(__file__).resolve().parents[1] / "README.md"
RANDOM_RETURN = -19.65  # uniform random walkers, 200 episodes (benchmarks.learning.team_baselines)


@pytest.fixture(scope="module")
def package(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``my_marl/`` written from the README."""
    blocks = re.findall(r"```python\n(# my_marl/meet_v0.py[^\n]*\n.*?)```", README.read_text(), flags=re.S)
    assert len(blocks) == 1, "README has one my_marl/meet_v0.py block"
    root = tmp_path_factory.mktemp("user")
    (root / "my_marl").mkdir()
    (root / "my_marl" / "__init__.py").write_text("")
    (root / "my_marl" / "meet_v0.py").write_text(blocks[0])
    return root


def test_the_example_passes_pettingzoo_api_and_seed_tests(package: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    monkeypatch.syspath_prepend(str(package))
    from my_marl.meet_v0 import parallel_env

    parallel_api_test(parallel_env(), num_cycles=200)
    parallel_seed_test(parallel_env)


@pytest.mark.slow  # learning: the README's own command and budget (~40 s here)
def test_the_readme_command_trains_it(package: Path) -> None:
    command = re.search(r"python -m sbagents\.train (--algo ppo --env my_marl\.meet_v0 -n \d+)", README.read_text())
    assert command is not None
    # subprocesses on purpose: the newcomer path, where ``python -m`` run from the folder that holds my_marl/ is what
    # makes the package importable (in this process it imported only if another test had put it on sys.path)
    result = cli_subprocess("train", *command.group(1).split(), "--seed", "0", cwd=package)
    assert result.returncode == 0, result.stderr
    assert (package / "logs" / "ppo" / "meet_v0_1" / "meet_v0.zip").exists()
    report = last_json(cli_subprocess("evaluate", "--algo", "ppo", "--env", "my_marl.meet_v0", "-n", "100", "--json",
                                      cwd=package).stdout)
    assert report["mean_return"] > RANDOM_RETURN + 12, report
    assert report["metrics"]["distance"] < 1  # the declared info metric: they (nearly) always meet
