"""Backends are objects behind one protocol: found by name, a run dir finds its own, a backend registered from
outside the package trains and evaluates through the same entry points, and no code outside a backend tests a
backend's name."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import pytest

import sbagents
from sbagents.api import evaluate, train
from sbagents.core.backends import (
    _REGISTERED,
    Backend,
    backend_names,
    backend_of_run,
    get_backend,
    register_backend,
)
from sbagents.core.lifecycle import TrainResult
from sbagents.core.options import EvaluateOptions, ExecOptions, TrainSpec
from sbagents.core.run_dir import RunRef
from sbagents.errors import UsageError

PACKAGE = Path(sbagents.__file__).resolve().parent


class _Recorder(Backend):
    """A backend of a user's own: writes a marker run dir and remembers what it was asked."""

    name: ClassVar[str] = "recorder"
    summary: ClassVar[str] = "test backend"

    def __init__(self, root: Path) -> None:
        self.root, self.calls = root, []  # type: list[str]

    def train(self, spec: TrainSpec, output: Any, evaluation: Any, execution: ExecOptions, callbacks: Sequence[Any],
              features: Sequence[Any], sb3: Any, rllib: Any) -> TrainResult:
        run_dir = self.root / spec.algo / "CartPole-v1_1"
        run_dir.mkdir(parents=True)
        (run_dir / "recorder.txt").write_text(spec.env)
        self.calls.append(f"train {spec.algo} {spec.env}")
        return TrainResult(run_dir=run_dir, model=None, experiment=None)

    def owns_run(self, run_dir: Path) -> bool:
        return (run_dir / "recorder.txt").is_file()

    def evaluate(self, run: RunRef, options: EvaluateOptions) -> dict[str, Any]:
        self.calls.append(f"evaluate {run.run_dir().name}")
        return {"mean_return": 1.0}


@pytest.fixture
def recorder(tmp_path: Path) -> Any:
    backend = register_backend(_Recorder(tmp_path))
    yield backend
    _REGISTERED.pop(backend.name, None)


def test_the_builtin_backends_are_found_by_name() -> None:
    assert backend_names()[:2] == ("sb3", "rllib")
    assert type(get_backend("sb3")).__name__ == "Sb3Backend"
    assert get_backend("rllib").name == "rllib"
    with pytest.raises(UsageError, match="unknown backend 'nope'; available: sb3, rllib"):
        get_backend("nope")


def test_a_backend_registered_from_outside_trains_and_evaluates(recorder: _Recorder, tmp_path: Path) -> None:
    assert "recorder" in backend_names()
    result = train(TrainSpec(algo="ppo", env="CartPole-v1"), execution=ExecOptions(backend="recorder"))
    assert result.run_dir.parent.parent == tmp_path and recorder.calls == ["train ppo CartPole-v1"]
    assert backend_of_run(result.run_dir) is recorder
    report = evaluate(RunRef(algo="ppo", env="CartPole-v1", log_folder=str(tmp_path)))
    assert report == {"mean_return": 1.0} and recorder.calls[-1] == "evaluate CartPole-v1_1"


def test_an_sb3_run_dir_is_claimed_without_importing_ray(tmp_path: Path) -> None:
    code = ("import sys; from pathlib import Path; from sbagents.core.backends import backend_of_run; "
            f"b = backend_of_run(Path({str(tmp_path)!r})); print(b.name, 'ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["sb3", "False"]


def test_no_code_outside_a_backend_tests_a_backend_name() -> None:
    owners = {PACKAGE / "core" / "backends.py", PACKAGE / "pipeline" / "sb3_backend.py", PACKAGE / "rllib"}
    pattern = re.compile(r"backend\s*[!=]=\s*['\"]|['\"](sb3|rllib)['\"]\s*[!=]=\s*\w*backend")
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        if path in owners or PACKAGE / "rllib" in path.parents:
            continue
        offenders += [f"{path.relative_to(PACKAGE)}:{i}" for i, line in enumerate(path.read_text().splitlines(), 1)
                      if pattern.search(line)]
    assert offenders == []
