"""The progress a person sees while a run trains, for either backend: a bar on a terminal and one line per
evaluation (:class:`ProgressReporter`). The SB3 callbacks that drive it are in :mod:`sbagents.pipeline.console`."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Mapping
from typing import Any, TextIO

from tqdm import tqdm


def format_eval_line(
    timesteps: int, total: int, mean: float, std: float, success: float | None,
    metrics: Mapping[str, float] | None = None, seconds: float | None = None,
) -> str:
    """``eval  2,000/20,000 steps  return 93.00 +- 0.00  success 1.00  (1.2 s)``."""
    text = f"eval {timesteps:>{len(f'{total:,}')},}/{total:,} steps  return {mean:.2f} +- {std:.2f}"
    if success is not None and not math.isnan(success):
        text += f"  success {success:.2f}"
    for key, value in (metrics or {}).items():
        text += f"  {key} {value:.3g}"
    if seconds is not None:
        text += f"  ({seconds:.1f} s)"
    return text


class ProgressReporter:
    """A progress bar (tqdm, on stderr) and evaluation lines (stdout) for one training run.

    :param total: env steps the run will take.
    :param bar: show the bar (None: only when stderr is a terminal).
    :param quiet: print nothing at all (``--verbose 0``).
    :param stream: where evaluation lines go.
    :param start: the model's step count when the run starts (``-i`` continues a model): the bar and the evaluation
        lines count this run's steps against this run's budget.
    """

    def __init__(self, total: int, bar: bool | None = None, quiet: bool = False, stream: TextIO | None = None,
                 start: int = 0) -> None:
        self.total = int(total)
        self.start = int(start)
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stdout
        show = (sys.stderr.isatty() if bar is None else bar) and not quiet
        self._bar: tqdm[Any] | None = tqdm(total=self.total, unit="step", dynamic_ncols=True) if show else None
        self._done = 0
        self._start = time.perf_counter()

    def update(self, timesteps: int) -> None:
        """Move the bar to ``timesteps`` env steps (the model's count)."""
        timesteps -= self.start
        if self._bar is not None and timesteps > self._done:
            self._bar.update(min(timesteps, self.total) - min(self._done, self.total))
        self._done = max(self._done, timesteps)

    def evaluation(self, timesteps: int, mean: float, std: float, success: float | None = None,
                   metrics: Mapping[str, float] | None = None) -> None:
        """Report one evaluation (at the model's ``timesteps``): mean and std of its episode returns, success rate,
        scalar metrics."""
        if self.quiet:
            return
        line = format_eval_line(timesteps - self.start, self.total, mean, std, success, metrics,
                                time.perf_counter() - self._start)
        if self._bar is not None:
            self._bar.set_postfix_str(f"eval {mean:.2f}", refresh=False)
            self._bar.write(line, file=self.stream)
        else:
            print(line, file=self.stream, flush=True)

    def warn(self, message: str) -> None:
        """One ``warning: ...`` line on stderr (above the bar), unless quiet."""
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.write(f"warning: {message}", file=sys.stderr)
        else:
            print(f"warning: {message}", file=sys.stderr, flush=True)

    def close(self) -> None:
        """Close the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
