"""SmartHome from the book's final project, as a Gymnasium environment.

Spec (docs/envs.md, SmartHome). The agent controls a thermostat and a light dimmer for a user
with their own preferred temperature and light level.

- State: temperature (18-28 C), light level (0-100 lux), hour of day (0-23), preferred temperature,
  preferred light. The observation is those five numbers (``obs_names``), with Gaussian noise
  (std ``noise_std``, 0.1 by default) on the *observed* temperature and light only; the true values are
  in ``info``.
- Reset: temperature U(20, 24), light U(40, 60), hour uniform in 0..23, preferred temperature U(20, 26),
  preferred light U(50, 80): a different user every episode unless ``preferred_temp`` /
  ``preferred_light`` fix them (a real user).
- Action ``Box([-1, -10], [1, 10])`` (``action_names``): thermostat and light adjustments, added to the
  state, which is then clipped to its range; the hour advances by one per step, modulo 24.
- Reward: ``-|temp - pref_temp| - 0.5 |light - pref_light| - 0.1 (|a_temp| + 0.05 |a_light|)``, on the
  state after the action; ``info["energy"]`` is the step's ``|a_temp| + 0.05 |a_light|`` (energy use).
- ``max_steps`` (100) steps, then truncation; the episode never terminates.
- Partial observability (``preference_steps``, off by default): the user states their preferences only in the
  first ``preference_steps`` observations of an episode (the reset's is the first); later observations show 0
  in their place, so a policy must remember them (``sbagents/SmartHomePrefOnce-v0``: told once, at the reset).

Choices the book leaves open (documented in the README table):

- Observation space: ``Box(float32, (5,))``. Temperature and light bounds are their ranges widened by
  ``5 * noise_std``; the noisy observation is clipped to those bounds (a 5-sigma clip, which changes the
  noise distribution by less than 1e-6). The preferences are bounded by the state ranges.
- Out-of-bounds actions are clipped to the action space (as SB3 does for Box actions before ``step``);
  the clipped action drives both the dynamics and the action penalty. Non-finite actions raise.
- Success: the book's comfort criterion is temperature within ``temp_tolerance`` (1 C) and light within
  ``light_tolerance`` (5 lux) of the preferences. ``info["comfortable"]`` tells it for every step;
  ``info["is_success"]`` (last step only) is ``criterion_share >= success_share`` (0.97), where
  ``criterion_share`` is the share of steps after step ``warmup_steps`` (10) that are comfortable.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sbagents.envs.bounds import MAX_EPISODE_STEPS, check_int, check_number, show

Range = tuple[float, float]

#: The largest noise, tolerance or action bound an env takes (float32 observation bounds stay finite).
MAX_MAGNITUDE = 1e6

OBS_NAMES: tuple[str, ...] = ("Temperature", "Light_Level", "Time", "Preferred_Temp", "Preferred_Light")
ACTION_NAMES: tuple[str, ...] = ("Action_Temp", "Action_Light")


def _range(value: Sequence[float], what: str) -> Range:
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray) or len(value) != 2:
        raise ValueError(f"{what} must be a finite (low, high) with low <= high, got {show(value)}")
    low, high = (check_number(v, what) for v in value)
    if low > high:
        raise ValueError(f"{what} must be a finite (low, high) with low <= high, got {tuple(value)!r}")
    return low, high


def _inside(inner: Range, outer: Range, what: str) -> None:
    if inner[0] < outer[0] or inner[1] > outer[1]:
        raise ValueError(f"{what} {inner} must lie inside {outer}")


class SmartHomeEnv(gym.Env[np.ndarray, np.ndarray]):
    """Keep a home's temperature and light at the (per-episode) user's preferences.

    :param noise_std: std of the Gaussian noise on the observed temperature and light (0 disables it).
    :param temp_tolerance: comfort tolerance on the temperature (C).
    :param light_tolerance: comfort tolerance on the light level (lux).
    :param temp_range: physical temperature range; the temperature is clipped to it.
    :param light_range: physical light range; the light level is clipped to it.
    :param init_temp_range: reset distribution U(low, high) of the temperature.
    :param init_light_range: reset distribution of the light level.
    :param pref_temp_range: reset distribution of the preferred temperature.
    :param pref_light_range: reset distribution of the preferred light level.
    :param preferred_temp: a fixed preferred temperature (a real user) instead of a random one.
    :param preferred_light: a fixed preferred light level instead of a random one.
    :param max_temp_step: thermostat action bound: ``a_temp`` in ``[-max_temp_step, max_temp_step]``.
    :param max_light_step: light action bound.
    :param max_steps: episode length (truncation); the episode never terminates.
    :param warmup_steps: steps excluded from the comfort criterion at the start of an episode.
    :param success_share: ``is_success`` threshold on the episode's criterion share.
    :param preference_steps: observations per episode that show the preferences (None: all of them); the later
        ones show 0 there (the observation bounds then include 0).
    :param render_mode: ``"ansi"`` (the state as a text line), ``"human"`` (prints it) or
        ``"rgb_array"`` (an ``(H, W, 3)`` uint8 bar chart: temperature, light, hour).
    """

    metadata = {"render_modes": ["ansi", "human", "rgb_array"], "render_fps": 4}
    obs_names: tuple[str, ...] = OBS_NAMES
    action_names: tuple[str, ...] = ACTION_NAMES

    def __init__(
        self,
        noise_std: float = 0.1,
        temp_tolerance: float = 1.0,
        light_tolerance: float = 5.0,
        temp_range: Sequence[float] = (18.0, 28.0),
        light_range: Sequence[float] = (0.0, 100.0),
        init_temp_range: Sequence[float] = (20.0, 24.0),
        init_light_range: Sequence[float] = (40.0, 60.0),
        pref_temp_range: Sequence[float] = (20.0, 26.0),
        pref_light_range: Sequence[float] = (50.0, 80.0),
        preferred_temp: float | None = None,
        preferred_light: float | None = None,
        max_temp_step: float = 1.0,
        max_light_step: float = 10.0,
        max_steps: int = 100,
        warmup_steps: int = 10,
        success_share: float = 0.97,
        render_mode: str | None = None,
        preference_steps: int | None = None,
    ) -> None:
        noise_std = check_number(noise_std, "noise_std", 0.0, MAX_MAGNITUDE)
        temp_tolerance = check_number(temp_tolerance, "temp_tolerance", 0.0, MAX_MAGNITUDE)
        light_tolerance = check_number(light_tolerance, "light_tolerance", 0.0, MAX_MAGNITUDE)
        max_steps = check_int(max_steps, "max_steps", 1, MAX_EPISODE_STEPS)
        warmup_steps = check_int(warmup_steps, "warmup_steps", 0, max_steps - 1)
        success_share = check_number(success_share, "success_share", 0.0, 1.0)
        if min(check_number(max_temp_step, "max_temp_step", 0.0, MAX_MAGNITUDE),
               check_number(max_light_step, "max_light_step", 0.0, MAX_MAGNITUDE)) <= 0:
            raise ValueError("action bounds max_temp_step and max_light_step must be > 0")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            modes = self.metadata["render_modes"]
            raise ValueError(f"render_mode must be one of {modes}, got {render_mode!r}")
        self.noise_std = float(noise_std)
        self.temp_tolerance, self.light_tolerance = float(temp_tolerance), float(light_tolerance)
        self.temp_range = _range(temp_range, "temp_range")
        self.light_range = _range(light_range, "light_range")
        self.init_temp_range = _range(init_temp_range, "init_temp_range")
        self.init_light_range = _range(init_light_range, "init_light_range")
        self.pref_temp_range = _range(pref_temp_range, "pref_temp_range")
        self.pref_light_range = _range(pref_light_range, "pref_light_range")
        #: Declared ranges of the per-episode user attributes in ``info`` (fairness buckets use them).
        self.attribute_ranges = {"preferred_temp": self.pref_temp_range, "preferred_light": self.pref_light_range}
        _inside(self.init_temp_range, self.temp_range, "init_temp_range")
        _inside(self.init_light_range, self.light_range, "init_light_range")
        _inside(self.pref_temp_range, self.temp_range, "pref_temp_range")
        _inside(self.pref_light_range, self.light_range, "pref_light_range")
        for value, rng, what in (
            (preferred_temp, self.temp_range, "preferred_temp"),
            (preferred_light, self.light_range, "preferred_light"),
        ):
            if value is not None and not rng[0] <= check_number(value, what) <= rng[1]:
                raise ValueError(f"{what} {value} must lie inside {rng}")
        self.fixed_pref_temp = None if preferred_temp is None else float(preferred_temp)
        self.fixed_pref_light = None if preferred_light is None else float(preferred_light)
        self.max_steps, self.warmup_steps = int(max_steps), int(warmup_steps)
        self.success_share = float(success_share)
        self.render_mode = render_mode
        self.preference_steps = None if preference_steps is None else check_int(
            preference_steps, "preference_steps", 0, MAX_EPISODE_STEPS)

        margin = 5.0 * self.noise_std
        (t_lo, t_hi), (l_lo, l_hi) = self.temp_range, self.light_range
        hidden_low = 0.0 if self.preference_steps is not None else np.inf  # what a hidden preference reads
        self._obs_low = np.array([t_lo - margin, l_lo - margin, 0.0, min(t_lo, hidden_low), min(l_lo, hidden_low)],
                                 np.float32)
        self._obs_high = np.array([t_hi + margin, l_hi + margin, 23.0, t_hi, l_hi], np.float32)
        self._act_low = np.array([-max_temp_step, -max_light_step], np.float32)
        self._act_high = np.array([max_temp_step, max_light_step], np.float32)
        self.observation_space = spaces.Box(self._obs_low, self._obs_high, dtype=np.float32)
        self.action_space = spaces.Box(self._act_low, self._act_high, dtype=np.float32)
        self.temperature = self.light = 0.0
        self.hour = 0
        self.preferred_temp = self.preferred_light = 0.0
        self.steps = 0
        self._n_comfortable = 0
        self._last_action = np.zeros(2, dtype=np.float32)

    # ------------------------------------------------------------------ core API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self.temperature = float(rng.uniform(*self.init_temp_range))
        self.light = float(rng.uniform(*self.init_light_range))
        self.hour = int(rng.integers(0, 24))
        pref_temp = float(rng.uniform(*self.pref_temp_range))
        pref_light = float(rng.uniform(*self.pref_light_range))
        self.preferred_temp = pref_temp if self.fixed_pref_temp is None else self.fixed_pref_temp
        self.preferred_light = pref_light if self.fixed_pref_light is None else self.fixed_pref_light
        self.steps = 0
        self._n_comfortable = 0
        self._last_action = np.zeros(2, dtype=np.float32)
        if self.render_mode == "human":
            self.render()
        return self._observe(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        act = np.asarray(action, dtype=np.float64).reshape(-1)
        if act.shape != (2,) or not np.all(np.isfinite(act)):
            raise ValueError(f"action must be 2 finite numbers (Action_Temp, Action_Light), got {action!r}")
        act = np.clip(act, self._act_low, self._act_high)
        a_temp, a_light = float(act[0]), float(act[1])
        self.temperature = float(np.clip(self.temperature + a_temp, *self.temp_range))
        self.light = float(np.clip(self.light + a_light, *self.light_range))
        self.hour = (self.hour + 1) % 24
        self.steps += 1
        self._last_action = act.astype(np.float32)
        reward = self.reward(a_temp, a_light)
        info = self._info()
        info["energy"] = abs(a_temp) + 0.05 * abs(a_light)
        if self.steps > self.warmup_steps and info["comfortable"]:
            self._n_comfortable += 1
        truncated = self.steps >= self.max_steps
        if truncated:
            share = self._n_comfortable / (self.steps - self.warmup_steps)
            info["criterion_share"] = share
            info["is_success"] = bool(share >= self.success_share)
        if self.render_mode == "human":
            self.render()
        return self._observe(), reward, False, truncated, info

    def reward(self, a_temp: float, a_light: float) -> float:
        """The book's reward for the current (post-action) state and the applied action."""
        return float(
            -abs(self.temperature - self.preferred_temp)
            - 0.5 * abs(self.light - self.preferred_light)
            - 0.1 * (abs(a_temp) + 0.05 * abs(a_light))
        )

    def _observe(self) -> np.ndarray:
        noise = self.np_random.normal(0.0, self.noise_std, size=2) if self.noise_std > 0 else np.zeros(2)
        temp, light = self.temperature + noise[0], self.light + noise[1]
        told = self.preference_steps is None or self.steps < self.preference_steps
        prefs = (self.preferred_temp, self.preferred_light) if told else (0.0, 0.0)
        obs = np.array([temp, light, self.hour, *prefs], dtype=np.float32)
        return np.clip(obs, self._obs_low, self._obs_high)

    def _info(self) -> dict[str, Any]:
        temp_error = abs(self.temperature - self.preferred_temp)
        light_error = abs(self.light - self.preferred_light)
        return {
            "step": self.steps,
            "temperature": self.temperature,
            "light_level": self.light,
            "hour": self.hour,
            "preferred_temp": self.preferred_temp,
            "preferred_light": self.preferred_light,
            "temp_error": temp_error,
            "light_error": light_error,
            "comfortable": bool(temp_error <= self.temp_tolerance and light_error <= self.light_tolerance),
        }

    # ------------------------------------------------------------------ metrics
    @staticmethod
    def episode_metrics(
        infos: Sequence[Mapping[str, Any]],
        warmup_steps: int = 10,
        temp_tolerance: float = 1.0,
        light_tolerance: float = 5.0,
    ) -> dict[str, float]:
        """Comfort metrics of one episode from its per-step ``info`` dicts (the ones ``step`` returned).

        Only steps after step ``warmup_steps`` count (``info["step"]`` when present, else the position
        in ``infos`` starting at 1). A step meets the criterion when ``info["comfortable"]`` is true;
        without that key the errors are compared with the given tolerances.

        :return: ``criterion_share`` (share of counted steps meeting both tolerances), ``mean_temp_error``
            (C) and ``mean_light_error`` (lux) over the counted steps; NaN when no step counts. With ``energy`` in
            the infos (``step`` puts it there) also ``mean_energy``: the mean ``|a_temp| + 0.05 |a_light|``.
        """
        ok: list[float] = []
        temp_errors: list[float] = []
        light_errors: list[float] = []
        energy: list[float] = []
        for position, info in enumerate(infos, start=1):
            if int(info.get("step", position)) <= warmup_steps:
                continue
            t_err = float(info.get("temp_error", abs(info["temperature"] - info["preferred_temp"])))
            l_err = float(info.get("light_error", abs(info["light_level"] - info["preferred_light"])))
            comfortable = info.get("comfortable")
            if comfortable is None:
                comfortable = t_err <= temp_tolerance and l_err <= light_tolerance
            ok.append(float(bool(comfortable)))
            temp_errors.append(t_err)
            light_errors.append(l_err)
            if "energy" in info:
                energy.append(float(info["energy"]))
        nan = float("nan")
        if not ok:
            return {"criterion_share": nan, "mean_temp_error": nan, "mean_light_error": nan}
        metrics = {
            "criterion_share": float(np.mean(ok)),
            "mean_temp_error": float(np.mean(temp_errors)),
            "mean_light_error": float(np.mean(light_errors)),
        }
        if energy:
            metrics["mean_energy"] = float(np.mean(energy))
        return metrics

    # ------------------------------------------------------------------ rendering
    def state_text(self) -> str:
        """The state as one line, the way the book prints it."""
        return (
            f"Step: {self.steps}, Temperature: {self.temperature:.2f} C, Light_Level: {self.light:.2f} lux, "
            f"Time: {self.hour:02d}:00, Preferred_Temp: {self.preferred_temp:.2f} C, "
            f"Preferred_Light: {self.preferred_light:.2f} lux, "
            f"Action: [{self._last_action[0]:.2f}, {self._last_action[1]:.2f}]"
        )

    def render(self) -> str | np.ndarray | None:  # type: ignore[override]  # gymnasium 1.2 types it narrower
        if self.render_mode == "ansi":
            return self.state_text()
        if self.render_mode == "human":
            print(self.state_text())
            return None
        if self.render_mode == "rgb_array":
            return self._rgb()
        return None

    def _rgb(self, height: int = 120, width: int = 160) -> np.ndarray:
        """Three vertical gauges: temperature (red), light (yellow), hour (blue); the comfort band is
        shaded green and the preference is a black line."""
        frame = np.full((height, width, 3), 255, dtype=np.uint8)
        top, bottom = 10, height - 10
        gauges = (
            (self.temperature, self.temp_range, self.preferred_temp, self.temp_tolerance, (220, 60, 40)),
            (self.light, self.light_range, self.preferred_light, self.light_tolerance, (230, 190, 30)),
            (float(self.hour), (0.0, 23.0), None, 0.0, (50, 100, 220)),
        )

        def to_y(value: float, rng: Range) -> int:
            frac = (value - rng[0]) / max(rng[1] - rng[0], 1e-9)
            return int(round(bottom - np.clip(frac, 0.0, 1.0) * (bottom - top)))

        col_w = width // len(gauges)
        for i, (value, rng, pref, tol, colour) in enumerate(gauges):
            x0, x1 = i * col_w + 12, (i + 1) * col_w - 12
            frame[top:bottom, x0:x1] = (225, 225, 225)
            if pref is not None:
                frame[to_y(pref + tol, rng) : to_y(pref - tol, rng) + 1, x0 - 4 : x1 + 4] = (160, 220, 160)
            frame[to_y(value, rng) : bottom, x0 + 4 : x1 - 4] = colour
            if pref is not None:
                y = to_y(pref, rng)
                frame[max(y - 1, 0) : y + 1, x0 - 4 : x1 + 4] = (0, 0, 0)
        return frame
