"""Env kinds are open and complete: every kind implements every kind operation (no silent single-agent fallback),
and a kind defined outside the package (tests/kind_plugin.py) is registered and trains, evaluates and exports through
the CLIs without an sbagents file edited."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_helpers import run_main

from sbagents.core.env_kinds import (
    KIND_OPERATIONS,
    REGISTERED_KINDS,
    SINGLE_AGENT,
    EnvKind,
    builtin_kinds,
    kind_operation,
    load_kind_operations,
    missing_operations,
    register_env_kind,
)
from sbagents.core.env_names import resolve_env

QUIET = ("--verbose", "0", "--eval-freq", "-1", "--final-eval-episodes", "0", "--seed", "0")


@pytest.mark.parametrize("kind", builtin_kinds(), ids=lambda k: k.name)
def test_every_builtin_kind_implements_every_operation(kind: EnvKind) -> None:
    assert len(load_kind_operations()) >= 15
    assert missing_operations(kind) == []


def test_an_operation_refuses_a_kind_without_an_implementation() -> None:
    class Bare(EnvKind):
        name = "bare"

    @kind_operation()
    def describe(kind: EnvKind) -> str:
        return "single-agent"

    try:
        assert describe(SINGLE_AGENT) == "single-agent"
        with pytest.raises(NotImplementedError, match="env kind 'bare' does not implement .*describe"):
            describe(Bare())
        with pytest.raises(ValueError, match="env kind 'bare' lacks the operations"):
            register_env_kind(Bare())
    finally:
        KIND_OPERATIONS.pop(f"{__name__}.describe")


def test_a_kind_from_outside_trains_evaluates_and_exports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import kind_plugin

    try:
        ref = resolve_env("noisy/CartPole-v1")
        assert ref.kind is kind_plugin.NOISY and missing_operations(ref.kind) == []
        logs = tmp_path / "logs"
        assert run_main("train", "--algo", "ppo", "--env", "noisy/CartPole-v1", "-n", "64", "-params", "n_steps:32",
                        "batch_size:32", "n_envs:2", "-f", str(logs), *QUIET) == 0
        (run_dir,) = (logs / "ppo").iterdir()
        assert run_dir.name == "noisy_CartPole-v1_1"
        capsys.readouterr()
        common = ("--algo", "ppo", "--env", "noisy/CartPole-v1", "-f", str(logs), "--gym-packages", "kind_plugin")
        assert run_main("evaluate", *common, "-n", "2", "--json") == 0
        assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["n_episodes"] == 2
        assert run_main("export", *common, "--n-observations", "20") == 0
        assert (run_dir / "export" / "policy.onnx").is_file()
    finally:
        REGISTERED_KINDS.remove(kind_plugin.NOISY)


CLAIMS = [("CartPole-v1", "single-agent", "CartPole-v1"), ("GridWorld-v0", "single-agent", "sbagents/GridWorld-v0"),
          ("gymnasium.envs.classic_control:CartPole-v1", "single-agent", "CartPole-v1"),
          ("treasure_hunt_v0", "team", "treasure_hunt_v0"), ("mpe2.simple_tag_v3", "team", "simple_tag_v3"),
          ("pettingzoo.classic.tictactoe_v3", "turn-based game", "tictactoe_v3"),
          ("pettingzoo.classic.tictactoe_v3:env", "turn-based game", "tictactoe_v3")]


@pytest.mark.parametrize(("name", "kind", "env_id"), CLAIMS, ids=[c[0] for c in CLAIMS])
def test_each_name_is_claimed_by_exactly_one_builtin_kind(name: str, kind: str, env_id: str) -> None:
    claims = [(k.name, ref.env_id) for k in builtin_kinds() if (ref := k.claim(name, ())) is not None]
    assert claims == [(kind, env_id)]
    assert resolve_env(name).kind.name == kind


def test_resolve_env_asks_the_kinds_and_names_none() -> None:
    """No if/elif by kind: resolve_env loops over the kinds' claims and names no built-in kind."""
    import ast
    import inspect

    import sbagents.core.env_names as env_names

    tree = ast.parse(inspect.getsource(env_names.resolve_env))
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert not names & {"SINGLE_AGENT", "TEAM", "GAME"}
    assert any(isinstance(n, ast.For) and "claim" in ast.unparse(n) for n in ast.walk(tree))
