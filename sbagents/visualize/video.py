"""Recording an mp4 of a trained agent (RL Zoo's ``record_video``), headless: the library side of
``python -m sbagents.record_video``.

The env is built exactly as in training (the run's ``config.yml`` through
:func:`sbagents.pipeline.env_factory.make_vec`, frozen ``VecNormalize`` statistics when the run has them) with
``render_mode="rgb_array"``, and SB3's :class:`~stable_baselines3.common.vec_env.VecVideoRecorder` writes
the frames (it needs ``moviepy``, whose ``imageio-ffmpeg`` dependency ships an ffmpeg binary, so no system
ffmpeg is needed). PettingZoo runs step one team copy on which every group's model acts (the shared policy for
every agent, or one model per group), as in training; the video shows the env's own frames.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecVideoRecorder

from sbagents.errors import UsageError
from sbagents.pipeline.env_factory import make_team_vecs, make_vec, normalize_for_eval
from sbagents.pipeline.run_dir import LoadedRun, RunRef, env_stem, load_run


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
        """Write the mp4 quietly (SB3's recorder lets moviepy print a progress bar and four lines per file)."""
        if self.recorded_frames:
            from moviepy.video.io.ImageSequenceClip import ImageSequenceClip

            clip = ImageSequenceClip(self.recorded_frames, fps=self.frames_per_sec)
            clip.write_videofile(self.video_path, logger=None)
            del clip
        self.recorded_frames = []
        self.recording = False


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
    loaded = load_run(run)
    if loaded.env.game:
        raise UsageError(f"record_video does not record turn-based games yet; play {loaded.env.env_id} against the "
                         "agent with python -m sbagents.play, or measure it with sbagents.evaluate --opponent")
    if deterministic is None:
        deterministic = loaded.experiment.deterministic_eval
    ref = loaded.env
    venvs = _render_vecs(loaded, seed)
    first = next(iter(venvs))
    if venvs[first].render_mode != "rgb_array":
        venvs[first].close()
        raise UsageError(f"{ref.env_id} does not render rgb_array frames (render_mode {venvs[first].render_mode!r})")
    frame_rate = fps if fps is not None else _render_fps(venvs[first])
    stats = {g: loaded.stats_paths.get(g, loaded.stats_path) for g in venvs}
    venvs = {g: normalize_for_eval(v, loaded.experiment, stats[g]) for g, v in venvs.items()}
    out = Path(output_dir) if output_dir is not None else loaded.run_dir / "videos"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError:
        venvs[first].close()
        raise
    prefix = f"{run.algo}-{env_stem(ref.env_id)}"
    recorder = _Recorder(
        venvs[first], str(out), record_video_trigger=lambda step: step == 0, video_length=n_steps, name_prefix=prefix
    )
    recorder.frames_per_sec = frame_rate  # type: ignore[assignment]  # SB3 annotates it too narrowly
    try:
        _play(recorder, venvs, loaded, n_steps, deterministic)
    finally:
        recorder.close()
    path = out / f"{prefix}-step-0-to-step-{n_steps}.mp4"
    if not path.exists():
        raise UsageError(f"no video was written to {path}")
    return path


def _render_vecs(loaded: LoadedRun, seed: int) -> dict[str, VecEnv]:
    """One env copy rendering ``rgb_array`` frames: group -> VecEnv for PettingZoo runs (one team), else one VecEnv."""
    exp, ref = loaded.experiment, loaded.env
    kwargs = {"render_mode": "rgb_array"}
    try:
        if ref.multi_agent:
            return make_team_vecs(exp, ref, 1, seed, vec_env="dummy", env_kwargs=kwargs)
        return {"shared": make_vec(exp, ref, 1, seed, env_kwargs=kwargs)}
    except (TypeError, ValueError, AssertionError) as exc:
        raise UsageError(f"{ref.env_id} cannot be created with render_mode='rgb_array': {exc}") from None


def _play(recorder: VecVideoRecorder, venvs: dict[str, VecEnv], loaded: LoadedRun, n_steps: int,
          deterministic: bool) -> None:
    """Step ``n_steps`` times: the other groups act first, then the recorded (first) group's step moves the team."""
    first, *others = list(venvs)
    obs: dict[str, Any] = {first: recorder.reset()}
    obs.update({g: venvs[g].reset() for g in others})
    for _ in range(n_steps):
        for g in others:
            venvs[g].step_async(loaded.models[g].predict(obs[g], deterministic=deterministic)[0])
        actions, _ = loaded.models[first].predict(obs[first], deterministic=deterministic)
        with contextlib.redirect_stdout(io.StringIO()):  # SB3 prints "Saving video to ..." at the last step
            obs[first] = recorder.step(actions)[0]
        for g in others:
            obs[g] = venvs[g].step_wait()[0]
