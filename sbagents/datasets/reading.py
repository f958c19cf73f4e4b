"""A Minari dataset -> the (observation, action) pairs of its episodes, checked against the spaces of the env they
are to train (any Minari dataset: one written by ``python -m sbagents.collect`` or by Minari itself)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.datasets.cloning import Transitions
from sbagents.datasets.writing import require_minari
from sbagents.errors import UsageError


def load_transitions(dataset_id: str, observation_space: spaces.Space[Any], action_space: spaces.Space[Any]
                     ) -> Transitions:
    """Every step's (observation, action) of the dataset ``dataset_id`` (the observation each action was taken on).

    :raises UsageError: (one line) a dataset that is not there or does not load, spaces that differ from the env's,
        or a dataset without steps.
    """
    minari = require_minari()
    try:
        dataset = minari.load_dataset(dataset_id)
    except Exception as exc:  # noqa: BLE001 - Minari raises many kinds for a missing or damaged dataset
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UsageError(f"--pretrain {dataset_id}: cannot load the dataset ({reason})") from None
    for what, theirs, ours in (("observation", dataset.spec.observation_space, observation_space),
                               ("action", dataset.spec.action_space, action_space)):
        if theirs != ours:
            raise UsageError(f"--pretrain {dataset_id}: its {what} space {theirs} is not the env's {ours}")
    observations: list[Any] = []
    actions: list[np.ndarray] = []
    try:
        for episode in dataset.iterate_episodes():
            obs = episode.observations
            observations.append({k: v[:-1] for k, v in obs.items()} if isinstance(obs, dict) else obs[:-1])
            actions.append(np.asarray(episode.actions))
    except Exception as exc:  # noqa: BLE001 - a damaged file fails while episodes are read
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UsageError(f"--pretrain {dataset_id}: cannot read its episodes ({reason})") from None
    if not actions or sum(len(a) for a in actions) == 0:
        raise UsageError(f"--pretrain {dataset_id}: the dataset holds no steps")
    if isinstance(observations[0], dict):
        stacked: Any = {k: np.concatenate([o[k] for o in observations]) for k in observations[0]}
    else:
        stacked = np.concatenate(observations)
    return Transitions(stacked, np.concatenate(actions))
