"""Whether an experiment can run on EnvPool, and with which EnvPool settings; EnvPool itself is not imported here.

EnvPool reproduces SB3's ``AtariWrapper`` (noop reset, frame skip with max-pooling, episodic life, fire reset,
grey 84x84 frames, reward clipping) on an ALE game stepped one frame at a time (a ``<Game>NoFrameskip-v4`` id). So
``--vec-env envpool`` takes an experiment whose only env wrapper is ``AtariWrapper`` (RL Zoo's ``atari`` entry);
frame stacking stays SB3's ``VecFrameStack`` on top, as on the default path. Anything else (other wrappers,
env kwargs, Monitor kwargs) is refused with the reason, so a run never silently trains on other observations.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from sbagents.core.env_names import EnvRef
from sbagents.errors import UsageError

#: How to install EnvPool (the ``atari`` extra), for error messages.
ATARI_EXTRA_HINT = 'pip install "sbagents[atari]" (EnvPool: Linux, Python >= 3.11)'

_ALE_ENTRY_POINT = "ale_py.env:AtariEnv"


@dataclass(frozen=True)
class AtariSettings:
    """SB3 ``AtariWrapper``'s settings for one ALE game, as EnvPool takes them.

    :param game: the ALE ROM name (``pong``, ``space_invaders``): the Gymnasium spec's ``game``.
    :param noop_max: at most this many no-op frames after a game reset (AtariWrapper's ``noop_max``).
    :param frame_skip: frames per agent step; the observation is the max of the last two.
    :param screen_size: side of the square grey observation.
    :param terminal_on_life_loss: a lost life ends the (training) episode; the game goes on at the next reset.
    :param clip_reward: rewards are clipped to their sign (the true score is kept for the monitor).
    :param repeat_action_probability: sticky actions (the Gymnasium spec's, or AtariWrapper's
        ``action_repeat_probability``, whichever is set).
    :param max_episode_steps: agent steps per game at most (the spec's ``max_num_frames_per_episode`` / frame skip).
    """

    game: str
    noop_max: int = 30
    frame_skip: int = 4
    screen_size: int = 84
    terminal_on_life_loss: bool = True
    clip_reward: bool = True
    repeat_action_probability: float = 0.0
    max_episode_steps: int = 27_000

    def envpool_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``envpool.make`` (one grey frame per step: SB3's ``VecFrameStack`` stacks them).

        EnvPool draws ``U[0, noop_max - 1]`` no-ops and needs ``noop_max >= 1``; ``noop_max=0`` (no no-ops in
        AtariWrapper) becomes 1, which is no no-op at all in games with a FIRE action and one otherwise.
        """
        return {
            "stack_num": 1,
            "frame_skip": self.frame_skip,
            "noop_max": max(self.noop_max, 1),
            "episodic_life": self.terminal_on_life_loss,
            "reward_clip": self.clip_reward,
            "img_height": self.screen_size,
            "img_width": self.screen_size,
            "gray_scale": True,
            "use_inter_area_resize": True,
            "use_fire_reset": True,
            "repeat_action_probability": float(self.repeat_action_probability),
            "max_episode_steps": self.max_episode_steps,
            "full_action_space": False,
            "zero_discount_on_life_loss": False,
        }


def envpool_installed() -> bool:
    """Whether the ``envpool`` package can be imported (it is not imported here)."""
    return importlib.util.find_spec("envpool") is not None


def _ale_spec(ref: EnvRef) -> gym.envs.registration.EnvSpec | None:
    if not ref.is_atari:  # a Gymnasium env with an ALE id
        return None
    try:
        spec = gym.spec(ref.env_id)
    except gym.error.Error:
        return None
    return spec if str(spec.entry_point) == _ALE_ENTRY_POINT else None


def _atari_wrapper_class() -> type:
    from stable_baselines3.common.atari_wrappers import AtariWrapper

    return AtariWrapper


def envpool_problems(exp: Any, ref: EnvRef, env_kwargs: dict[str, Any] | None = None) -> list[str]:
    """Why ``exp`` on ``ref`` cannot run on EnvPool (empty: it can).

    :param exp: the :class:`~sbagents.core.experiment.Experiment`.
    :param env_kwargs: the env kwargs the VecEnv would be built with (the experiment's and the call's).
    """
    spec = _ale_spec(ref)
    if spec is None:
        return [f"{ref.env_id} is not an ALE Atari id"]
    problems = []
    kwargs = dict(spec.kwargs or {})
    if kwargs.get("frameskip", 1) != 1 or kwargs.get("obs_type", "rgb") != "rgb":
        problems.append(f"{ref.env_id} skips frames itself (use its NoFrameskip-v4 id)")
    if kwargs.get("full_action_space"):
        problems.append(f"{ref.env_id} uses the full action space")
    wrappers = [w for w, _ in exp.env_wrapper]
    if wrappers != [_atari_wrapper_class()]:
        names = ", ".join(getattr(w, "__name__", str(w)) for w in wrappers) or "none"
        problems.append(f"env_wrapper must be AtariWrapper alone (got {names})")
    if env_kwargs:
        problems.append(f"env kwargs are not passed to EnvPool (got {', '.join(sorted(env_kwargs))})")
    if exp.monitor_kwargs:
        problems.append("monitor_kwargs are not supported")
    return problems


def atari_settings(exp: Any, ref: EnvRef) -> AtariSettings:
    """The EnvPool settings that reproduce ``exp``'s ``AtariWrapper`` on ``ref`` (see :func:`envpool_problems`)."""
    spec = _ale_spec(ref)
    assert spec is not None and exp.env_wrapper, "atari_settings needs an ALE id with AtariWrapper"
    kwargs = dict(spec.kwargs or {})
    wrapper_kwargs = dict(exp.env_wrapper[0][1] or {})
    frame_skip = int(wrapper_kwargs.get("frame_skip", 4))
    max_frames = int(kwargs.get("max_num_frames_per_episode") or 108_000)
    sticky = float(wrapper_kwargs.get("action_repeat_probability", 0.0)) or float(
        kwargs.get("repeat_action_probability", 0.0))
    return AtariSettings(
        game=str(kwargs["game"]),
        noop_max=int(wrapper_kwargs.get("noop_max", 30)),
        frame_skip=frame_skip,
        screen_size=int(wrapper_kwargs.get("screen_size", 84)),
        terminal_on_life_loss=bool(wrapper_kwargs.get("terminal_on_life_loss", True)),
        clip_reward=bool(wrapper_kwargs.get("clip_reward", True)),
        repeat_action_probability=sticky,
        max_episode_steps=max(max_frames // frame_skip, 1),
    )


def check_envpool(exp: Any, ref: EnvRef, env_kwargs: dict[str, Any] | None = None) -> None:
    """Raise a one-line :class:`UsageError` unless ``--vec-env envpool`` can run ``exp`` on ``ref``."""
    problems = envpool_problems(exp, ref, env_kwargs)
    if problems:
        raise UsageError("--vec-env envpool runs ALE <Game>NoFrameskip-v4 ids with AtariWrapper as their only env "
                         f"wrapper: {'; '.join(problems)}")
    if not envpool_installed():
        raise UsageError(f"--vec-env envpool needs EnvPool, which is not installed: {ATARI_EXTRA_HINT}")


def training_vec_env(vec_env: str, exp: Any, ref: EnvRef) -> str:
    """The ``--vec-env`` a training run uses: ``auto`` becomes ``envpool`` for an Atari experiment that EnvPool
    reproduces when EnvPool is installed; ``envpool`` is checked (before any run dir exists); others pass as given.

    :raises UsageError: ``envpool`` where it cannot run (see :func:`check_envpool`).
    """
    if vec_env == "envpool":
        check_envpool(exp, ref, exp.env_kwargs)
    if vec_env != "auto" or not ref.is_atari or not envpool_installed():
        return vec_env
    return "envpool" if not envpool_problems(exp, ref, exp.env_kwargs) else vec_env
