"""Recording an mp4 of a trained agent (RL Zoo's ``record_video``), headless: the library side of
``python -m sbagents.record_video``.

The env is built exactly as in training (the run's ``config.yml`` through
:func:`sbagents.pipeline.env_factory.make_vec`, frozen ``VecNormalize`` statistics when the run has them) with
``render_mode="rgb_array"``, and SB3's :class:`~stable_baselines3.common.vec_env.VecVideoRecorder` writes
the frames (it needs ``moviepy``, whose ``imageio-ffmpeg`` dependency ships an ffmpeg binary, so no system
ffmpeg is needed). Multi-agent runs (``treasure_hunt_v0``) are driven by the shared policy for every agent,
as in training.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecVideoRecorder

from sbagents.errors import UsageError
from sbagents.pipeline.env_factory import make_vec, normalize_for_eval
from sbagents.pipeline.run_dir import RunRef, env_stem, load_run


class _Recorder(VecVideoRecorder):
    """``VecVideoRecorder`` padding odd frame sizes by one edge pixel (H.264 in yuv420p needs even sizes)."""

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
    deterministic: bool = True,
    fps: float | None = None,
) -> Path:
    """Record ``n_steps`` steps of a finished run's agent to an mp4 and return its path.

    :param run: the run (algo, env, log folder, exp id, best or final model).
    :param n_steps: vec-env steps to record (episodes that end are reset and recording goes on);
        the video has ``n_steps + 1`` frames of shape ``(H, W, 3)`` (the env's ``render()`` size).
    :param output_dir: where the mp4 goes (default: ``<run dir>/videos``).
    :param seed: seed of the recording env.
    :param deterministic: greedy actions (``False``: sample from the policy).
    :param fps: video frame rate (default: the env's ``metadata["render_fps"]``).
    :return: the path of the mp4 file, named ``<algo>-<EnvId>-step-0-to-step-<n_steps>.mp4``.
    """
    if n_steps < 1:
        raise UsageError(f"-n/--n-steps must be >= 1, got {n_steps}")
    if fps is not None and not fps > 0:
        raise UsageError(f"--fps must be > 0, got {fps}")
    loaded = load_run(run)
    exp, ref = loaded.experiment, loaded.env
    try:
        venv = make_vec(exp, ref, 1, seed, env_kwargs={"render_mode": "rgb_array"})
    except (TypeError, ValueError, AssertionError) as exc:
        raise UsageError(f"{ref.env_id} cannot be created with render_mode='rgb_array': {exc}") from None
    if venv.render_mode != "rgb_array":
        venv.close()
        raise UsageError(f"{ref.env_id} does not render rgb_array frames (render_mode {venv.render_mode!r})")
    frame_rate = fps if fps is not None else _render_fps(venv)
    venv = normalize_for_eval(venv, exp, loaded.stats_path)
    out = Path(output_dir) if output_dir is not None else loaded.run_dir / "videos"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError:
        venv.close()
        raise
    prefix = f"{run.algo}-{env_stem(ref.env_id)}"
    recorder = _Recorder(
        venv, str(out), record_video_trigger=lambda step: step == 0, video_length=n_steps, name_prefix=prefix
    )
    recorder.frames_per_sec = frame_rate  # type: ignore[assignment]  # SB3 annotates it too narrowly
    try:
        obs = recorder.reset()
        for _ in range(n_steps):
            actions, _ = loaded.model.predict(obs, deterministic=deterministic)  # type: ignore[arg-type]
            obs, _, _, _ = recorder.step(actions)
    finally:
        recorder.close()
    path = out / f"{prefix}-step-0-to-step-{n_steps}.mp4"
    if not path.exists():
        raise UsageError(f"no video was written to {path}")
    return path
