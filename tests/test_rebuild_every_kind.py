"""Every kind of run loads without decoding a pickle, and acts as SB3's own (unpickling) loader's copy does.

For each kind (plain, VecNormalize and action noise, constrained, robust, differentially private, HER on a goal env,
a PettingZoo team with one shared model and with one model per group, a turn-based game), a tiny run is trained
through the CLI; ``evaluate --json`` on it by default (models rebuilt from plain data and weights) and with
``--trust-run`` (models unpickled by SB3) must report the same episodes.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import run_main

QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "0", "--seed", "0")

#: id -> (train arguments, evaluate arguments)
KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "plain": (("--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-n", "64", "-params", "n_steps:32",
               "batch_size:32"), ()),
    "normalize and noise": (("--algo", "ddpg", "--env", "sbagents/SmartHome-v0", "-n", "120", "-params",
                             "learning_starts:50", "normalize:True"), ()),
    "constrained": (("--algo", "ppo", "--env", "sbagents/HazardGridWorld-v0", "-n", "64", "--constraint",
                     "lagrangian", "--cost-limit", "1", "-params", "n_steps:32", "batch_size:32"), ()),
    "robust": (("--algo", "ddpg", "--env", "sbagents/SmartHome-v0", "-n", "120", "--robust", "sa:0.05", "-params",
                "learning_starts:50"), ()),
    "private": (("--algo", "ppo", "--env", "sbagents/GridWorld-v0", "-n", "64", "--dp-epsilon", "8", "-params",
                 "n_steps:32", "batch_size:32"), ()),
    "her": (("--algo", "sac", "--env", "sbagents/PickAndPlaceGoal-v0", "-n", "150", "-params", "learning_starts:100",
             "batch_size:32", "buffer_size:1000"), ()),
    "team shared": (("--algo", "ppo", "--env", "treasure_hunt_v0", "-n", "128", "-params", "n_steps:32",
                     "batch_size:32"), ()),
    "team per group": (("--algo", "ppo", "--env", "mpe2.simple_tag_v3", "-n", "256", "-params", "n_steps:32",
                        "batch_size:32", "policies:per_group"), ()),
    "game": (("--algo", "ppo_mask", "--env", "pettingzoo.classic.tictactoe_v3", "-n", "128", "-params",
              "n_steps:32", "batch_size:32"), ("--opponent", "random")),
}


def _report(capsys: pytest.CaptureFixture[str], code: int) -> dict[str, object]:
    out, err = capsys.readouterr()
    assert code == 0, err
    report: dict[str, object] = json.loads(out.strip().splitlines()[-1])
    return report


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_of_run_is_rebuilt_as_sb3_would_load_it(kind: str, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    train_args, eval_args = KINDS[kind]
    logs = tmp_path / "logs"
    code = run_main("train", *train_args, "-f", str(logs), *QUIET)
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    algo, env = train_args[1], train_args[3]
    common = ("--algo", algo, "--env", env, "-f", str(logs), "-n", "3", "--seed", "1", "--json", *eval_args)
    rebuilt = _report(capsys, run_main("evaluate", *common))
    unpickled = _report(capsys, run_main("evaluate", *common, "--trust-run"))
    assert rebuilt == unpickled
