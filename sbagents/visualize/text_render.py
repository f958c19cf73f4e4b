"""Printing an episode as text, one labelled state per step (``evaluate --render`` on ``ansi`` envs).

The wrappers sit *inside* a VecEnv, so the final state of an episode is printed before the VecEnv resets the
env; the state after a reset is printed only when the next episode takes its first step (no dangling board
after the last episode).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TextIO

import gymnasium as gym
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper


class _StatePrinter:
    """Labels and prints ``render()`` texts: ``episode 1, step 3, reward -1`` then the state."""

    def __init__(self, render: Callable[[], Any], stream: TextIO | None) -> None:
        self._render, self.stream = render, stream
        self.episode, self.step, self.total = 0, 0, 0.0
        self._pending: str | None = None

    def _print(self, text: str) -> None:
        print(text + "\n", file=self.stream, flush=True)

    def reset(self) -> None:
        self.episode += 1
        self.step, self.total = 0, 0.0
        self._pending = f"episode {self.episode}, start\n{self._render()}"

    def stepped(self, reward: float, ended: bool, truncated: bool) -> None:
        if self._pending is not None:
            self._print(self._pending)
            self._pending = None
        self.step += 1
        self.total += reward
        self._print(f"episode {self.episode}, step {self.step}, reward {reward:g}\n{self._render()}")
        if ended:
            how = "truncated" if truncated else "terminated"
            self._print(f"episode {self.episode} {how} after {self.step} steps: return {self.total:g}")


class TextStepPrinter(gym.Wrapper[Any, Any, Any, Any]):
    """Print every state of a Gymnasium env made with ``render_mode="ansi"``, labelled with episode and step.

    :param stream: where to print (default: stdout).
    """

    def __init__(self, env: gym.Env[Any, Any], stream: TextIO | None = None) -> None:
        super().__init__(env)
        if env.render_mode != "ansi":
            raise ValueError(f"TextStepPrinter needs render_mode='ansi', got {env.render_mode!r}")
        self._printer = _StatePrinter(env.render, stream)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        result = self.env.reset(**kwargs)
        self._printer.reset()
        return result

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._printer.stepped(float(reward), terminated or truncated, truncated and not terminated)
        return obs, reward, terminated, truncated, info


class ParallelTextStepPrinter(BaseParallelWrapper):  # type: ignore[misc]
    """:class:`TextStepPrinter` for a PettingZoo ``ParallelEnv`` (the reward shown is the team's: the sum)."""

    def __init__(self, env: ParallelEnv, stream: TextIO | None = None) -> None:
        super().__init__(env)
        # every PettingZoo env sets render_mode, but pettingzoo's ParallelEnv does not declare it
        render_mode = env.render_mode  # type: ignore[attr-defined]
        if render_mode != "ansi":
            raise ValueError(f"ParallelTextStepPrinter needs render_mode='ansi', got {render_mode!r}")
        self._printer = _StatePrinter(env.render, stream)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> Any:
        result = self.env.reset(seed=seed, options=options)
        self._printer.reset()
        return result

    def step(self, actions: dict[Any, Any]) -> Any:
        obs, rewards, terms, truncs, infos = self.env.step(actions)
        ended = not self.env.agents
        truncated = bool(truncs) and all(truncs.values()) and not any(terms.values())
        self._printer.stepped(float(sum(rewards.values())), ended, truncated)
        return obs, rewards, terms, truncs, infos


def supports_text(render_modes: Any) -> bool:
    """Whether an env's ``metadata["render_modes"]`` offers ``ansi`` text."""
    return "ansi" in (render_modes or ())
