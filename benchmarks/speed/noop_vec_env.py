"""A VecEnv that does no env work: the speed ceiling of any VecEnv for a given env and SB3 contract.

:class:`NoOpVecEnv` copies one real step of a source VecEnv (observation shape and dtype, one info dict per
slot) and then returns, every step, what SB3 requires of any VecEnv: freshly allocated observation, reward
and done arrays and a fresh info dict per slot (copies of the recorded ones), without computing anything.
No implementation of the env can step faster, and PPO on it pays only SB3's own costs (policy forward
passes, rollout buffer, gradient steps). ``python -m benchmarks`` reports both as ceilings next to the
batched VecEnvs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

#: Info keys that only appear at episode ends (dropped from the recorded per-step infos).
END_KEYS = frozenset({"terminal_observation", "episode", "is_success", "treasures"})


class NoOpVecEnv(VecEnv):
    """Replays one recorded step of ``source`` forever (``source`` is stepped once, then closed).

    :param source: a VecEnv of the env to imitate (its spaces, observation dtype and per-step infos).
    """

    def __init__(self, source: VecEnv) -> None:
        self._obs = np.asarray(source.reset()).copy()
        n = source.num_envs
        shape: tuple[int, ...] = (n, *(source.action_space.shape or ()))
        _, _, _, infos = source.step(np.zeros(shape, dtype=source.action_space.dtype))
        self._infos = [{k: v for k, v in info.items() if k not in END_KEYS} for info in infos]
        super().__init__(n, source.observation_space, source.action_space)
        source.close()

    def reset(self) -> VecEnvObs:
        return self._obs.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._last_actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        n = self.num_envs
        infos = [info.copy() for info in self._infos]
        return self._obs.copy(), np.zeros(n, dtype=np.float32), np.zeros(n, dtype=bool), infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Only ``render_mode`` (None), which SB3's ``VecEnv.__init__`` reads."""
        if attr_name != "render_mode":
            raise AttributeError(f"NoOpVecEnv has no env attribute {attr_name!r}")
        return [None] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        raise NotImplementedError("NoOpVecEnv has no envs")

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        raise NotImplementedError("NoOpVecEnv has no envs")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices: VecEnvIndices) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)
