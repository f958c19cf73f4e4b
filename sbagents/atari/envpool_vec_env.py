"""An SB3 ``VecEnv`` over an EnvPool Atari pool: ``AtariWrapper``'s observations and episode ends, stepped in C++.

:class:`EnvPoolAtariVecEnv` stands where the default path has ``DummyVecEnv`` of ``AtariWrapper(Monitor(ALE env))``:
one grey ``screen_size`` x ``screen_size`` frame per step, channel-first ``(1, H, W)`` (the experiment's
``frame_stack`` puts SB3's ``VecFrameStack`` on top, giving the ``(4, 84, 84)`` observations SB3's
``VecTransposeImage`` gives the default path), clipped rewards, an episode end at each lost life, and SB3
``Monitor`` rows with the whole game's score. SB3 semantics are kept where EnvPool's differ: an env that ends an
episode is reset within the same ``step`` (its last observation in ``info["terminal_observation"]``), and a lost life
continues the game at the next reset instead of restarting it.

Differences from ``AtariWrapper`` that EnvPool's C++ preprocessing fixes (tests/test_envpool_atari.py measures them
on fixed action sequences):

- grey levels come from the ALE palette's luminance and the max over the last two frames is taken on grey frames;
  ``AtariWrapper`` max-pools RGB frames and converts with OpenCV. Measured: Breakout's frames identical over 600
  steps, Pong's differing in ~5 pixels per million (where the ball crosses a paddle, by up to ~100 levels);
- reset: in games with FIRE, ``U[0, noop_max - 1]`` no-op frames then one FIRE frame, where AtariWrapper does
  ``U[1, noop_max]`` no-op frames, then FIRE and UP/RIGHT for ``frame_skip`` frames each (other games: ``U[1,
  noop_max]`` no-ops on both); after a lost life EnvPool resets the same way where AtariWrapper steps a no-op and
  then FIRE/UP. No-ops are drawn from EnvPool's own generator, so seeds do not give the ALE env's episodes;
- monitor lengths (``l``) count ``frame_skip`` frames per agent step; the default path's Monitor, below the frame
  skip, also counts the reset's no-op and FIRE frames.

Emulator and ROM are the ALE's: when the ``envpool-assets`` package is missing EnvPool loads ale-py's ROMs (the same
files), see :func:`import_envpool`.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.monitor import Monitor, ResultsWriter
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from sbagents.atari.envpool_support import AtariSettings, atari_settings, check_envpool
from sbagents.core.env_names import EnvRef

#: EnvPool's C++ seeds are ints: base seeds are taken modulo this (env ``i`` gets ``seed + i``).
_SEED_MODULUS = 2**31 - 2**16


#: Files EnvPool 1.2 reads when it is imported, outside its Atari part: empty stand-ins (no such env is made).
_IMPORT_TIME_FILES = {
    "mujoco/myosuite/assets/metadata/myosuite_tasks.json": "[]",
    "mujoco/myosuite/assets/metadata/myosuite_oracle_metadata.json":
        '{"version": "", "commit": "", "numpy2_broken_ids": []}',
}


def _ale_rom_assets() -> Path:
    """A folder laid out as EnvPool's assets whose ROMs (``atari/roms/<game>.bin``) are links to ale-py's, with
    empty stand-ins for what EnvPool's other env families list or read when it is imported."""
    import ale_py

    roms = Path(ale_py.__file__).resolve().parent / "roms"
    digest = hashlib.sha1(str(roms).encode()).hexdigest()[:12]
    root = Path(tempfile.gettempdir()) / f"sbagents-envpool-assets-v1-{os.getuid()}-{digest}"
    if (root / "atari" / "roms").is_dir():
        return root
    staging = Path(tempfile.mkdtemp(prefix=".sbagents-envpool-assets-", dir=tempfile.gettempdir()))
    (staging / "atari" / "roms").mkdir(parents=True)
    (staging / "vizdoom" / "maps").mkdir(parents=True)
    for rom in roms.glob("*.bin"):
        (staging / "atari" / "roms" / rom.name).symlink_to(rom)
    for name, text in _IMPORT_TIME_FILES.items():
        (staging / name).parent.mkdir(parents=True, exist_ok=True)
        (staging / name).write_text(text)
    try:
        staging.rename(root)  # complete or absent: never half-made
    except OSError:  # another process made it first
        shutil.rmtree(staging, ignore_errors=True)
    return root


def import_envpool() -> ModuleType:
    """Import EnvPool. Without its ``envpool-assets`` package (and no ``ENVPOOL_ASSETS_PATH``) it is pointed at
    ale-py's ROMs first (EnvPool lists its ROM folder when imported); that is how a machine given the EnvPool wheel
    alone (``--no-deps``) runs it.

    :raises UsageError: EnvPool is not installed (naming the ``atari`` extra) or cannot be imported.
    """
    from sbagents.atari.envpool_support import ATARI_EXTRA_HINT
    from sbagents.errors import UsageError

    if importlib.util.find_spec("envpool") is None:
        raise UsageError(f"--vec-env envpool needs EnvPool, which is not installed: {ATARI_EXTRA_HINT}")
    if not os.environ.get("ENVPOOL_ASSETS_PATH") and importlib.util.find_spec("envpool_assets") is None:
        os.environ["ENVPOOL_ASSETS_PATH"] = str(_ale_rom_assets())
    try:
        import envpool
    except (OSError, ValueError, KeyError) as exc:  # FileNotFoundError included: an asset EnvPool looks for
        raise UsageError(f"EnvPool cannot be imported ({type(exc).__name__}: {exc}); {ATARI_EXTRA_HINT}") from None
    return envpool


def default_threads(n_envs: int) -> int:
    """EnvPool worker threads for ``n_envs`` envs: one per env, at most one per CPU this process may use (EnvPool
    itself would count the host's CPUs, more than a container or ``taskset`` allows)."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(min(n_envs, cpus), 1)


def envpool_task_id(game: str) -> str:
    """EnvPool's id of an ALE game (``space_invaders`` -> ``SpaceInvaders-v5``)."""
    return "".join(part.capitalize() for part in game.split("_")) + "-v5"


class EnvPoolAtariVecEnv(VecEnv):
    """``n_envs`` copies of an ALE game in one EnvPool, with SB3 ``VecEnv`` semantics.

    Observations: ``uint8`` array of shape ``(n_envs, 1, screen_size, screen_size)``; rewards: ``float32``
    ``(n_envs,)``, clipped to their sign when ``settings.clip_reward``; dones: ``bool`` ``(n_envs,)``, at each lost
    life when ``settings.terminal_on_life_loss``. The step that ends a game also carries ``info["episode"]``
    (``r``: the unclipped score of the whole game, ``l``: frames, ``t``: seconds), as SB3's ``Monitor`` under
    ``AtariWrapper`` does, and appends that row to ``<monitor_dir>/<i>.monitor.csv``.

    :param env_id: the Gymnasium id (monitor headers name it).
    :param n_envs: env copies.
    :param settings: the ``AtariWrapper`` settings to reproduce.
    :param seed: base seed (env ``i`` draws its no-ops from ``seed + i``; None: a random one).
    :param monitor_dir: folder of the monitor files (None: none).
    :param num_threads: EnvPool worker threads (0: one per env, at most one per CPU).
    """

    def __init__(
        self,
        env_id: str,
        n_envs: int,
        settings: AtariSettings,
        seed: int | None = None,
        monitor_dir: str | None = None,
        num_threads: int = 0,
    ) -> None:
        self.env_id = env_id
        self.settings = settings
        self.num_threads = num_threads
        self._envpool = import_envpool()
        self._n = n_envs
        self._pool_seed = self._base_seed(seed)
        self._pool: Any = self._make_pool(self._pool_seed)
        self._fresh = True  # not reset since it was made: a seed() equal to its seed needs no new pool
        self._pending_seed: int | None = None
        size = settings.screen_size
        observation_space = spaces.Box(0, 255, (1, size, size), np.uint8)
        action_space = spaces.Discrete(int(self._pool.action_space.n))
        self._ids = np.arange(n_envs, dtype=np.int32)
        self._actions = np.zeros(n_envs, dtype=np.int32)
        self._scores = np.zeros(n_envs, dtype=np.float64)  # unclipped score of each env's current game
        self._steps = np.zeros(n_envs, dtype=np.int64)  # agent steps of each env's current game
        self._t_start = time.time()
        self._writers: list[ResultsWriter] = []
        if monitor_dir is not None:
            header: dict[str, float | str] = {"t_start": self._t_start, "env_id": env_id}
            self._writers = [ResultsWriter(os.path.join(monitor_dir, str(i)), header=header) for i in range(n_envs)]
        super().__init__(n_envs, observation_space, action_space)

    # ------------------------------------------------------------------ pool
    @staticmethod
    def _base_seed(seed: int | None) -> int:
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        return int(seed) % _SEED_MODULUS

    def _make_pool(self, seed: int) -> Any:
        threads = self.num_threads if self.num_threads > 0 else default_threads(self._n)
        return self._envpool.make(
            envpool_task_id(self.settings.game), env_type="gymnasium", num_envs=self._n, batch_size=self._n,
            seed=seed, num_threads=threads, **self.settings.envpool_kwargs())

    def _in_order(self, ids: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
        """``arrays`` reordered by env id (EnvPool returns a batch in the order its envs finished)."""
        if np.array_equal(ids, self._ids):
            return arrays
        order = np.argsort(ids)
        return tuple(a[order] for a in arrays)

    # ------------------------------------------------------------------ VecEnv API
    def seed(self, seed: int | None = None) -> list[int | None]:  # type: ignore[override]
        """Env ``i`` draws from ``seed + i`` from the next :meth:`reset` on (EnvPool is rebuilt for a new seed)."""
        self._pending_seed = self._base_seed(seed)
        return [self._pending_seed + i for i in range(self.num_envs)]

    def reset(self) -> np.ndarray:
        """Reset every env (a new game each, ending unfinished ones unrecorded); ``(n_envs, 1, H, W)``."""
        if self._pending_seed is not None:
            if self._pending_seed != self._pool_seed or not self._fresh:
                self._pool.close()
                self._pool = self._make_pool(self._pending_seed)
                self._pool_seed = self._pending_seed
            self._pending_seed = None
        obs, info = self._pool.reset()
        self._fresh = False
        (obs,) = self._in_order(info["env_id"], obs)
        self._scores[:] = 0.0
        self._steps[:] = 0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Store the actions, shape ``(n_envs,)`` (integers in ``0..n_actions-1``)."""
        acts = np.asarray(actions).reshape(self.num_envs).astype(np.int32)
        n_actions = int(self.action_space.n)  # type: ignore[attr-defined]
        if acts.min() < 0 or acts.max() >= n_actions:
            slot = int(np.flatnonzero((acts < 0) | (acts >= n_actions))[0])
            raise ValueError(f"actions must be ints in 0..{n_actions - 1}, got {acts[slot]} in slot {slot}")
        self._actions = acts

    def step_wait(self) -> VecEnvStepReturn:
        """Step every env with the stored actions; envs whose episode ended are reset within this call."""
        self._pool.send(self._actions, self._ids)
        obs, rewards, terminated, truncated, info = self._pool.recv()
        obs, rewards, terminated, truncated, true_rewards, game_over = self._in_order(
            info["env_id"], obs, rewards, terminated, truncated, info["reward"], info["terminated"])
        self._scores += true_rewards
        self._steps += 1
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        if dones.any():
            self._end_episodes(np.flatnonzero(dones), obs, terminated, truncated | (game_over != 0), infos)
        return obs, rewards.astype(np.float32, copy=False), dones, infos

    def _end_episodes(self, done: np.ndarray, obs: np.ndarray, terminated: np.ndarray, game_end: np.ndarray,
                      infos: list[dict[str, Any]]) -> None:
        """Fill the infos of the envs in ``done``, record their finished games and reset them in ``obs``."""
        now = round(time.time() - self._t_start, 6)
        for i in done:
            info = infos[i]
            info["terminal_observation"] = obs[i].copy()
            info["TimeLimit.truncated"] = bool(not terminated[i])
            if game_end[i]:
                episode = {"r": round(float(self._scores[i]), 6),
                           "l": int(self._steps[i]) * self.settings.frame_skip, "t": now}
                info["episode"] = episode
                if self._writers:
                    self._writers[i].write_row(episode)
                self._scores[i] = 0.0
                self._steps[i] = 0
        # a step of an env whose episode ended resets it; after a lost life the game goes on (EpisodicLifeEnv)
        self._pool.send(np.zeros(len(done), dtype=np.int32), done.astype(np.int32))
        reset_obs, _, _, _, reset_info = self._pool.recv()
        obs[reset_info["env_id"]] = reset_obs

    def close(self) -> None:
        """Close the monitor files and the pool."""
        for writer in self._writers:
            writer.close()
        self._writers = []
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """``render_mode`` (None) of each env; other attributes do not exist (the envs live in C++)."""
        if attr_name == "render_mode":
            return [None for _ in self._get_indices(indices)]
        raise AttributeError(f"{type(self).__name__} has no per-env attribute {attr_name!r} (envs live in EnvPool)")

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Not supported: the envs live in EnvPool."""
        raise NotImplementedError(f"{type(self).__name__} cannot set {attr_name!r}: the envs live in EnvPool")

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        """Not supported: the envs live in EnvPool."""
        raise NotImplementedError(f"{type(self).__name__} cannot call {method_name!r}: the envs live in EnvPool")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """True for ``Monitor`` and ``AtariWrapper`` (and their bases): their contract holds, e.g. evaluation
        counts the games of ``info["episode"]``, not the lives."""
        from stable_baselines3.common.atari_wrappers import AtariWrapper

        wrapped = any(issubclass(cls, wrapper_class) for cls in (Monitor, AtariWrapper))
        return [wrapped for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """No frames (record videos on the ALE env: ``record_video`` does)."""
        return [None for _ in range(self.num_envs)]


def make_envpool_vec_env(exp: Any, ref: EnvRef, n_envs: int, seed: int | None, env_kwargs: dict[str, Any],
                         monitor_dir: str | None) -> EnvPoolAtariVecEnv:
    """The EnvPool VecEnv of an experiment whose env wrapper is ``AtariWrapper`` (before frame stacking).

    :param exp: the :class:`~sbagents.core.experiment.Experiment`.
    :param env_kwargs: the env kwargs it would be built with (none are supported).
    :raises UsageError: the experiment cannot run on EnvPool, or EnvPool is not installed.
    """
    check_envpool(exp, ref, env_kwargs)
    return EnvPoolAtariVecEnv(ref.env_id, n_envs, atari_settings(exp, ref), seed, monitor_dir)
