"""A scripted inverse-kinematics controller that pushes the block onto the target.

It proves the Kuka tasks feasible (tests require >= 90% success with no safety violation) and is a
baseline for learned agents. It reads the block and target positions from the *observation* only
(so it sees the robust variant's sensor noise) and uses the env's arm model for kinematics only
(forward kinematics of the observed joint angles, inverse kinematics of its waypoints).

Plan: while the block rests, average its noisy observed position; move the tool above a start point
behind the block on the block->target line, lower it to pushing height, then push along the line and
stop where the block, in contact with the tool, sits on the target. The stopping point depends on the
target (exact) and not on the block estimate, so the noise only shifts the contact point sideways.

For ``object="cube"`` the defaults change (:data:`CUBE_DEFAULTS`): a tool that stalls short of a waypoint at the
rim of the arm's workspace pushes from where it is, and a cube that drifts off the push line is pushed again
from behind (the tool backs off and lifts first).

With ``via`` the tool first visits these end-effector waypoints (a detour), then plans as above:
``PATH_DETOUR`` keeps a push from the ready pose out of ``safety_zone="path"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from sbagents.envs.kuka.envs import KukaPushEnv
from sbagents.envs.kuka.robot import N_CONTROLLED, PUSHER_RADIUS
from sbagents.envs.kuka.tasks import BLOCK_HALF_HEIGHT, CUBE_SIZE

#: End-effector waypoint that takes the tool from the ready pose around ``safety_zone="path"`` (back over the
#: robot's side of the block at the ready height, then down behind the block).
PATH_DETOUR: tuple[tuple[float, float, float], ...] = ((0.45, -0.08, 0.31),)

#: :class:`ScriptedPusher` defaults for the book's block (m, m per step).
BLOCK_DEFAULTS: dict[str, float] = {
    "push_speed": 0.03,
    "approach_height": 0.15,
    "contact_offset": PUSHER_RADIUS + BLOCK_HALF_HEIGHT,
    "standoff": 0.05,
    "overshoot": 0.03,
    "stall": 0.0,
    "replan": 0.0,
}
#: :class:`ScriptedPusher` defaults for ``object="cube"``.
CUBE_DEFAULTS: dict[str, float] = {
    "push_speed": 0.04,
    "approach_height": 0.07,
    "contact_offset": PUSHER_RADIUS + CUBE_SIZE / 2,
    "standoff": 0.02,
    "overshoot": 0.0,
    "stall": 0.002,
    "replan": 0.015,
}


class ScriptedPusher:
    """Waypoint controller for :class:`~sbagents.envs.kuka.envs.KukaPushEnv` and its subclasses.

    :param env: the environment (wrappers allowed); its ``control`` ("joints" or "ee") is honoured.
    :param push_speed: tool speed along the push line (m per step).
    :param approach_height: tool height (m, end-effector frame) while travelling above the block.
    :param push_height: height of the pusher's tip while pushing (m).
    :param contact_offset: distance from the pusher's axis to the block centre when they touch
        along the push direction (rod radius + block half width at scale 1).
    :param standoff: extra distance behind the block where the tool is lowered.
    :param min_samples: observations of the resting block to average before pushing (the tool waits
        behind the block until it has them). Default: 55 when the env's ``noise_level`` is positive
        (0.05 / sqrt(55) = 7 mm), else 1.
    :param overshoot: how far past the planned end point the tool may push (success ends the episode).
    :param via: end-effector waypoints ``(x, y, z)`` to visit, in order, before the approach (default: none).
    :param stall: if positive, a waypoint the arm cannot reach (at the rim of its workspace) counts as reached
        when the tool moved less than this (m) in the last step while within 3 cm of it horizontally, so the
        tool pushes from as close as it gets; 0 (default for the block): wait for the waypoint.
    :param replan: if positive, re-plan the push (back up behind the block and push again) when the observed
        block is this far (m) sideways off the push line (a push off its centre turned it); 0: never.

    Defaults of ``None`` depend on the env's object (see :data:`CUBE_DEFAULTS`): the book's block keeps
    the values above; panda-gym's 4 cm cube (``object="cube"``) gets a contact offset of its half width,
    a lower approach, a shorter standoff, a faster push, stall detection and re-planning, so that it succeeds
    in panda-gym's randomized workspace (``benchmarks/configs/kuka_random.yml``) within 50 steps.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        push_speed: float | None = None,
        approach_height: float | None = None,
        push_height: float = 0.004,
        contact_offset: float | None = None,
        standoff: float | None = None,
        min_samples: int | None = None,
        overshoot: float | None = None,
        via: Sequence[Sequence[float]] = (),
        stall: float | None = None,
        replan: float | None = None,
    ) -> None:
        base = env.unwrapped
        if not isinstance(base, KukaPushEnv):
            raise TypeError(f"ScriptedPusher needs a KukaPushEnv, got {type(base).__name__}")
        self.env = base
        defaults = CUBE_DEFAULTS if base.task.object == "cube" else BLOCK_DEFAULTS
        self.push_speed = defaults["push_speed"] if push_speed is None else push_speed
        self.approach_height = defaults["approach_height"] if approach_height is None else approach_height
        self.push_height = push_height
        self.contact_offset = defaults["contact_offset"] if contact_offset is None else contact_offset
        self.standoff = defaults["standoff"] if standoff is None else standoff
        self.stall = defaults["stall"] if stall is None else stall
        self.replan = defaults["replan"] if replan is None else replan
        overshoot = defaults["overshoot"] if overshoot is None else overshoot
        if min_samples is None:
            min_samples = 55 if base.task.noise_level > 0 else 1
        self.min_samples = min_samples
        self.overshoot = overshoot
        self.via = [np.asarray(p, dtype=np.float64) for p in via]
        self.reset()

    def reset(self) -> None:
        """Forget the episode (call after every ``env.reset``)."""
        self.phase = "via" if self.via else "approach"
        self._waypoint = 0
        self._sum = np.zeros(3)
        self._count = 0
        self._line: tuple[np.ndarray, np.ndarray] | None = None
        self._previous_ee: np.ndarray | None = None
        self._retreat = np.zeros(3)

    def _parse(self, obs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint angles (6,), observed block position (3,), target (3,) from either observation layout."""
        if isinstance(obs, dict):
            flat = np.asarray(obs["observation"], dtype=np.float64)
            return (
                flat[:N_CONTROLLED],
                flat[N_CONTROLLED + 3 : N_CONTROLLED + 6],
                np.asarray(obs["desired_goal"]),
            )
        flat = np.asarray(obs, dtype=np.float64)
        return (
            flat[:N_CONTROLLED],
            flat[N_CONTROLLED : N_CONTROLLED + 3],
            flat[N_CONTROLLED + 3 : N_CONTROLLED + 6],
        )

    def _plan(self, block: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points ``(3,)`` of the tool's push line for a block estimate and a target."""
        delta = target[:2] - block[:2]
        u = delta / max(float(np.linalg.norm(delta)), 1e-6)
        start = block[:2] - u * (self.contact_offset + self.standoff)
        end = target[:2] - u * self.contact_offset
        return np.array([*start, self.push_height]), np.array([*end, self.push_height])

    def act(self, obs: Any) -> np.ndarray:
        """Action for ``obs`` in the env's action space (joint deltas or end-effector deltas)."""
        q6, block_obs, target = self._parse(obs)
        q = np.zeros(self.env.robot.n_joints)
        q[:N_CONTROLLED] = q6
        ee = self.env.robot.forward_kinematics(q)
        stalled = self._stalled(ee)
        if self.phase == "push" and self.replan > 0 and self._off_line(block_obs):
            # back off along the line and lift, so that the tool does not sweep the block on its way round
            assert self._line is not None
            line = self._line[1] - self._line[0]
            back = ee - line / max(float(np.linalg.norm(line)), 1e-6) * self.standoff
            self._retreat = np.array([back[0], back[1], self.push_height + self.approach_height])
            self.phase, self._sum, self._count = "retreat", np.zeros(3), 0
        if self.phase == "retreat":  # the block may still slide: average from the approach on
            self._sum, self._count = np.zeros(3), 0
        if self.phase != "push":
            self._sum += block_obs
            self._count += 1
            start, end = self._plan(self._sum / self._count, target)
            self._line = (start, end)
        assert self._line is not None
        start, end = self._line
        above = start + np.array([0.0, 0.0, self.approach_height - self.push_height])
        if self.phase == "retreat":
            goal = self._retreat
            if np.linalg.norm(ee - goal) < 0.03 or stalled:
                self.phase = "approach"
        if self.phase == "via":
            goal = self.via[self._waypoint]
            if np.linalg.norm(ee - goal) < 0.03:
                self._waypoint += 1
                self.phase = "via" if self._waypoint < len(self.via) else "approach"
        if self.phase == "approach":
            goal = above
            if np.linalg.norm(ee - above) < 0.03 or (stalled and self._near(ee, above)):
                self.phase = "descend"
        if self.phase == "descend":
            goal = start
            reached = np.linalg.norm(ee - start) < 0.01 or (stalled and self._near(ee, start))
            if reached and self._count >= self.min_samples:
                self.phase = "push"
        if self.phase == "push":
            line = end - start
            length = max(float(np.linalg.norm(line)), 1e-6)
            progress = float(np.dot(ee - start, line) / length**2)
            goal = start + line * min(1.0 + self.overshoot / length, max(progress, 0.0) + self.push_speed / length)
        return self._command(ee, goal, q)

    def _stalled(self, ee: np.ndarray) -> bool:
        """Whether stall detection is on and the tool moved less than :attr:`stall` since the last call."""
        previous, self._previous_ee = self._previous_ee, ee
        return self.stall > 0 and previous is not None and float(np.linalg.norm(ee - previous)) < self.stall

    @staticmethod
    def _near(ee: np.ndarray, goal: np.ndarray) -> bool:
        return float(np.linalg.norm(ee[:2] - goal[:2])) < 0.03

    def _off_line(self, block: np.ndarray) -> bool:
        """Whether the observed block ``(3,)`` is more than :attr:`replan` sideways off the push line."""
        assert self._line is not None
        start, end = self._line
        u = (end - start)[:2] / max(float(np.linalg.norm((end - start)[:2])), 1e-6)
        rel = block[:2] - start[:2]
        return abs(float(rel[0] * u[1] - rel[1] * u[0])) > self.replan

    def _command(self, ee: np.ndarray, goal: np.ndarray, q: np.ndarray) -> np.ndarray:
        space = self.env.action_space
        assert isinstance(space, gym.spaces.Box)
        if self.env.control == "ee":
            action = (goal - ee) / self.env.ee_step
        else:
            action = (self.env.robot.inverse_kinematics(goal) - q)[:N_CONTROLLED]
        return np.clip(action, space.low, space.high).astype(np.float32)

    def predict(
        self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True
    ) -> tuple[np.ndarray, None]:
        """SB3-style ``predict`` for a single (non-vectorised) env: ``(action, None)``."""
        return self.act(obs), None


class ScriptedController(Protocol):
    """What :func:`run_episode` needs of a controller (:class:`ScriptedPusher`, ``scripted_pick.ScriptedPicker``)."""

    def reset(self) -> None: ...

    def act(self, obs: Any) -> np.ndarray: ...


def run_episode(env: gym.Env[Any, Any], controller: ScriptedController, seed: int | None = None) -> dict[str, Any]:
    """Run one episode with ``controller``; return ``return``, ``length``, ``is_success``, ``cost``."""
    obs, _ = env.reset(seed=seed)
    controller.reset()
    total, cost, length = 0.0, 0.0, 0
    info: dict[str, Any] = {}
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(controller.act(obs))
        total += float(reward)
        cost += float(info.get("cost", 0.0))
        length += 1
        done = terminated or truncated
    return {"return": total, "length": length, "is_success": bool(info.get("is_success")), "cost": cost}
