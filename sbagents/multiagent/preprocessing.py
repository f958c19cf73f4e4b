"""Pixel-observation preprocessing for PettingZoo parallel envs: grayscale and resize, as parallel wrappers.

The wrappers follow SB3's Atari ``WarpFrame`` (OpenCV's ``RGB2GRAY`` weights, ``INTER_AREA`` resizing) and always
return channel-last ``uint8`` images ``(height, width, channels)``, which SB3's ``VecFrameStack`` stacks along the
channel axis and ``VecTransposeImage`` turns into the channel-first input of ``CnnPolicy``. In a zoo entry::

    env_wrapper:
      - sbagents.multiagent.preprocessing.ImagePreprocessing: {grayscale: true, shape: [84, 84]}
    frame_stack: 4      # (84, 84, 1) frames -> (84, 84, 4) observations; CnnPolicy sees (4, 84, 84)
    policy: CnnPolicy

An image observation space is a ``uint8`` :class:`~gymnasium.spaces.Box` of shape ``(H, W)`` or ``(H, W, C)`` with
``C`` in 1, 3 (RGB) or 4 (RGBA); a 2-D image is read as ``(H, W, 1)``. Every agent's observation space must be one.
When the env's ``state_space`` is an image too, ``state()`` is preprocessed the same way (and ``state_space``
updated); any other state passes through unchanged.

Why not SuperSuit's wrappers (3.11; measured in ``tests/test_supersuit_parity.py``): ``color_reduction_v0("full")``
truncates where OpenCV (and ``WarpFrame`` on the Gymnasium side) rounds, one grey level darker on 98% of
pistonball's pixels, takes RGB only and drops the channel axis; ``resize_v1`` resamples bilinearly or nearest, not by
area (up to 167 grey levels apart on cooperative pong at 84x84, where the ball dims to 31 of 255); neither touches an
image ``state()``; and as SuperSuit has no parallel form of them, each runs the env through ``parallel_to_aec`` and
back (about 5x this wrapper's cost per step on pistonball). Frame stacking stays SB3's ``VecFrameStack``
(``frame_stack_v1`` stacks the same values but overwrites one returned array in place); observations stay ``uint8``
(``dtype_v0``/``normalize_obs_v0`` would give float images that SB3's ``CnnPolicy`` refuses).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

from sbagents.errors import UsageError

#: ``(height, width, channels)``
ImageShape = tuple[int, int, int]

_GRAY_CODES = {3: cv2.COLOR_RGB2GRAY, 4: cv2.COLOR_RGBA2GRAY}


def image_shape(space: spaces.Space[Any]) -> ImageShape | None:
    """The ``(H, W, C)`` of an image space (a ``uint8`` Box ``(H, W)`` or ``(H, W, C)``, ``C`` in 1, 3, 4), else
    None."""
    if not isinstance(space, spaces.Box) or space.dtype != np.uint8:
        return None
    shape = tuple(int(n) for n in space.shape)
    if len(shape) == 2:
        return (shape[0], shape[1], 1)
    if len(shape) == 3 and shape[2] in (1, 3, 4):
        return (shape[0], shape[1], shape[2])
    return None


def _target_size(shape: int | Sequence[int] | None) -> tuple[int, int] | None:
    """``shape`` (``n`` for ``(n, n)``, or ``(height, width)``) as a pair of positive ints; None: keep the size."""
    if shape is None:
        return None
    dims = [shape] if isinstance(shape, int) else list(shape)
    if len(dims) == 1:
        dims = dims * 2
    if len(dims) != 2 or not all(isinstance(d, int) and not isinstance(d, bool) and d > 0 for d in dims):
        raise UsageError(f"shape must be a positive int or [height, width] of positive ints, got {shape!r}")
    return (dims[0], dims[1])


class ImagePreprocessing(BaseParallelWrapper):
    """Grayscale and/or resize every agent's image observation (and an image ``state()``).

    Observations ``(H, W, C)`` (or ``(H, W)``) ``uint8`` become ``(h, w, c)`` ``uint8``, where ``(h, w)`` is
    ``shape`` (or ``(H, W)``) and ``c`` is 1 with ``grayscale`` (else ``C``, 1 for a 2-D input). Both
    ``observation_space(agent)`` and the observations of ``reset``/``step`` change; actions, rewards and infos do not.

    :param env: a PettingZoo ``ParallelEnv`` whose agents all observe images.
    :param grayscale: convert RGB(A) to one luminance channel (``cv2.COLOR_RGB2GRAY``: 0.299 R + 0.587 G + 0.114 B).
    :param shape: ``(height, width)`` to resize to with ``cv2.INTER_AREA`` (an int ``n``: ``(n, n)``); None: keep.
    :raises UsageError: an agent (or ``env`` itself) that is not a parallel env of image observations, or a bad
        ``shape``.
    """

    def __init__(self, env: ParallelEnv, grayscale: bool = True, shape: int | Sequence[int] | None = (84, 84)
                 ) -> None:
        name = type(self).__name__
        if not hasattr(env, "possible_agents") or not callable(getattr(env, "observation_space", None)):
            raise UsageError(f"{name} wraps a PettingZoo ParallelEnv, got {type(env).__name__}")
        super().__init__(env)
        self.grayscale = bool(grayscale)
        self.size = _target_size(shape)
        self._spaces: dict[Any, spaces.Box] = {}
        for agent in env.possible_agents:
            space = env.observation_space(agent)
            in_shape = image_shape(space)
            if in_shape is None:
                raise UsageError(f"{name} needs uint8 image observations (H, W) or (H, W, 1|3|4); {agent} observes "
                                 f"{space}")
            self._spaces[agent] = self._out_space(in_shape)
        self.observation_spaces = dict(self._spaces)  # PettingZoo's deprecated dict, kept consistent
        state_space = getattr(env, "state_space", None)
        state_shape = image_shape(state_space) if state_space is not None else None
        self._state_image = state_shape is not None
        if state_shape is not None:
            self.state_space = self._out_space(state_shape)

    def _out_space(self, in_shape: ImageShape) -> spaces.Box:
        height, width, channels = in_shape
        if self.size is not None:
            height, width = self.size
        return spaces.Box(0, 255, (height, width, 1 if self.grayscale else channels), np.uint8)

    def frame(self, image: np.ndarray) -> np.ndarray:
        """One image ``(H, W)`` or ``(H, W, C)`` ``uint8`` -> the preprocessed ``(h, w, c)`` ``uint8`` image."""
        img = np.asarray(image)
        if img.ndim == 2:
            img = img[:, :, None]
        if self.grayscale and img.shape[2] in _GRAY_CODES:
            img = cv2.cvtColor(np.ascontiguousarray(img), _GRAY_CODES[img.shape[2]])[:, :, None]
        if self.size is not None and img.shape[:2] != self.size:
            height, width = self.size
            img = cv2.resize(np.ascontiguousarray(img), (width, height), interpolation=cv2.INTER_AREA)
            if img.ndim == 2:  # OpenCV drops a single channel axis
                img = img[:, :, None]
        return img

    def observation_space(self, agent: Any) -> spaces.Box:
        """The preprocessed image space of ``agent``: ``Box(0, 255, (h, w, c), uint8)``."""
        return self._spaces[agent]

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[Any, np.ndarray], dict[Any, dict[str, Any]]]:
        """Reset the env; the observations are preprocessed."""
        obs, infos = self.env.reset(seed=seed, options=options)
        return {a: self.frame(o) for a, o in obs.items()}, infos

    def step(self, actions: dict[Any, Any]) -> tuple[
        dict[Any, np.ndarray], dict[Any, float], dict[Any, bool], dict[Any, bool], dict[Any, dict[str, Any]]
    ]:
        """Step the env; the observations are preprocessed."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        return {a: self.frame(o) for a, o in obs.items()}, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The env's ``state()``, preprocessed when its ``state_space`` is an image."""
        state = self.env.state()
        return self.frame(state) if self._state_image else state

    def __str__(self) -> str:
        return f"{type(self).__name__}<{self.env}>"


class GrayscaleObservation(ImagePreprocessing):
    """RGB(A) image observations ``(H, W, 3|4)`` -> grayscale ``(H, W, 1)`` ``uint8`` (the channel axis stays).

    :param env: a PettingZoo ``ParallelEnv`` whose agents all observe images.
    """

    def __init__(self, env: ParallelEnv) -> None:
        super().__init__(env, grayscale=True, shape=None)


class ResizeObservation(ImagePreprocessing):
    """Image observations ``(H, W, C)`` -> ``(height, width, C)`` ``uint8`` (``cv2.INTER_AREA``).

    :param env: a PettingZoo ``ParallelEnv`` whose agents all observe images.
    :param shape: ``(height, width)``, or an int ``n`` for ``(n, n)``.
    """

    def __init__(self, env: ParallelEnv, shape: int | Sequence[int] = (84, 84)) -> None:
        super().__init__(env, grayscale=False, shape=shape)
