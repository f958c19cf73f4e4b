"""Recording an mp4 of a trained agent (RL Zoo's ``record_video``), headless: the library side of
``python -m sbagents.record_video``.

The env is built exactly as in training (the run's ``config.yml`` through
:func:`sbagents.env_factory.make_vec`, frozen ``VecNormalize`` statistics when the run has them) with
``render_mode="rgb_array"``, and SB3's :class:`~stable_baselines3.common.vec_env.VecVideoRecorder` writes
the frames (it needs ``moviepy``, whose ``imageio-ffmpeg`` dependency ships an ffmpeg binary, so no system
ffmpeg is needed). PettingZoo runs step one team copy on which every group's model acts (the shared policy for
every agent, or one model per group), as in training; the video shows the env's own frames.

Next to every single-agent video a decisions sidecar (same stem, ``.csv``) lists the recorded steps, one row per
step, so each decision can be shown with the frame it was taken in (see :func:`record_video`).
"""

from __future__ import annotations

import contextlib
import io
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecVideoRecorder

from sbagents.atomic import raise_disk_error, run_subfolder, temporary_name, write_text
from sbagents.callbacks.common import find_vec_normalize
from sbagents.callbacks.episodes import Policy, model_actor
from sbagents.callbacks.safety import step_violation
from sbagents.callbacks.transparency import column_names, csv_cell, csv_quote, flat_observations, observation_layout
from sbagents.core.backends import DEFAULT_BACKEND, backend_of_run
from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.run_dir import LoadedRun, RunRef, env_stem, load_run
from sbagents.env_factory import make_team_vecs, make_vec, normalize_for_eval
from sbagents.errors import UsageError


class _Recorder(VecVideoRecorder):
    """``VecVideoRecorder`` padding odd frame sizes by one edge pixel (H.264 in yuv420p needs even sizes), writing
    without moviepy's console output."""

    def _capture_frame(self) -> None:
        frame = self.env.render()
        if isinstance(frame, np.ndarray) and frame.ndim == 3:
            pad = ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0))
            if any(p[1] for p in pad):
                frame = np.pad(frame, pad, mode="edge")
            self.recorded_frames.append(frame)
        else:
            raise UsageError(
                f"render() returned {type(frame).__name__}, not an RGB image; cannot record a video"
            )

    def _stop_recording(self) -> None:
        """Write the mp4 quietly (SB3's recorder lets moviepy print a progress bar and four lines per file), to a
        temporary name renamed into place: an interrupted recording never leaves a truncated video."""
        if self.recorded_frames:
            from moviepy.video.io.ImageSequenceClip import ImageSequenceClip

            final = Path(self.video_path)
            clip = ImageSequenceClip(self.recorded_frames, fps=self.frames_per_sec)
            tmp = temporary_name(final, ".partial.mp4")  # mkstemp (never a symlink); ffmpeg takes the format from it
            try:
                clip.write_videofile(str(tmp), logger=None)
                os.replace(tmp, final)
            except BaseException as exc:
                tmp.unlink(missing_ok=True)
                raise_disk_error(exc, final)
                raise
            finally:
                del clip
        self.recorded_frames = []
        self.recording = False


class _DecisionLog:
    """The rows of a video's decisions sidecar: one per recorded step of a single-agent VecEnv with one env.

    Observations are flattened as in the transparency log (:class:`~sbagents.callbacks.TransparencyCSVCallback`:
    Dict observations key by key, no columns for images or components of more than 512 numbers) and are the
    ORIGINAL ones under ``VecNormalize`` (``get_original_obs``), as are the rewards (``get_original_reward``).
    """

    def __init__(self, venv: VecEnv) -> None:
        self.venv = venv
        self.norm = find_vec_normalize(venv)
        self.layout = observation_layout(venv.observation_space)
        self.header: list[str] | None = None
        self.rows: list[str] = []
        self.episode = self.step = 0
        self.obs: list[Any] = []

    def observe(self, obs: Any) -> None:
        """Keep the (original) observation just returned by ``reset``/``step``: the next decision is taken in it."""
        raw = self.norm.get_original_obs() if self.norm is not None else obs
        self.obs = flat_observations(raw, self.layout, 1)[0].tolist()

    def record(self, actions: np.ndarray, rewards: np.ndarray, dones: np.ndarray,
               infos: Sequence[dict[str, Any]]) -> None:
        """Add the row of the step just taken (``actions`` chosen in the last observed observation)."""
        action = np.asarray(actions).reshape(len(dones), -1)[0].tolist()
        if self.header is None:
            self.header = ["frame", "episode", "step", *column_names(self.venv, "obs_names", len(self.obs), "obs"),
                           *column_names(self.venv, "action_names", len(action), "action"),
                           "reward", "terminated", "truncated", "violation", "cost"]
        reward = float((self.norm.get_original_reward() if self.norm is not None else np.asarray(rewards))[0])
        done, info = bool(dones[0]), infos[0]
        truncated = done and bool(info.get("TimeLimit.truncated", False))
        violation, cost = step_violation(info)
        cells = [len(self.rows), self.episode, self.step, *self.obs, *action, reward, done and not truncated,
                 truncated, violation or "", cost]
        self.rows.append(",".join(csv_cell(c) for c in cells))
        self.step += 1
        if done:
            self.episode, self.step = self.episode + 1, 0

    def write(self, path: Path) -> None:
        """Write the header and the rows to ``path``."""
        assert self.header is not None, "no step was recorded"
        lines = [",".join(csv_quote(h) for h in self.header), *self.rows]
        write_text(path, "\n".join(lines) + "\n")


def _render_fps(venv: VecEnv) -> float:
    """Frames per second for the video: the env's ``metadata['render_fps']`` (30 when it has none)."""
    try:
        metadata = venv.get_attr("metadata", [0])[0]
    except (AttributeError, IndexError):
        metadata = getattr(venv, "metadata", {})
    fps = (metadata or {}).get("render_fps") or 30
    return float(fps)


def record_video(
    run: RunRef,
    n_steps: int = 1000,
    output_dir: str | Path | None = None,
    seed: int = 0,
    deterministic: bool | None = None,
    fps: float | None = None,
) -> Path:
    """Record ``n_steps`` steps of a finished run's agent to an mp4 and return its path.

    Decisions sidecar: ``<same stem>.csv`` next to the mp4, one row per recorded step, columns ``frame, episode,
    step, <observation columns>, <action columns>, reward, terminated, truncated, violation, cost``:

    - ``frame``: the video frame showing the state in which the row's action was chosen (the recorder captures
      frame 0 at reset and one frame after every step, so row ``t`` is frame ``t``; the last frame, ``n_steps``,
      shows the state after the last recorded step and has no row).
    - ``episode``: 0-based episode of the recording; ``step``: 0-based step within it. The env resets itself
      inside the step that ends an episode, so the frame after a terminal (or truncated) step already shows the
      next episode's reset state (the row of ``step`` 0 of the next episode): the state reached by an episode's
      last action appears in no frame.
    - observation columns: the env's ``obs_names`` (else ``obs_0..``), flattened and unnormalized as in the
      transparency log (Dict observations key by key, none for images); action columns: ``action_names`` (else
      ``action_0..``); ``reward``: the unnormalized reward of the step; ``violation``/``cost``: from the step's
      ``info`` (:func:`sbagents.callbacks.step_violation`; empty and 0 without a violation).

    PettingZoo (multi-agent) runs get no sidecar (their team steps have one row per agent, not per frame).

    :param run: the run (algo, env, log folder, exp id, best or final model).
    :param n_steps: vec-env steps to record (episodes that end are reset and recording goes on);
        the video has ``n_steps + 1`` frames of shape ``(H, W, 3)`` (the env's ``render()`` size).
    :param output_dir: where the mp4 goes (default: ``<run dir>/videos``).
    :param seed: seed of the recording env.
    :param deterministic: greedy actions (``False``: sample from the policy; None: the run's ``deterministic_eval``).
    :param fps: video frame rate (default: the env's ``metadata["render_fps"]``).
    :return: the path of the mp4 file, named ``<algo>-<EnvId>-step-0-to-step-<n_steps>.mp4``.
    """
    if n_steps < 1:
        raise UsageError(f"-n/--n-steps must be >= 1, got {n_steps}")
    if fps is not None and not fps > 0:
        raise UsageError(f"--fps must be > 0, got {fps}")
    backend = backend_of_run(run.run_dir())
    if backend.name != DEFAULT_BACKEND:  # e.g. an RLlib run: its backend plays its modules (record_policies)
        return backend.record_video(run, n_steps, output_dir, seed, deterministic, fps)
    loaded = load_run(run)
    ref = loaded.env
    venvs = _render_vecs(loaded, seed)
    if deterministic is None:
        deterministic = loaded.experiment.deterministic_eval
    stats = {g: loaded.stats_paths.get(g, loaded.stats_path) for g in venvs}
    first = next(iter(venvs))
    if venvs[first].render_mode == "rgb_array":  # (else refused by record_policies)
        venvs = {g: normalize_for_eval(v, loaded.experiment, stats[g], loaded.trust) for g, v in venvs.items()}
    policies = {g: model_actor(loaded.models[g], deterministic) for g in venvs}
    return record_policies(venvs, policies, ref, loaded.run_dir, str(run.algo), n_steps, output_dir, fps)


def record_policies(venvs: dict[str, VecEnv], policies: dict[str, Policy], ref: EnvRef, run_dir: Path, algo: str,
                    n_steps: int, output_dir: str | Path | None = None, fps: float | None = None) -> Path:
    """Record ``n_steps`` steps of ``policies`` acting in ``venvs`` (one env copy rendering ``rgb_array`` frames;
    group -> VecEnv of one team, the first one recorded) to ``<output_dir or run_dir/videos>/<algo>-<EnvId>-step-0-
    to-step-<n_steps>.mp4`` (and the decisions sidecar of a one-agent env); ``venvs`` are closed. What every backend's
    recording shares (:func:`record_video` for SB3 runs)."""
    first = next(iter(venvs))
    if venvs[first].render_mode != "rgb_array":
        for venv in venvs.values():
            venv.close()
        raise UsageError(f"{ref.env_id} does not render rgb_array frames (render_mode {venvs[first].render_mode!r})")
    frame_rate = fps if fps is not None else _render_fps(venvs[first])
    try:
        out = Path(output_dir) if output_dir is not None else run_subfolder(run_dir, "videos")
        out.mkdir(parents=True, exist_ok=True)
    except (OSError, UsageError):
        for venv in venvs.values():
            venv.close()
        raise
    prefix = f"{algo}-{env_stem(ref.env_id)}"
    recorder = _Recorder(
        venvs[first], str(out), record_video_trigger=lambda step: step == 0, video_length=n_steps, name_prefix=prefix
    )
    recorder.frames_per_sec = frame_rate  # type: ignore[assignment]  # SB3 annotates it too narrowly
    log = _decision_log(ref.kind, recorder)
    try:
        _play(recorder, venvs, policies, n_steps, log)
    finally:
        recorder.close()
        for group, venv in venvs.items():
            if group != first:
                venv.close()
    path = out / f"{prefix}-step-0-to-step-{n_steps}.mp4"
    if not path.exists():
        raise UsageError(f"no video was written to {path}")
    if log is not None:
        log.write(sidecar_path(path))
    else:  # a sidecar left by an earlier recording to this path would describe a video that is gone
        sidecar_path(path).unlink(missing_ok=True)
    return path


def sidecar_path(video: str | Path) -> Path:
    """The decisions sidecar of a video written by :func:`record_video`: the same path with ``.csv``."""
    return Path(video).with_suffix(".csv")


def _render_vecs(loaded: LoadedRun, seed: int) -> dict[str, VecEnv]:
    """One env copy rendering ``rgb_array`` frames: group -> VecEnv for PettingZoo runs (one team), else one VecEnv."""
    exp, ref = loaded.experiment, loaded.env
    try:
        return _kind_render_vecs(ref.kind, exp, ref, seed, {"render_mode": "rgb_array"})
    except UsageError:  # MissingDependencyError included
        raise
    except (TypeError, ValueError, AssertionError) as exc:
        raise UsageError(f"{ref.env_id} cannot be created with render_mode='rgb_array': {exc}") from None


@kind_operation()
def _kind_render_vecs(kind: EnvKind, exp: Experiment, ref: EnvRef, seed: int,
                      kwargs: dict[str, Any]) -> dict[str, VecEnv]:
    """A Gymnasium env: one VecEnv."""
    return {"shared": make_vec(exp, ref, 1, seed, env_kwargs=kwargs)}


@_kind_render_vecs.register
def _team_kind_render_vecs(kind: TeamKind, exp: Experiment, ref: EnvRef, seed: int, kwargs: dict[str,
                           Any]) -> dict[str, VecEnv]:
    """A team: one team, group -> VecEnv."""
    return make_team_vecs(exp, ref, 1, seed, vec_env="dummy", env_kwargs=kwargs)


@_kind_render_vecs.register
def _game_kind_render_vecs(kind: GameKind, exp: Experiment, ref: EnvRef, seed: int, kwargs: dict[str,
                           Any]) -> dict[str, VecEnv]:
    """A turn-based game: not recorded."""
    raise UsageError(f"record_video does not record turn-based games yet; play {ref.env_id} against the agent with "
                     "python -m sbagents.play, or measure it with sbagents.evaluate --opponent")


@kind_operation(GameKind)
def _decision_log(kind: EnvKind, recorder: VecEnv) -> _DecisionLog | None:
    """The decisions sidecar of a one-agent video (teams have none)."""
    return _DecisionLog(recorder)


@_decision_log.register
def _team_decision_log(kind: TeamKind, recorder: VecEnv) -> _DecisionLog | None:
    return None


def _play(recorder: VecVideoRecorder, venvs: dict[str, VecEnv], policies: dict[str, Policy], n_steps: int,
          log: _DecisionLog | None = None) -> None:
    """Step ``n_steps`` times: the other groups act first, then the recorded (first) group's step moves the team;
    ``log`` gets every step of a single-agent run. Each group's policy carries its state (a recurrent policy's
    memory), reset in the slots whose episode ended."""
    first, *others = list(venvs)
    obs: dict[str, Any] = {first: recorder.reset()}
    obs.update({g: venvs[g].reset() for g in others})
    states: dict[str, Any] = dict.fromkeys(venvs)
    starts = {g: np.ones(venvs[g].num_envs, dtype=bool) for g in venvs}
    if log is not None:
        log.observe(obs[first])
    for _ in range(n_steps):
        for g in others:
            actions, states[g] = policies[g](obs[g], states[g], starts[g])
            venvs[g].step_async(actions)
        actions, states[first] = policies[first](obs[first], states[first], starts[first])
        with contextlib.redirect_stdout(io.StringIO()):  # SB3 prints "Saving video to ..." at the last step
            obs[first], rewards, dones, infos = recorder.step(actions)
        starts[first] = np.asarray(dones, dtype=bool)
        if log is not None:
            log.record(actions, rewards, dones, infos)
            log.observe(obs[first])
        for g in others:
            obs[g], _, other_dones, _ = venvs[g].step_wait()
            starts[g] = np.asarray(other_dones, dtype=bool)
