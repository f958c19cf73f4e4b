"""``python -m sbagents.record_video``: an mp4 of a trained agent (RL Zoo's ``record_video``), headless.

The env is built exactly as in training (the run's ``config.yml`` through
:func:`sbagents.env_factory.make_vec`, frozen ``VecNormalize`` statistics when the run has them) with
``render_mode="rgb_array"``, and SB3's :class:`~stable_baselines3.common.vec_env.VecVideoRecorder` writes
the frames (it needs ``moviepy``, whose ``imageio-ffmpeg`` dependency ships an ffmpeg binary, so no system
ffmpeg is needed). Multi-agent runs (``treasure_hunt_v0``) are driven by the shared policy for every agent,
as in training.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv, VecVideoRecorder

from sbagents.cli import ArgumentParser, add_run_arguments, run
from sbagents.env_factory import make_vec, normalize_for_eval
from sbagents.env_ids import resolve_env
from sbagents.errors import UsageError
from sbagents.run_dir import env_stem
from sbagents.run_loading import load_run


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
    algo: str,
    env: str,
    log_folder: str | Path = "logs",
    exp_id: int = 0,
    load_best: bool = False,
    n_steps: int = 1000,
    output_dir: str | Path | None = None,
    seed: int = 0,
    deterministic: bool = True,
    fps: float | None = None,
    gym_packages: tuple[str, ...] = (),
) -> Path:
    """Record ``n_steps`` steps of a finished run's agent to an mp4 and return its path.

    :param algo: algorithm of the run (as passed to ``train``).
    :param env: env id of the run (Gymnasium ID, ``module:EnvId`` or a PettingZoo name).
    :param exp_id: run number k (0 = the latest).
    :param load_best: use ``best_model.zip`` instead of the final model.
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
    ref = resolve_env(env, gym_packages)
    loaded = load_run(algo, ref.env_id, log_folder, exp_id, load_best)
    exp = loaded.experiment
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
    prefix = f"{algo}-{env_stem(ref.env_id)}"
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


def build_parser() -> ArgumentParser:
    """The ``record_video`` argument parser."""
    p = ArgumentParser(
        prog="python -m sbagents.record_video", description="Record an mp4 of a trained agent."
    )
    add_run_arguments(p)
    p.add_argument("-n", "--n-steps", type=int, default=1000, help="steps to record (default 1000)")
    p.add_argument("-o", "--output-folder", default=None, help="video folder (default: <run dir>/videos)")
    p.add_argument("--seed", type=int, default=0, help="seed of the recording env")
    p.add_argument("--fps", type=float, default=None, help="video frame rate (default: the env's render_fps)")
    group = p.add_mutually_exclusive_group()
    group.add_argument(
        "--deterministic",
        dest="deterministic",
        action="store_true",
        default=True,
        help="greedy actions (default)",
    )
    group.add_argument("--stochastic", dest="deterministic", action="store_false", help="sample actions")
    return p


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv``, record the video, print its path."""
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    path = record_video(
        args.algo,
        args.env,
        log_folder=args.log_folder,
        exp_id=args.exp_id,
        load_best=args.load_best,
        n_steps=args.n_steps,
        output_dir=args.output_folder,
        seed=args.seed,
        deterministic=args.deterministic,
        fps=args.fps,
        gym_packages=tuple(args.gym_packages),
    )
    print(f"video: {path}")
    return 0


if __name__ == "__main__":
    run("python -m sbagents.record_video", main)
