"""Where the env copies of a team VecEnv run: in this process, or in worker processes (``--vec-env subproc``, for
envs whose step dominates the training time). Both give the same :class:`~sbagents.multiagent.env_copy.CopyStep`
results for the same actions, so the choice changes speed only.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
from collections.abc import Callable, Mapping, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv

from sbagents.multiagent.env_copy import CopyStep, EnvCopy

EnvFn = Callable[[], ParallelEnv]


class LocalCopies:
    """The copies in this process.

    :param env_fns: one zero-argument constructor per copy.
    :param with_state: collect ``env.state()`` after every reset and step.
    """

    def __init__(self, env_fns: Sequence[EnvFn], with_state: bool = False) -> None:
        self.copies = [EnvCopy(fn, with_state) for fn in env_fns]

    def reset(self, index: int, seed: int | None, options: Mapping[str, Any] | None
              ) -> tuple[dict[str, Any], dict[str, dict[str, Any]], np.ndarray | None]:
        """Reset copy ``index``."""
        return self.copies[index].reset(seed, options)

    def step(self, actions: Sequence[Mapping[str, Any]]) -> list[CopyStep]:
        """Step every copy with its actions (agent -> action)."""
        return [copy.step(acts) for copy, acts in zip(self.copies, actions, strict=True)]

    def call(self, index: int, name: str, *args: Any, **kwargs: Any) -> Any:
        """``getattr(env, name)(*args, **kwargs)`` of copy ``index``'s env (or the attribute, without arguments
        and when it is not callable)."""
        value = getattr(self.copies[index].env, name)
        return value(*args, **kwargs) if callable(value) else value

    def set(self, index: int, name: str, value: Any) -> None:
        """``setattr(env, name, value)`` on copy ``index``'s env."""
        setattr(self.copies[index].env, name, value)

    def close(self) -> None:
        """Close every env."""
        for copy in self.copies:
            copy.close()


def _worker(remote: Connection, env_fns: list[EnvFn], with_state: bool) -> None:
    copies = [EnvCopy(fn, with_state) for fn in env_fns]
    try:
        while True:
            command, payload = remote.recv()
            if command == "step":
                remote.send([c.step(a) for c, a in zip(copies, payload, strict=True)])
            elif command == "reset":
                index, seed, options = payload
                remote.send(copies[index].reset(seed, options))
            elif command == "call":
                index, name, args, kwargs = payload
                value = getattr(copies[index].env, name)
                remote.send(value(*args, **kwargs) if callable(value) else value)
            elif command == "set":
                index, name, value = payload
                setattr(copies[index].env, name, value)
                remote.send(None)
            elif command == "close":
                break
    except (EOFError, KeyboardInterrupt):  # the parent went away or Ctrl-C reached the whole process group
        pass
    finally:
        for copy in copies:
            copy.close()
        remote.close()


class SubprocCopies:
    """The copies in ``n_workers`` worker processes (each holds a contiguous share of the copies).

    The env constructors must be picklable (module-level functions or ``functools.partial``); the workers start
    with the ``forkserver`` method where available (as SB3's ``SubprocVecEnv``), else ``spawn``.
    """

    def __init__(self, env_fns: Sequence[EnvFn], with_state: bool = False, n_workers: int | None = None) -> None:
        n_workers = max(1, min(n_workers or mp.cpu_count() or 1, len(env_fns)))
        bounds = np.linspace(0, len(env_fns), n_workers + 1).astype(int)
        self._shares = [list(range(lo, hi)) for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]
        method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        ctx: Any = mp.get_context(method)
        self._remotes: list[Connection] = []
        self._processes = []
        for share in self._shares:
            remote, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, [env_fns[i] for i in share], with_state), daemon=True)
            proc.start()
            child.close()
            self._remotes.append(remote)
            self._processes.append(proc)
        self._where = {i: (w, j) for w, share in enumerate(self._shares) for j, i in enumerate(share)}

    def reset(self, index: int, seed: int | None, options: Mapping[str, Any] | None
              ) -> tuple[dict[str, Any], dict[str, dict[str, Any]], np.ndarray | None]:
        """Reset copy ``index`` in its worker."""
        worker, local = self._where[index]
        self._remotes[worker].send(("reset", (local, seed, options)))
        result: tuple[dict[str, Any], dict[str, dict[str, Any]], np.ndarray | None] = self._remotes[worker].recv()
        return result

    def step(self, actions: Sequence[Mapping[str, Any]]) -> list[CopyStep]:
        """Step every copy; the workers step their shares in parallel."""
        for remote, share in zip(self._remotes, self._shares, strict=True):
            remote.send(("step", [actions[i] for i in share]))
        results: list[CopyStep] = []
        for remote in self._remotes:
            results.extend(remote.recv())
        return results

    def call(self, index: int, name: str, *args: Any, **kwargs: Any) -> Any:
        """An attribute or method call on copy ``index``'s env, in its worker."""
        worker, local = self._where[index]
        self._remotes[worker].send(("call", (local, name, args, kwargs)))
        return self._remotes[worker].recv()

    def set(self, index: int, name: str, value: Any) -> None:
        """``setattr`` on copy ``index``'s env, in its worker."""
        worker, local = self._where[index]
        self._remotes[worker].send(("set", (local, name, value)))
        self._remotes[worker].recv()

    def close(self) -> None:
        """Stop the workers (they close their envs)."""
        for remote in self._remotes:
            with contextlib.suppress(BrokenPipeError, EOFError, ConnectionResetError):
                remote.send(("close", None))
        for proc in self._processes:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
