"""The training commands set ``OMP_WAIT_POLICY=PASSIVE`` before torch loads OpenMP (:mod:`sbagents.openmp`), and keep
a value the user set."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sbagents.openmp import WAIT_POLICY, passive_wait_policy

PROBE = ("import sys, sbagents.openmp as o; first = o.passive_wait_policy; "
         "o.passive_wait_policy = lambda: (print('torch loaded first:', 'torch' in sys.modules), first())[1]; "
         "import {module}, os; print('policy:', os.environ['OMP_WAIT_POLICY'])")


def test_passive_wait_policy_sets_the_variable_only_when_unset(monkeypatch: pytest.MonkeyPatch) -> None:
    name, value = WAIT_POLICY
    monkeypatch.delenv(name, raising=False)
    assert passive_wait_policy() and os.environ[name] == value == "PASSIVE"
    monkeypatch.setenv(name, "ACTIVE")
    assert not passive_wait_policy() and os.environ[name] == "ACTIVE"


@pytest.mark.parametrize("module", ["sbagents.train", "sbagents.tune"])
@pytest.mark.parametrize("preset", [None, "ACTIVE"])
def test_training_commands_set_it_before_torch_is_imported(module: str, preset: str | None) -> None:
    env = {k: v for k, v in os.environ.items() if k != WAIT_POLICY[0]}
    if preset is not None:
        env[WAIT_POLICY[0]] = preset
    out = subprocess.run([sys.executable, "-c", PROBE.format(module=module)], env=env, capture_output=True,
                         text=True, check=True).stdout
    assert "torch loaded first: False" in out and f"policy: {preset or 'PASSIVE'}" in out
