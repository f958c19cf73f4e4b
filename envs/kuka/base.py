"""What every Kuka env shares: the settings checked alike, one control step under an optional safety zone,
rendering and closing (:class:`KukaEnvBase`), and chapter 6's perturbation defaults (:class:`RobustDefaults`).

Subclasses: the pushes (:mod:`sbagents.envs.kuka.envs`, :mod:`sbagents.envs.kuka.goal`) and the pick and place
(:mod:`sbagents.envs.kuka.pick`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeAlias

import gymnasium as gym
import numpy as np

from sbagents.envs.bounds import MAX_EPISODE_STEPS, check_int
from sbagents.envs.kuka.robot import KukaIiwa
from sbagents.envs.kuka.sim import BulletSim
from sbagents.envs.kuka.tasks import SafetyZone, make_safety_zone

#: What a step into the safety zone does: ``"block"`` undoes it (book), ``"cost"`` applies it and reports a cost.
ZONE_MODES = ("block", "cost")
#: Bound of every observed position coordinate (m); observations are clipped to it.
POS_BOUND = 5.0
XYZ = ("x", "y", "z")

ZoneSpec: TypeAlias = str | SafetyZone | Sequence[Sequence[float]] | None


def _inside(zone: SafetyZone, point: np.ndarray) -> bool:
    """:meth:`SafetyZone.contains` on plain floats (the same comparisons, ~10x faster on a ``(3,)`` point)."""
    lo, hi = zone.low, zone.high
    x, y, z = point.tolist()
    return lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1] and lo[2] <= z <= hi[2]


def attribute_ranges(
    scale_range: Sequence[float] | None, mass_range: Sequence[float] | None
) -> dict[str, tuple[float, float]]:
    """Declared ranges of the per-episode attributes in ``info`` (fairness buckets use them)."""
    return {
        key: (float(r[0]), float(r[1]))
        for key, r in (("object_scale", scale_range), ("object_mass", mass_range))
        if r is not None
    }


class KukaEnvBase(gym.Env[Any, np.ndarray]):
    """A Kuka env: checked settings, one control step under an optional safety zone, rendering, closing.

    Subclasses call :meth:`_init_common` first, build :attr:`sim` and :attr:`robot`, and provide three hooks:
    ``_command(targets)`` (send the motor targets: the arm's ``(7,)`` joint angles, then any extra actuator
    values), ``_snapshot()`` and ``_restore(snapshot)`` (the state a rejected step returns to).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 24}
    sim: BulletSim
    robot: KukaIiwa

    def _init_common(self, max_steps: int, safety_zone: ZoneSpec, zone_mode: str, render_mode: str | None) -> None:
        """Check and keep the settings every Kuka env has (:class:`ValueError` naming what is accepted)."""
        if zone_mode not in ZONE_MODES:
            raise ValueError(f"zone_mode must be one of {ZONE_MODES}, got {zone_mode!r}")
        max_steps = check_int(max_steps, "max_steps", 1, MAX_EPISODE_STEPS)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.safety_zone: SafetyZone | None = make_safety_zone(safety_zone)
        self.zone_mode = zone_mode

    def _command(self, targets: np.ndarray) -> None:
        raise NotImplementedError

    def _snapshot(self) -> Any:
        raise NotImplementedError

    def _restore(self, snapshot: Any) -> None:
        raise NotImplementedError

    def _apply(self, targets: np.ndarray) -> bool:
        """Command ``targets`` and simulate one step; True if the end effector entered the zone (block mode: the
        state is then restored, cost mode: the step is kept)."""
        zone = self.safety_zone
        if zone is None:
            self._command(targets)
            self.sim.step()
            return False
        if self.zone_mode == "cost":
            self._command(targets)
            entered = False
            for _ in range(self.sim.n_substeps):
                self.sim.step(1)
                entered = entered or _inside(zone, self.robot.ee_position())
            return entered
        if zone.contains(self.robot.forward_kinematics(targets[: self.robot.n_joints])):
            return True
        snapshot = self._snapshot()
        self._command(targets)
        for _ in range(self.sim.n_substeps):
            self.sim.step(1)
            if _inside(zone, self.robot.ee_position()):
                self._restore(snapshot)
                return True
        return False

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """``rgb_array``: an ``(H, W, 3)`` uint8 frame; ``human``: the GUI shows the scene, returns None."""
        if self.render_mode == "rgb_array":
            return self.sim.render()
        return None

    def close(self) -> None:
        """Disconnect this env's physics client."""
        self.sim.close()


class RobustDefaults:
    """Chapter 6's perturbations as defaults, for a Kuka env listed after this class: observation noise 0.05 m,
    object scale U(0.5, 1.5), mass U(0.1, 1.0) kg and the default safety zone; every other argument passes on."""

    def __init__(
        self,
        noise_level: float = 0.05,
        scale_range: Sequence[float] | None = (0.5, 1.5),
        mass_range: Sequence[float] | None = (0.1, 1.0),
        safety_zone: ZoneSpec = "default",
        **kwargs: Any,
    ) -> None:
        super().__init__(  # type: ignore[call-arg]
            noise_level=noise_level, scale_range=scale_range, mass_range=mass_range, safety_zone=safety_zone, **kwargs
        )
