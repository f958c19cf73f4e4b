"""Stepping one :class:`~sbagents.multiagent.team.Team` for several groups of agents, each seen by its own SB3
VecEnv (its own model): :class:`JointStepper`.

Every group submits its actions; once all have, the team steps once and each group takes its share of the result.
Single-threaded code (evaluation, one shared group) calls all ``step_async`` first, then the ``step_wait`` s. For
training, one SB3 ``learn`` per group runs in its own thread, and :class:`Turns` lets exactly one of them run at a
time, in group order, handing over at every env step (threads used as coroutines): the models never run
concurrently, so a run is as reproducible as a single-model one, and every group's SB3 loop (rollouts, training,
callbacks, logging) stays SB3's own.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from sbagents.multiagent.team import Team, TeamStep


class LockstepAborted(RuntimeError):
    """Raised in a group's thread when another group failed, stopped training or the run was interrupted."""


class Turns:
    """Lets ``n`` threads run one at a time, in order ``0 .. n-1``, each until it hands the turn over.

    :meth:`stop` ends the rotation: every thread waiting for its turn (and any that asks later) gets
    :class:`LockstepAborted`, so no thread is left waiting forever.
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.turn = 0
        self.reason: str | None = None
        self._finished: set[int] = set()
        self._cond = threading.Condition()

    def wait(self, index: int) -> None:
        """Block until it is ``index``'s turn (or raise :class:`LockstepAborted` once stopped)."""
        with self._cond:
            self._cond.wait_for(lambda: self.turn == index or self.reason is not None)
            if self.reason is not None:
                raise LockstepAborted(self.reason)

    def hand_over(self, index: int) -> None:
        """Give the turn to the next thread that has not finished."""
        with self._cond:
            nxt = (index + 1) % self.n
            while nxt in self._finished and len(self._finished) < self.n:
                nxt = (nxt + 1) % self.n
            self.turn = nxt
            self._cond.notify_all()

    @property
    def finished(self) -> set[int]:
        """The threads that left the rotation."""
        with self._cond:
            return set(self._finished)

    def finish(self, index: int) -> None:
        """``index`` is done: it leaves the rotation (and hands the turn over)."""
        with self._cond:
            self._finished.add(index)
        self.hand_over(index)

    def stop(self, reason: str) -> None:
        """End the rotation for every thread."""
        with self._cond:
            if self.reason is None:
                self.reason = reason
            self._cond.notify_all()


class JointStepper:
    """The coordination of the groups of one team (see the module docstring).

    :param team: the env copies.
    :param groups: group name -> its agents (every agent of the team in exactly one group).
    """

    def __init__(self, team: Team, groups: dict[str, list[str]]) -> None:
        self.team = team
        self.groups = groups
        self.order = list(groups)
        self._actions: dict[str, np.ndarray] = {}
        self._submitted: set[str] = set()
        self._reset_pending: set[str] = set()
        self._step_pending: set[str] = set()
        self._last: TeamStep | None = None
        self._reset_result: tuple[dict[str, np.ndarray], dict[str, list[dict[str, Any]]]] | None = None
        self.turns: Turns | None = None  # set for threaded training
        self._closed = False

    # ------------------------------------------------------------------ single-threaded and threaded protocol
    def submit(self, group: str, actions: dict[str, np.ndarray]) -> None:
        """Group ``group``'s actions for the next step (``agent -> (n_envs, ...)``)."""
        self._actions.update(actions)
        self._submitted.add(group)

    def step_result(self, group: str) -> TeamStep:
        """The team step this group's submitted actions took part in (stepping the team when all groups have
        submitted; in threaded training, waiting for the other groups' turns first)."""
        self._check_running()
        if self._submitted >= set(self.order):
            self._last = self.team.step(self._actions)
            self._actions, self._submitted = {}, set()
            self._step_pending = set(self.order) - {group}
        elif self.turns is None and group not in self._step_pending:
            missing = ", ".join(g for g in self.order if g not in self._submitted)
            raise RuntimeError(f"every group submits its actions before the first collects: missing {missing}")
        self._wait_round(group)
        self._step_pending.discard(group)
        assert self._last is not None, "a group stepped before the team was reset"
        return self._last

    def reset(self, group: str) -> tuple[dict[str, np.ndarray], dict[str, list[dict[str, Any]]]]:
        """The team's reset observations: the first group to ask resets the team, the others (asking next, in any
        order) get the same observations."""
        self._check_running()
        if group in self._reset_pending:
            self._reset_pending.discard(group)
        else:
            self._reset_result = self.team.reset()
            self._reset_pending = set(self.order) - {group}
            self._actions, self._submitted = {}, set()
        self._wait_round(group)
        assert self._reset_result is not None
        return self._reset_result

    def _check_running(self) -> None:
        if self.turns is not None and self.turns.finished:
            raise LockstepAborted(f"group(s) {', '.join(self.order[i] for i in sorted(self.turns.finished))} "
                                  "stopped training, so the team cannot step")

    def _wait_round(self, group: str) -> None:
        if self.turns is None:
            return
        index = self.order.index(group)
        self.turns.hand_over(index)
        self.turns.wait(index)

    def seed(self, seed: int | None) -> Sequence[int | None]:
        """Seed the team's next reset (copy ``i`` with ``seed + i``)."""
        return self.team.seed(seed)

    def close(self) -> None:
        """Close the team (once, whichever group's VecEnv asks first)."""
        if not self._closed:
            self._closed = True
            self.team.close()
