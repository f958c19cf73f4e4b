"""The life of a run, shared by the SB3 and RLlib backends: seed, run dir and config files, timed learning that
survives Ctrl-C, and ``summary.json`` (written before the final evaluation and again after it).

A backend does::

    seed = draw_seed(execution.seed)
    with new_run_dir(log_folder, algo, env_id, hyperparams, args, command) as run_dir:
        ...build everything; an exception here removes the half-made run dir...
    clock = LearningClock()  # LearningClock(graceful=True): a callback polls clock.stop_requested instead
    with clock:
        ...learn; Ctrl-C / SIGTERM (KeyboardInterrupt) ends the block with clock.interrupted = True...
    summary = finish_run(run_dir, {**base_summary(...), ...}, clock.interrupted, final_eval)
"""

from __future__ import annotations

import contextlib
import shlex
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType, TracebackType
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from sbagents.atomic import write_json
from sbagents.core.backends import DEFAULT_BACKEND
from sbagents.core.options import ExecOptions, TrainSpec
from sbagents.core.run_dir import SUMMARY_FILE, create_run_dir, save_run_config

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

    from sbagents.core.extensions import ActiveExtension


def draw_seed(seed: int) -> int:
    """``seed`` itself, or a fresh random seed when it is negative (``--seed -1``)."""
    return int(np.random.default_rng().integers(2**31 - 1)) if seed < 0 else seed


@contextlib.contextmanager
def new_run_dir(
    log_folder: str | Path, algo: str, env_id: str, hyperparams: dict[str, Any], args: dict[str, Any], command: str
) -> Iterator[Path]:
    """Create the next run dir and its ``config.yml``, ``args.yml`` and ``command.txt``; if the block raises
    (a setup failure), the run dir is removed, with the folders above it that this call created, so a failed start
    leaves nothing behind."""
    algo_dir = Path(log_folder) / algo
    created = [p for p in (algo_dir, *algo_dir.parents) if not p.exists()]  # deepest first
    run_dir = create_run_dir(log_folder, algo, env_id)
    try:
        save_run_config(run_dir, env_id, hyperparams, args, command)
        yield run_dir
    except BaseException:
        shutil.rmtree(run_dir, ignore_errors=True)
        for folder in created:
            with contextlib.suppress(OSError):  # not empty: another run started in it meanwhile
                folder.rmdir()
        raise


class LearningClock:
    """Times the learning block (wall and process CPU seconds) and turns Ctrl-C / SIGTERM into
    :attr:`interrupted` instead of an exception, so the caller still saves the model and writes the summary.

    :param graceful: inside the block (in the main thread), the first Ctrl-C / SIGTERM only sets
        :attr:`stop_requested`, which the learning loop polls (an SB3 callback returning False) to stop between two
        steps, so no file that training is writing (``best_model.zip`` mid-save) is cut short; a second one raises
        KeyboardInterrupt at once. A signal the process ignores (a job started in the background) stays ignored.
    """

    def __init__(self, graceful: bool = False) -> None:
        self.seconds = 0.0
        self.cpu_seconds = 0.0
        self.interrupted = False
        self.stop_requested = False
        self._graceful = graceful
        self._start = self._cpu_start = 0.0
        self._previous: dict[int, Any] = {}

    def _request_stop(self, signum: int, frame: FrameType | None) -> None:
        if self.stop_requested:
            raise KeyboardInterrupt(f"signal {signum}")
        self.stop_requested = True

    def __enter__(self) -> LearningClock:
        if self._graceful and threading.current_thread() is threading.main_thread():
            ignored = {sig for sig in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(sig) == signal.SIG_IGN}
            self._previous = {sig: signal.signal(sig, self._request_stop)
                              for sig in (signal.SIGINT, signal.SIGTERM) if sig not in ignored}
        self._start, self._cpu_start = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> bool:
        self.seconds = time.perf_counter() - self._start
        self.cpu_seconds = time.process_time() - self._cpu_start
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}
        self.interrupted = self.stop_requested or (kind is not None and issubclass(kind, KeyboardInterrupt))
        return kind is not None and issubclass(kind, KeyboardInterrupt)


def base_summary(algo: str, env_id: str, seed: int, n_timesteps: int, steps_done: int, clock: LearningClock
                 ) -> dict[str, Any]:
    """The ``summary.json`` keys every backend writes (``eval`` is filled by :func:`finish_run`).

    :param n_timesteps: the model's step count after learning.
    :param steps_done: steps taken by this run (the basis of ``fps``; less than ``n_timesteps`` when continuing).
    """
    return {
        "algo": algo, "env": env_id, "seed": seed, "n_timesteps": int(n_timesteps),
        "train_seconds": round(clock.seconds, 3), "train_cpu_seconds": round(clock.cpu_seconds, 3),
        "fps": round(steps_done / max(clock.seconds, 1e-9), 1), "interrupted": clock.interrupted, "eval": None,
    }


@runtime_checkable
class SummaryItems(Protocol):
    """A callback whose model reports items of ``summary.json`` (a game's learner: its illegal moves in training; the
    DP callback: its privacy spent)."""

    def summary_items(self) -> dict[str, Any]:
        """The callback's ``summary.json`` items (JSON values)."""
        ...


def write_summary(run_dir: Path, summary: dict[str, Any]) -> None:
    """Write ``<run dir>/summary.json`` (atomically)."""
    write_json(run_dir / SUMMARY_FILE, summary)


def finish_run(
    run_dir: Path, summary: dict[str, Any], final_eval: Callable[[], dict[str, Any]] | None
) -> dict[str, Any]:
    """Write the summary, then (unless the run was interrupted or ``final_eval`` is None) run the final
    evaluation into ``summary["eval"]`` and write it again; returns the summary."""
    write_summary(run_dir, summary)
    if final_eval is not None and not summary["interrupted"]:
        summary["eval"] = final_eval()
        write_summary(run_dir, summary)
    return summary


@dataclass
class TrainResult:
    """What a training run produced (either backend).

    :param model: the trained SB3 model (None for RLlib runs, whose policy is in ``rllib_checkpoint/``, and for runs
        of one model per group, which are in :attr:`models`).
    :param experiment: the resolved experiment (an SB3 :class:`Experiment` or an RLlib experiment).
    :param results: the items of ``summary.json`` that the run's extensions report
        (:meth:`sbagents.extensions.TrainingExtension.finish`; e.g. ``safety``, ``adversarial``, ``fairness``,
        ``constraint``), under ``by_group`` for a run of one model per group.
    """

    run_dir: Path
    model: BaseAlgorithm | None
    experiment: Any
    summary: dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False
    results: dict[str, Any] = field(default_factory=dict)
    models: dict[str, BaseAlgorithm] = field(default_factory=dict)


def default_command(spec: TrainSpec, execution: ExecOptions, extensions: Sequence[ActiveExtension] = ()) -> str:
    """The command line recorded when the caller gave none (the Python API): the spec's, the extensions' flags
    (:meth:`~sbagents.extensions.TrainingExtension.record`) and the backend."""
    args = ["--algo", spec.algo, "--env", spec.env]
    for active in extensions:
        args += active.extension.record(active.spec).flags
    if execution.backend != DEFAULT_BACKEND:
        args += ["--backend", execution.backend]
    return "python -m sbagents.train " + shlex.join(args)
