"""Exporting a trained policy for the edge: ``policy.onnx`` (+ ``policy.int8.onnx``) and the ``policy.json``
sidecar, with the parity and latency report (:func:`export_run`; :func:`export` for a finished run dir, the library
side of ``python -m sbagents.export``).

The files are made in a staging folder inside the output folder and moved in at the end, so a failure leaves no
partial export.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.atomic import raise_disk_error, run_subfolder, write_json
from sbagents.callbacks.common import env_attr
from sbagents.core.backends import DEFAULT_BACKEND, backend_of_run
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.run_dir import LoadedRun, RunRef, load_run
from sbagents.deploy.onnx_export import (
    ACTION_OUTPUT,
    OBS_INPUT,
    START_INPUT,
    STATE_INPUTS,
    STATE_OUTPUTS,
    check_exportable,
    export_onnx,
    quantize_int8,
    state_shape,
    taken_observation_space,
)
from sbagents.deploy.parity import (
    INT8_TOLERANCE,
    Observations,
    Recording,
    action_deviation,
    check_parity,
    latency_table,
    record_episodes,
    state_parity,
)
from sbagents.env_factory import make_eval_vec
from sbagents.errors import UsageError
from sbagents.multiagent.centralized import OBS_KEY


@dataclass
class ExportReport:
    """What :func:`export_run` wrote and measured.

    ``parity_*``: max abs action difference vs SB3; ``int8_deviation``: :func:`action_deviation` of the int8 file,
    ``int8_acceptable``: whether it is within :data:`INT8_TOLERANCE` for the action space (``action_kind``:
    ``box`` or ``discrete``). ``preprocessing``: the env wrappers and frame stack the policy works inside (it takes
    their observations, e.g. an Atari run's 84x84 grayscale 4-frame stack), None when it takes the env's own.
    ``parity_state``: a recurrent policy's max abs hidden/cell state difference vs SB3 over the recorded episodes
    (both carrying their own state; None for a stateless policy).
    """

    onnx_path: Path
    sidecar_path: Path
    parity_fp32: float
    onnx_bytes: int
    int8_path: Path | None = None
    parity_int8: float | None = None
    int8_bytes: int | None = None
    int8_deviation: float | None = None
    int8_acceptable: bool | None = None
    action_kind: str = "box"
    n_parity_observations: int = 0
    latency: dict[str, dict[str, float]] = field(default_factory=dict)
    preprocessing: dict[str, Any] | None = None
    parity_state: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (paths as str)."""
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(self).items()}


@dataclass
class ExportChecks:
    """How much :func:`export_run` measures: parity observations (recorded with the greedy policy from ``seed``)
    and latency calls per file."""

    n_observations: int = 1000
    seed: int = 0
    latency_n: int = 1000


class _ActorNormalize:
    """The actor's part of a Dict-observation ``VecNormalize``: ``normalize_obs`` of the ``obs`` entry alone."""

    def __init__(self, norm: VecNormalize) -> None:
        self.norm = norm
        self.obs_rms = norm.obs_rms[OBS_KEY]  # type: ignore[index]
        self.norm_obs, self.clip_obs, self.epsilon = norm.norm_obs, norm.clip_obs, norm.epsilon

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        return self.norm._normalize_obs(obs, self.obs_rms).astype(np.float32)  # type: ignore[arg-type]


def _space_meta(space: spaces.Space[Any]) -> dict[str, Any]:
    if isinstance(space, spaces.Discrete):
        return {"type": "discrete", "n": int(space.n), "start": int(space.start)}
    assert isinstance(space, spaces.Box), f"unsupported space {space}"
    low, high = (np.asarray(b, dtype=np.float64).ravel().tolist() for b in (space.low, space.high))
    return {"type": "box", "shape": list(space.shape), "low": low, "high": high}


def _names_of(env: gym.Env[Any, Any] | VecEnv | None, attr: str, size: int, prefix: str) -> list[str]:
    """The env's ``obs_names``/``action_names`` when it has ``size`` of them, else ``<prefix>_<i>``."""
    value = None
    if env is not None:
        value = env_attr(env, attr) if isinstance(env, VecEnv) else getattr(env.unwrapped, attr, None)
    names = [str(v) for v in value] if value is not None else []
    return names if len(names) == size else [f"{prefix}_{i}" for i in range(size)]


def export_run(
    model: BaseAlgorithm,
    out_dir: str | Path,
    env_id: str,
    env: gym.Env[Any, Any] | VecEnv | None = None,
    vec_normalize: VecNormalize | None = None,
    int8: bool = False,
    checks: ExportChecks | None = None,
    observations: Observations | None = None,
    preprocessing: dict[str, Any] | None = None,
    algo: str | None = None,
) -> ExportReport:
    """Export ``model``, quantize it (``int8``), check parity and latency, and write the ``policy.json`` sidecar.

    Writes ``policy.onnx`` (+ ``policy.int8.onnx``) and ``policy.json`` (env id, algo, obs/action names from the
    env's ``obs_names``/``action_names``, spaces with bounds, ONNX input/output names, parity and latency) into
    ``out_dir``.

    :param env: where parity observations are recorded (default ``gym.make(env_id)``); a ``VecNormalize`` env also
        supplies the normalization statistics.
    :param vec_normalize: the statistics the model was trained with, when ``env`` does not carry them.
    :param observations: raw parity observations ``(N, *obs_shape)`` or a :class:`~sbagents.deploy.parity.Recording`
        (required for a recurrent model) recorded elsewhere (then ``env`` only names observations and actions, and
        may be None); e.g. a team's, where one group's env cannot step alone.
    :param preprocessing: the env wrappers and frame stack ``env`` applies, which the exported policy does not
        (recorded in the sidecar and the report: a caller applies them before calling the policy).
    :param algo: the sidecar's ``algo`` (default: the model's class name, lower case).
    :raises TypeError: the model cannot be exported (:func:`check_exportable`).
    :raises ValueError: ``checks.n_observations < 1``.
    """
    checks = checks or ExportChecks()
    check_exportable(model)
    if checks.n_observations < 1:
        raise ValueError(f"n_observations must be >= 1, got {checks.n_observations}")
    out = Path(out_dir)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=out))
    own_env = env is None and observations is None
    rec_env = gym.make(env_id) if own_env else env
    if vec_normalize is None and isinstance(rec_env, VecNormalize):
        vec_normalize = rec_env
    try:
        report = _export_into(model, staging, out, env_id, rec_env, vec_normalize, int8, checks, observations,
                              preprocessing=preprocessing or None, algo=algo)
        for path in staging.iterdir():
            os.replace(path, out / path.name)
    except BaseException as exc:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise_disk_error(exc, out)
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if own_env and rec_env is not None:
            rec_env.close()
    return report


def _export_into(
    model: BaseAlgorithm, staging: Path, out: Path, env_id: str, env: gym.Env[Any, Any] | VecEnv | None,
    vec_normalize: VecNormalize | None, int8: bool, checks: ExportChecks, recorded: Observations | None, *,
    preprocessing: dict[str, Any] | None = None, algo: str | None = None,
) -> ExportReport:
    """The work of :func:`export_run`: files are written to ``staging``, the report names them in ``out``."""
    norm = vec_normalize if vec_normalize is not None and vec_normalize.norm_obs else None
    obs_rms: Any = norm.obs_rms if norm is not None else None
    if isinstance(obs_rms, dict):  # a centralized critic's Dict observations: the actor's part is exported
        obs_rms = obs_rms.get(OBS_KEY)
        norm = _ActorNormalize(norm) if norm is not None and obs_rms is not None else None  # type: ignore[assignment]
    if obs_rms is not None and not isinstance(obs_rms, RunningMeanStd):
        raise TypeError("dict observations are not supported")
    clip_obs = vec_normalize.clip_obs if vec_normalize is not None else 10.0
    epsilon = vec_normalize.epsilon if vec_normalize is not None else 1e-8
    env_space = env.observation_space if env is not None else None
    obs_space = taken_observation_space(model, env_space)  # channels-last images: the env's layout
    onnx_path = export_onnx(model, staging / "policy.onnx", obs_rms, clip_obs, epsilon, obs_space)
    observations: Observations
    if recorded is not None:
        observations = recorded
    else:
        assert env is not None
        plain_norm = None if isinstance(env, VecNormalize) else norm
        observations = record_episodes(env, model, checks.n_observations, checks.seed,
                                       vec_normalize=plain_norm)  # type: ignore[arg-type]
    first = (observations.flat() if isinstance(observations, Recording) else observations)[0]
    recurrent = state_shape(model)

    paths: dict[str, Path] = {"onnx": onnx_path}
    report = ExportReport(
        onnx_path=out / onnx_path.name, sidecar_path=out / "policy.json",
        parity_fp32=check_parity(model, onnx_path, observations, norm),
        onnx_bytes=onnx_path.stat().st_size, n_parity_observations=len(observations),
        action_kind="box" if isinstance(model.action_space, spaces.Box) else "discrete", preprocessing=preprocessing,
    )
    if recurrent is not None:
        assert isinstance(observations, Recording)  # check_parity refused anything else
        report.parity_state = state_parity(model, onnx_path, observations, norm)
    if int8:
        int8_path = quantize_int8(onnx_path, staging / "policy.int8.onnx")
        paths["onnx_int8"] = int8_path
        report.int8_path = out / int8_path.name
        report.int8_bytes = int8_path.stat().st_size
        report.parity_int8 = check_parity(model, int8_path, observations, norm)
        report.int8_deviation = action_deviation(model, int8_path, observations, norm)
        report.int8_acceptable = report.int8_deviation <= INT8_TOLERANCE[report.action_kind]
    report.latency = latency_table(model, paths, first, checks.latency_n, norm)

    n_obs = int(np.prod(obs_space.shape)) if obs_space.shape else 1
    n_act = int(np.prod(model.action_space.shape)) if model.action_space.shape else 1
    sidecar = {
        "env_id": env_id,
        "algo": algo or type(model).__name__.lower(),
        "obs_names": _names_of(env, "obs_names", n_obs, "obs"),
        "action_names": _names_of(env, "action_names", n_act, "action"),
        "observation_space": _space_meta(obs_space),
        "action_space": _space_meta(model.action_space),
        "input_name": OBS_INPUT,
        "output_name": ACTION_OUTPUT,
        "obs_normalization_baked_in": obs_rms is not None,
        **({"recurrent": {"state_inputs": list(STATE_INPUTS), "state_outputs": list(STATE_OUTPUTS),
                          "start_input": START_INPUT, "n_layers": recurrent[0], "hidden": recurrent[1]}}
           if recurrent is not None else {}),
        **({"preprocessing": preprocessing} if preprocessing else {}),
        "files": {name: p.name for name, p in paths.items()},
        "report": report.to_dict(),
    }
    write_json(staging / "policy.json", sidecar)
    return report


def default_export_dir(run: RunRef) -> str:
    """Where in the run dir a model is exported without ``--out``: ``export`` (the final model), ``export_best``
    (``--load-best``) or ``export_checkpoint_<steps>`` (``--load-checkpoint``), so exports never overwrite each
    other."""
    if run.load_best:
        return "export_best"
    return "export" if run.checkpoint is None else f"export_checkpoint_{run.checkpoint}"


def export(run: RunRef, int8: bool = False, out: str | Path | None = None, n_observations: int = 1000) -> ExportReport:
    """Export a finished one-model run to ONNX in ``out`` (default: ``<run dir>/``:func:`default_export_dir`).

    Parity is checked on ``n_observations`` observations recorded with the greedy policy on an env built exactly
    as in training (same env kwargs and wrappers, frozen VecNormalize statistics).

    :raises UsageError: a run with one model per group of agents (use :func:`export_groups`).
    """
    reports = export_groups(run, int8, out, n_observations)
    if len(reports) > 1:
        raise UsageError(f"this run has one model per group ({', '.join(reports)}): use export_groups")
    return next(iter(reports.values()))


def export_groups(
    run: RunRef, int8: bool = False, out: str | Path | None = None, n_observations: int = 1000
) -> dict[str, ExportReport]:
    """Export every model of a finished run: group -> its report (``{"shared": report}`` for a one-model run,
    whose files go to ``out`` itself; with several groups each goes to ``out/<group>/``). Nothing is written
    unless every model exports.

    PettingZoo runs record their parity observations on a team in which every group's model acts; a centralized
    critic's policy is exported as its actor (the agent's own observation in, the action out).
    """
    if n_observations < 1:
        raise UsageError(f"--n-observations must be >= 1, got {n_observations}")
    backend = backend_of_run(run.run_dir())
    if backend.name != DEFAULT_BACKEND:  # e.g. an RLlib run: its backend exports its modules (export_run)
        return backend.export(run, int8, out, n_observations)
    loaded = load_run(run)
    target = Path(out) if out is not None else run_subfolder(loaded.run_dir, default_export_dir(run), create=False)
    return _export_kind(loaded.env.kind, loaded, target, int8, ExportChecks(n_observations=n_observations))


def _check_exportable_run(loaded: LoadedRun, wrappers: bool = False) -> None:
    """Refuse (one line) a run whose wrappers or models export cannot reproduce (``wrappers``: env wrappers and
    frame stacking are taken: the policy is exported as it works inside them)."""
    exp, ref = loaded.experiment, loaded.env
    if not wrappers and (exp.frame_stack or exp.env_wrapper):
        raise UsageError(f"{ref.env_id} runs use env wrappers or frame stacking, which export cannot bake in")
    for model in loaded.models.values():
        try:
            check_exportable(model)
        except TypeError as exc:
            raise UsageError(f"cannot export {exp.algo}: {exc}") from None


@kind_operation()
def _export_kind(kind: EnvKind, loaded: LoadedRun, target: Path, int8: bool,
                 checks: ExportChecks) -> dict[str, ExportReport]:
    """A Gymnasium env's run: its one model, with parity observations from its evaluation env (built as in training:
    a run with env wrappers or a frame stack, e.g. Atari's, is exported as the policy works inside them, and the
    sidecar names them: :func:`preprocessing_of`)."""
    _check_exportable_run(loaded, wrappers=True)
    venv = make_eval_vec(loaded.experiment, loaded.env, 1, seed=0, stats_path=loaded.stats_path, trust=loaded.trust)
    try:
        return {"shared": export_run(loaded.model, target, loaded.env.env_id, env=venv, int8=int8, checks=checks,
                                     preprocessing=preprocessing_of(loaded))}
    finally:
        venv.close()


def preprocessing_of(loaded: LoadedRun) -> dict[str, Any] | None:
    """The env wrappers (with their kwargs) and the frame stack of a run, which its exported policy sits behind;
    None when it has neither."""
    exp = loaded.experiment
    if not (exp.env_wrapper or exp.frame_stack):
        return None
    wrappers = [{"class": f"{cls.__module__}.{cls.__qualname__}",
                 "kwargs": {str(k): v if isinstance(v, bool | int | float | str) or v is None else str(v)
                            for k, v in kwargs.items()}}
                for cls, kwargs in exp.env_wrapper]
    return {"env_wrapper": wrappers, "frame_stack": int(exp.frame_stack or 0)}


@_export_kind.register
def _team_export_kind(kind: TeamKind, loaded: LoadedRun, target: Path, int8: bool,
                      checks: ExportChecks) -> dict[str, ExportReport]:
    """A team's run: every group's model (parity observations from a team in which each acts)."""
    from sbagents.deploy.team_export import export_team

    _check_exportable_run(loaded)
    return export_team(loaded, target, int8, checks)


@_export_kind.register
def _game_export_kind(kind: GameKind, loaded: LoadedRun, target: Path, int8: bool,
                      checks: ExportChecks) -> dict[str, ExportReport]:
    """A turn-based game's run: refused."""
    raise UsageError(f"cannot export {loaded.experiment.algo} on {loaded.env.env_id} yet: its policy needs the action "
                     "mask as an input, which the ONNX policy and serve do not take (an exported argmax could pick "
                     "illegal moves)")


def format_report(report: ExportReport) -> str:
    """The human-readable export report: files, parity, whether int8 is acceptable, latency."""
    lines = [f"wrote {report.onnx_path} ({report.onnx_bytes:,} bytes) and {report.sidecar_path}",
             f"parity fp32: max abs action difference {report.parity_fp32:.2e} over "
             f"{report.n_parity_observations} observations"
             + (f" (whole episodes, state carried; max abs state difference {report.parity_state:.2e})"
                if report.parity_state is not None else "")]
    if report.int8_path is not None and report.int8_deviation is not None:
        limit = INT8_TOLERANCE[report.action_kind]
        if report.action_kind == "box":
            size = f"{100 * report.int8_deviation:.1f}% of the action range (limit {100 * limit:g}%)"
        else:
            size = f"a different action on {100 * report.int8_deviation:.1f}% of observations (limit {100 * limit:g}%)"
        verdict = "acceptable" if report.int8_acceptable else "NOT acceptable: keep the fp32 policy"
        lines.append(f"int8: {report.int8_path} ({report.int8_bytes:,} bytes), max abs action difference "
                     f"{report.parity_int8:.2e}, {size}: {verdict}")
    if report.preprocessing:
        names = [str(w["class"]).rsplit(".", 1)[-1] for w in report.preprocessing["env_wrapper"]]
        stack = report.preprocessing["frame_stack"]
        inside = " + ".join([*names, *([f"{stack}-frame stack"] if stack else [])])
        lines.append(f"the policy works inside {inside}: it takes their observations and gives the actions they "
                     "take, so apply them before calling it (policy.json: preprocessing)")
    lines.append("latency (single observation): " + ", ".join(
        f"{name} p50 {row['p50_us']:.1f} us / p99 {row['p99_us']:.1f} us" for name, row in report.latency.items()))
    return "\n".join(lines)
