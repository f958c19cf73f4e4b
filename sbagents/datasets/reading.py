"""A Minari dataset -> its episodes, or the (observation, action) pairs of its episodes, checked against the spaces of
the env they are to train (any Minari dataset: one written by ``python -m sbagents.collect`` or by Minari itself)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.datasets.cloning import Transitions
from sbagents.datasets.writing import require_minari
from sbagents.errors import UsageError


@dataclass(frozen=True)
class Episode:
    """One recorded episode of ``T`` steps.

    :param observations: ``(T + 1, *obs_shape)`` (a dict of such arrays for a ``Dict`` space): every observation,
        the last one after the final step.
    :param actions: ``(T, *action_shape)``.
    :param rewards: ``(T,)``.
    :param terminations: ``(T,)`` booleans (true at most at the last step).
    :param truncations: ``(T,)`` booleans.
    """

    observations: Any
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    def observation(self, t: int) -> Any:
        """The observation before step ``t`` (``t == len(self)``: the last one)."""
        obs = self.observations
        return {k: v[t] for k, v in obs.items()} if isinstance(obs, dict) else obs[t]


def load_episodes(dataset_id: str, observation_space: spaces.Space[Any], action_space: spaces.Space[Any],
                  flag: str = "--pretrain") -> list[Episode]:
    """Every episode of the dataset ``dataset_id`` that has steps.

    :param flag: the option the dataset came from, as errors name it.
    :raises UsageError: (one line) a dataset that is not there or does not load, spaces that differ from the env's,
        or a dataset without steps.
    """
    minari = require_minari()
    try:
        dataset = minari.load_dataset(dataset_id)
    except Exception as exc:  # noqa: BLE001 - Minari raises many kinds for a missing or damaged dataset
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UsageError(f"{flag} {dataset_id}: cannot load the dataset ({reason})") from None
    for what, theirs, ours in (("observation", dataset.spec.observation_space, observation_space),
                               ("action", dataset.spec.action_space, action_space)):
        if theirs != ours:
            raise UsageError(f"{flag} {dataset_id}: its {what} space {theirs} is not the env's {ours}")
    episodes: list[Episode] = []
    try:
        for data in dataset.iterate_episodes():
            actions = np.asarray(data.actions)
            if len(actions):
                episodes.append(Episode(data.observations, actions, np.asarray(data.rewards, dtype=np.float32),
                                        np.asarray(data.terminations, dtype=bool),
                                        np.asarray(data.truncations, dtype=bool)))
    except Exception as exc:  # noqa: BLE001 - a damaged file fails while episodes are read
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UsageError(f"{flag} {dataset_id}: cannot read its episodes ({reason})") from None
    if not episodes:
        raise UsageError(f"{flag} {dataset_id}: the dataset holds no steps")
    return episodes


def transitions_of(episodes: list[Episode]) -> Transitions:
    """The (observation, action) pairs of ``episodes``: the observation each action was taken on."""
    first = episodes[0].observations
    if isinstance(first, dict):
        stacked: Any = {k: np.concatenate([e.observations[k][:-1] for e in episodes]) for k in first}
    else:
        stacked = np.concatenate([e.observations[:-1] for e in episodes])
    return Transitions(stacked, np.concatenate([e.actions for e in episodes]))


def load_transitions(dataset_id: str, observation_space: spaces.Space[Any], action_space: spaces.Space[Any]
                     ) -> Transitions:
    """Every step's (observation, action) of the dataset ``dataset_id`` (see :func:`load_episodes`)."""
    return transitions_of(load_episodes(dataset_id, observation_space, action_space))
