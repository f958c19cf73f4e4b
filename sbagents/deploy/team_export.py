"""Exporting the models of a PettingZoo run (:func:`export_team`): one ONNX policy per group, checked on the
observations each group meets while every group's model acts on one team.

A group's VecEnv cannot step alone (the team steps when every group has acted), so the parity observations are
recorded here for all groups at once (:func:`record_team_observations`) and handed to
:func:`~sbagents.deploy.exporting.export_run`.
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.callbacks.common import find_vec_normalize
from sbagents.callbacks.episodes import model_actor
from sbagents.core.run_dir import LoadedRun
from sbagents.deploy.exporting import ExportChecks, ExportReport, export_run
from sbagents.deploy.onnx_export import state_shape
from sbagents.deploy.parity import Recording, recording_goes_on
from sbagents.env_factory import make_team_vecs, normalize_for_eval
from sbagents.multiagent.centralized import OBS_KEY
from sbagents.multiagent.parameter_sharing import SHARED_GROUP


def _actor_part(obs: Any) -> np.ndarray:
    """The actor's observations of a slot batch: the ``obs`` entry of a centralized critic's Dict observations."""
    return np.asarray(obs[OBS_KEY] if isinstance(obs, dict) else obs)


def record_team_observations(
    venvs: Mapping[str, VecEnv], models: Mapping[str, BaseAlgorithm], n: int, seed: int = 0
) -> dict[str, Recording]:
    """Raw (unnormalized) actor observations per group, in time order (a :class:`~sbagents.deploy.parity.Recording`
    of at least ``n`` observations: ``(T, n_slots, *obs_shape)`` and each slot's episode starts), met while every
    group's model acts greedily through the one policy protocol (a recurrent model's state kept per agent slot and
    reset where that agent's episode ends; then whole episodes are recorded, as in
    :func:`~sbagents.deploy.parity.record_episodes`) on the team that ``venvs`` (group -> VecEnv, one team) step
    together.
    ``VecNormalize`` statistics stay frozen."""
    order = list(venvs)
    norms = {g: find_vec_normalize(v) for g, v in venvs.items()}
    frozen = {g: vn.training for g, vn in norms.items() if vn is not None}
    for g in frozen:
        norms[g].training = False  # type: ignore[union-attr]
    policies = {g: model_actor(models[g], deterministic=True) for g in order}
    recorded: dict[str, list[np.ndarray]] = {g: [] for g in order}
    starts_seen: dict[str, list[np.ndarray]] = {g: [] for g in order}
    states: dict[str, Any] = dict.fromkeys(order)
    try:
        venvs[order[0]].seed(seed)
        obs = {g: venvs[g].reset() for g in order}
        starts = {g: np.ones(venvs[g].num_envs, dtype=bool) for g in order}
        whole = any(state_shape(m) is not None for m in models.values())
        ended = {g: np.zeros(venvs[g].num_envs, dtype=bool) for g in order}
        while any(recording_goes_on(len(r) * venvs[g].num_envs, n, whole, ended[g], len(r))
                  for g, r in recorded.items()):
            for g in order:
                norm = norms[g]
                recorded[g].append(_actor_part(norm.get_original_obs() if norm is not None else obs[g]))
                starts_seen[g].append(starts[g])
                actions, states[g] = policies[g](obs[g], states[g], starts[g])
                venvs[g].step_async(actions)
            for g in order:
                obs[g], _, dones, _ = venvs[g].step_wait()
                starts[g] = np.asarray(dones, dtype=bool)
                if len(recorded[g]) * venvs[g].num_envs >= n:
                    ended[g] |= starts[g]
    finally:
        for g, was in frozen.items():
            norms[g].training = was  # type: ignore[union-attr]
    return {g: Recording(np.stack(r), np.stack(starts_seen[g])) for g, r in recorded.items()}


def export_team(loaded: LoadedRun, out: Path, int8: bool, checks: ExportChecks) -> dict[str, ExportReport]:
    """Export every group's model of a PettingZoo run: group -> report. One group (``shared``) goes to ``out``,
    several to ``out/<group>/`` (a failure removes the group folders it made)."""
    exp, ref = loaded.experiment, loaded.env
    venvs = {g: normalize_for_eval(v, exp, loaded.stats_paths.get(g), loaded.trust) for g, v in
             make_team_vecs(exp, ref, 1, seed=checks.seed, vec_env="dummy").items()}
    try:
        observations = record_team_observations(venvs, loaded.models, checks.n_observations, checks.seed)
        if list(venvs) == [SHARED_GROUP]:
            return {SHARED_GROUP: _export_group(loaded, SHARED_GROUP, venvs, out, int8, checks, observations)}
        return _export_groups(loaded, venvs, out, int8, checks, observations)
    finally:
        next(iter(venvs.values())).close()


def _export_group(loaded: LoadedRun, group: str, venvs: Mapping[str, VecEnv], out: Path, int8: bool,
                  checks: ExportChecks, observations: Mapping[str, Recording]) -> ExportReport:
    venv = venvs[group]
    norm = venv if isinstance(venv, VecNormalize) else None
    return export_run(loaded.models[group], out, loaded.env.env_id, env=venv, vec_normalize=norm, int8=int8,
                      checks=checks, observations=observations[group])


def _export_groups(loaded: LoadedRun, venvs: Mapping[str, VecEnv], out: Path, int8: bool, checks: ExportChecks,
                   observations: Mapping[str, Recording]) -> dict[str, ExportReport]:
    """Each group into ``out/<group>/`` (each folder written atomically by ``export_run``); if one group fails, the
    folders made for the others are removed again."""
    made: list[Path] = []
    try:
        reports = {}
        for group in venvs:
            if not (out / group).exists():
                made.append(out / group)
            reports[group] = _export_group(loaded, group, venvs, out / group, int8, checks, observations)
        return reports
    except BaseException:
        for path in made:
            shutil.rmtree(path, ignore_errors=True)
        raise
