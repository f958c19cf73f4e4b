"""Newcomer traps: run dirs of ``module:callable`` envs, budgets that learn nothing, pixel observations without an
entry, progress after ``-i``, the clone's parent folder, and ``evaluate --env-kwargs``."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from sbagents.pipeline.env_names import resolve_env
from sbagents.pipeline.run_dir import env_stem

USER_ENVS = Path(__file__).resolve().parent / "user_envs"

_MAKE_ENV = '''from tiny_marl_pkg.relay_v0 import parallel_env


def make_env(**kwargs):
    return parallel_env(**kwargs)
'''


@pytest.fixture
def two_packages(tmp_path: Path) -> Iterator[None]:
    """``tests/user_envs`` and two packages whose modules both define ``make_env`` on ``sys.path``."""
    for package in ("pkg_a", "pkg_b"):
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
        (tmp_path / package / "envs.py").write_text(_MAKE_ENV)
    sys.path[:0] = [str(tmp_path), str(USER_ENVS)]
    try:
        yield
    finally:
        sys.path.remove(str(tmp_path))
        sys.path.remove(str(USER_ENVS))
        for name in [m for m in sys.modules if m.split(".")[0] in ("pkg_a", "pkg_b")]:
            del sys.modules[name]


def test_module_callable_runs_are_named_after_module_and_callable(two_packages: None) -> None:
    """``pkg_a.envs:make_env`` and ``pkg_b.envs:make_env`` get run dirs of their own (before, both were
    ``make_env_<k>``, and ``evaluate`` picked the other's run); PettingZoo's own entry point keeps the module's
    name, so ``module:parallel_env`` and ``module`` name the same runs."""
    first, second = resolve_env("pkg_a.envs:make_env"), resolve_env("pkg_b.envs:make_env")
    assert (first.env_id, second.env_id) == ("pkg_a.envs:make_env", "pkg_b.envs:make_env")
    assert (env_stem(first.env_id), env_stem(second.env_id)) == ("pkg_a.envs_make_env", "pkg_b.envs_make_env")
    assert first.multi_agent and first.source == "pkg_a.envs:make_env"
    plain, explicit = resolve_env("tiny_marl_pkg.relay_v0"), resolve_env("tiny_marl_pkg.relay_v0:parallel_env")
    assert plain.env_id == explicit.env_id == "relay_v0"
