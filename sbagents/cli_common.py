"""What the CLI modules (``python -m sbagents.<command>``) share: one-line errors and exit codes, SIGTERM as
Ctrl-C, and the flags that pick a finished run. Importing it needs neither torch nor gymnasium (``serve``)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from collections.abc import Callable
from types import FrameType
from typing import Any, NoReturn

from sbagents.core.run_dir import RunRef
from sbagents.errors import UsageError
from sbagents.source_tree import shadowing_folder, shadowing_hint


class ArgumentParser(argparse.ArgumentParser):
    """argparse with a one-line error and exit code 2 (no usage dump)."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def add_run_arguments(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, *, required: bool = True, exp_id: bool = True,
    load_best: bool = True, env_kwargs: bool = False, trust: bool = True,
) -> None:
    """The flags that pick finished runs (a :class:`~sbagents.core.run_dir.RunRef`, see :func:`run_ref`):
    ``--algo --env -f --gym-packages``, plus ``--exp-id`` and ``--load-best`` / ``--load-checkpoint`` for commands
    on one run.

    :param required: ``--algo`` and ``--env`` must be given (else they filter, as for ``plot``).
    :param env_kwargs: add ``--env-kwargs KEY:VALUE...`` (parsed as ``train``'s): env constructor arguments on top of
        the run's, for commands that build its env.
    :param trust: add ``--trust-run`` (commands that load a run's model and statistics).
    """
    parser.add_argument("--algo", required=required, default=None,
                        help="algorithm of the run" if required else "algorithm of the run(s) (default: any)")
    parser.add_argument("--env", required=required, default=None,
                        help="env id of the run" if required else "env id of the run(s) (default: any)")
    parser.add_argument("-f", "--log-folder", default="logs", help="root of the run dirs (default: logs)")
    if exp_id:
        parser.add_argument("--exp-id", type=int, default=0, help="run number k (0 = latest)")
    if load_best:
        which = parser.add_mutually_exclusive_group()
        which.add_argument("--load-best", action="store_true", help="use best_model.zip instead of the final model")
        which.add_argument("--load-checkpoint", type=int, default=None, metavar="STEPS",
                           help="use the checkpoint saved after STEPS timesteps (train --save-freq)")
    parser.add_argument("--gym-packages", nargs="+", default=[], help="packages to import that register envs")
    if env_kwargs:
        parser.add_argument("--env-kwargs", nargs="+", metavar="KEY:VALUE",
                            help="env constructor keyword arguments on top of the run's (as train's --env-kwargs)")
    if trust:
        parser.add_argument("--trust-run", action="store_true",
                            help="the run comes from a source you trust: load pickles in its files (older runs' "
                                 "vecnormalize.pkl, model entries beyond plain data); see docs/security.md")


def run_ref(args: argparse.Namespace) -> RunRef:
    """The :class:`~sbagents.core.run_dir.RunRef` of the flags of :func:`add_run_arguments`."""
    env_kwargs: dict[str, Any] = {}
    if getattr(args, "env_kwargs", None):
        from sbagents.core.zoo_config import parse_overrides  # imports gymnasium: only when given

        env_kwargs = parse_overrides(args.env_kwargs, "--env-kwargs")
    return RunRef(args.algo, args.env, args.log_folder, exp_id=getattr(args, "exp_id", 0),
                  load_best=getattr(args, "load_best", False), gym_packages=tuple(args.gym_packages),
                  checkpoint=getattr(args, "load_checkpoint", None), env_kwargs=env_kwargs,
                  trust=getattr(args, "trust_run", False))


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def describe_os_error(exc: OSError) -> str:
    """``cannot use /proc/x: No such file or directory`` (the path and the reason, no errno noise)."""
    where = f" {exc.filename}" if exc.filename else ""
    return f"cannot use{where}: {exc.strerror or exc}"


def run(prog: str, body: Callable[[], int | None]) -> NoReturn:
    """Run a CLI body: SIGTERM acts like Ctrl-C; :class:`UsageError` and file-system errors (a path that
    cannot be read or written) become one line on stderr and exit code 2, and so does a folder named ``sbagents``
    that Python imported instead of the package (:func:`~sbagents.source_tree.shadowing_folder`)."""
    shadow = shadowing_folder()
    if shadow is not None:  # nothing of sbagents is registered: say why instead of "unknown env id"
        print(f"{prog}: error: {shadowing_hint(shadow)}", file=sys.stderr)
        raise SystemExit(2)
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
