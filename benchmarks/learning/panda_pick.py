"""A scripted grasp for panda-gym's ``PandaPickAndPlace-v3`` (benchmark-only: panda-gym is not a dependency of
sbagents) and the Minari dataset of its episodes, so that ``kuka-pick-demos`` can give the Panda the same number of
demonstrations as our Kuka (``pip install panda-gym``).

The grasp reads the observation only (panda-gym's layout: end-effector position ``[0:3]``, finger width ``[6]``,
cube position ``[7:10]``; the target is ``desired_goal``): above the cube with the fingers open, down to it, close,
then to the target with the fingers closed; each phase moves the end effector toward its point by
``clip(10 * error, -1, 1)`` (panda-gym moves it 5 cm per unit of action).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: m above the cube where the descent starts
ABOVE = 0.05
#: steps the fingers take to close
CLOSE_STEPS = 6


class PandaGrasp:
    """The scripted grasp; :meth:`reset` at every episode's start, then :meth:`__call__` per observation."""

    def __init__(self) -> None:
        self.phase, self.closing = 0, 0

    def reset(self) -> None:
        """A new episode: back to the first phase."""
        self.phase, self.closing = 0, 0

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        o = obs["observation"]
        ee, cube, goal = o[0:3], o[7:10], obs["desired_goal"]
        if self.phase == 0:  # above the cube, fingers open
            target, fingers = cube + [0.0, 0.0, ABOVE], 1.0
            if np.linalg.norm(target - ee) < 0.01:
                self.phase = 1
        if self.phase == 1:  # down to it
            target, fingers = cube, 1.0
            if np.linalg.norm(cube - ee) < 0.008:
                self.phase = 2
        if self.phase == 2:  # close in place
            target, fingers = cube, -1.0
            self.closing += 1
            if self.closing >= CLOSE_STEPS:
                self.phase = 3
        if self.phase == 3:  # carry to the target
            target, fingers = goal, -1.0
        move = np.clip(10.0 * (target - ee), -1.0, 1.0)
        return np.asarray([*move, fingers], dtype=np.float32)


def record(dataset: str, episodes: int, seed: int) -> float:
    """Write ``episodes`` episodes of the grasp on ``PandaPickAndPlace-v3`` (episode ``i`` reset with ``seed + i``) as
    the Minari dataset ``dataset``; the grasp's success rate."""
    import gymnasium as gym
    import panda_gym  # noqa: F401 - registers the Panda envs

    from sbagents.datasets.writing import DatasetInfo, EpisodeRecorder, write_dataset

    env: Any = gym.make("PandaPickAndPlace-v3")
    grasp, recorded, successes = PandaGrasp(), [], 0
    try:
        for i in range(episodes):
            obs, info = env.reset(seed=seed + i)
            grasp.reset()
            recorder = EpisodeRecorder()
            recorder.start(obs, info)
            done = False
            while not done:
                action = grasp(obs)
                obs, reward, terminated, truncated, info = env.step(action)
                recorder.step(action, obs, float(reward), terminated, truncated, info)
                done = terminated or truncated
            successes += bool(info.get("is_success"))
            recorded.append(recorder)
    finally:
        env.close()
    write_dataset(dataset, recorded, [seed + i for i in range(episodes)], "PandaPickAndPlace-v3",
                  DatasetInfo("scripted grasp (benchmarks/learning/panda_pick.py)",
                              description=f"{episodes} episodes of the scripted Panda grasp"),
                  env.observation_space, env.action_space)
    return successes / episodes
