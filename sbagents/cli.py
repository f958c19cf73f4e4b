"""Shared pieces of the argparse shells: error handling, ``key:value`` flags, signals."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Callable
from types import FrameType
from typing import NoReturn

from sbagents.errors import UsageError


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error and exit code 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags that pick a finished run: ``--algo --env -f --exp-id --load-best --gym-packages``."""
    parser.add_argument("--algo", required=True, help="algorithm of the run")
    parser.add_argument("--env", required=True, help="env id of the run")
    parser.add_argument("-f", "--log-folder", default="logs", help="root of the run dirs (default: logs)")
    parser.add_argument("--exp-id", type=int, default=0, help="run number k (0 = latest)")
    parser.add_argument("--load-best", action="store_true", help="use best_model.zip instead of the final model")
    parser.add_argument("--gym-packages", nargs="+", default=[], help="packages to import that register envs")


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def describe_os_error(exc: OSError) -> str:
    """``cannot use /proc/x: No such file or directory`` (the path and the reason, no errno noise)."""
    where = f" {exc.filename}" if exc.filename else ""
    return f"cannot use{where}: {exc.strerror or exc}"


def run(prog: str, body: Callable[[], int | None]) -> NoReturn:
    """Run a CLI body: SIGTERM acts like Ctrl-C; :class:`UsageError` and file-system errors (a path that
    cannot be read or written) become one line on stderr and exit code 2."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        code = body() or 0
    except UsageError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        code = 2
    except BrokenPipeError:  # the reader of our output went away (``| head``): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 141
    except OSError as exc:
        print(f"{prog}: error: {describe_os_error(exc)}", file=sys.stderr)
        code = 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        code = 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    raise SystemExit(code)
