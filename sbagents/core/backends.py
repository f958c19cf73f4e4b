"""Training backends as objects: the one protocol every training library implements (:class:`Backend`) and the
registry that finds one by its ``--backend`` name, so that nothing outside a backend tests the backend's name.

A backend trains a :class:`~sbagents.core.options.TrainSpec` into a run dir of the common layout, says whether a
finished run dir is one of its own (:meth:`Backend.owns_run`) and evaluates it. The built-in backends are named in
:data:`sbagents.registration.BACKENDS` as ``module:class`` paths (``sb3`` in :mod:`sbagents.pipeline.sb3_backend`,
``rllib`` in :mod:`sbagents.rllib.backend`) and imported the first time they are asked for: finding the backend of
an SB3 run imports neither Ray nor RLlib. :func:`register_backend` adds one from outside the package.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from sbagents.capabilities import Capability
from sbagents.errors import UsageError

if TYPE_CHECKING:
    from sbagents.core.lifecycle import TrainResult
    from sbagents.core.options import (
        EvalOptions,
        EvaluateOptions,
        ExecOptions,
        OutputOptions,
        RllibOptions,
        Sb3Options,
        TrainSpec,
    )
    from sbagents.core.run_dir import RunRef

#: The backend a run uses unless ``--backend`` names another.
DEFAULT_BACKEND = "sb3"


class Backend(ABC):
    """One training library behind ``python -m sbagents.train --backend NAME`` and ``evaluate``.

    Subclasses set :attr:`name` and :attr:`summary` and implement the abstract methods; a backend checks everything
    it refuses (options it does not implement, env kinds it does not train) before anything is written.
    """

    #: The ``--backend`` name.
    name: ClassVar[str]
    #: One line for ``--help`` and the docs.
    summary: ClassVar[str] = ""
    #: The ``--algo`` names the backend trains, a column of the capability table named like the backend (None: any
    #: algorithm, no column). The env kinds declare the backends that train them (``EnvKind.backends``).
    algos: ClassVar[tuple[str, ...] | None] = None

    def capabilities(self) -> list[Capability]:
        """The backend's columns of the capability table (:func:`sbagents.algos.capability_rows`): one named
        :attr:`name` when :attr:`algos` is declared."""
        if self.algos is None:
            return []
        return [Capability(self.name, f"--backend {self.name}: {self.summary}", self.algos,
                           label=f"--backend {self.name}")]

    @abstractmethod
    def train(self, spec: TrainSpec, output: OutputOptions | None, evaluation: EvalOptions | None,
              execution: ExecOptions, callbacks: Sequence[Any], features: Sequence[Any], sb3: Sb3Options,
              rllib: RllibOptions) -> TrainResult:
        """Train ``spec`` and write its run dir; refuse (:class:`UsageError`, one line) what this backend cannot
        honour before anything is written."""

    @abstractmethod
    def owns_run(self, run_dir: Path) -> bool:
        """Whether ``run_dir`` (a finished run) was made by this backend (cheap: imports no training library)."""

    @abstractmethod
    def evaluate(self, run: RunRef, options: EvaluateOptions) -> dict[str, Any]:
        """The ``evaluate --json`` summary of a run of this backend."""

    def record_video(self, run: RunRef, n_steps: int, output_dir: str | Path | None, seed: int,
                     deterministic: bool | None, fps: float | None) -> Path:
        """``record_video`` of a run of this backend (the mp4's path; the SB3 backend's runs are recorded by
        :func:`sbagents.visualize.video.record_video` itself, which calls this for every other backend's run).

        :raises UsageError: the backend does not record videos (the default).
        """
        raise UsageError(f"record_video does not record --backend {self.name} runs")

    def export(self, run: RunRef, int8: bool, out: str | Path | None, n_observations: int) -> dict[str, Any]:
        """``export`` of a run of this backend: group -> its :class:`~sbagents.deploy.exporting.ExportReport` (the
        SB3 backend's runs are exported by :func:`sbagents.deploy.exporting.export_groups` itself, which calls this
        for every other backend's run).

        :raises UsageError: the backend does not export (the default).
        """
        raise UsageError(f"export does not export --backend {self.name} runs")


_REGISTERED: dict[str, Backend] = {}


def register_backend(backend: Backend) -> Backend:
    """Make ``backend`` available as ``--backend <backend.name>`` (replacing a backend of that name)."""
    if not getattr(backend, "name", ""):
        raise ValueError("a backend needs a name")
    _REGISTERED[backend.name] = backend
    return backend


def _load_builtin() -> None:
    from sbagents.registration import BACKENDS

    for name, path in BACKENDS.items():
        if name not in _REGISTERED:
            module, _, attr = path.partition(":")
            register_backend(getattr(importlib.import_module(module), attr)())


def backend_names() -> tuple[str, ...]:
    """Every ``--backend`` name: the built-in ones (without importing them), then registered ones."""
    from sbagents.registration import BACKENDS

    return tuple(dict.fromkeys([*BACKENDS, *_REGISTERED]))


def get_backend(name: str) -> Backend:
    """The backend called ``name``.

    :raises UsageError: no backend has that name (one line naming the ones that exist).
    """
    if name not in _REGISTERED:
        _load_builtin()
    if name not in _REGISTERED:
        raise UsageError(f"unknown backend {name!r}; available: {', '.join(backend_names())}")
    return _REGISTERED[name]


def backend_capabilities() -> list[Capability]:
    """Every backend's :meth:`~Backend.capabilities` (the built-in ones imported), in registration order."""
    _load_builtin()
    return [capability for backend in _REGISTERED.values() for capability in backend.capabilities()]


def backend_of_run(run_dir: Path) -> Backend:
    """The backend that made the finished run ``run_dir`` (the default one when no other claims it)."""
    _load_builtin()
    for backend in _REGISTERED.values():
        if backend.name != DEFAULT_BACKEND and backend.owns_run(run_dir):
            return backend
    return get_backend(DEFAULT_BACKEND)
