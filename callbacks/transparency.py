"""Per-decision audit log (the book's chapter 6 transparency CSV) as an SB3 callback."""

from __future__ import annotations

import functools
import gzip
import io
import weakref
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.preprocessing import is_image_space

from sbagents.callbacks.common import (
    INTERNAL_INFO_KEYS,
    acted_slots,
    agent_layout,
    env_attr,
    find_vec_normalize,
    install_exception_hook,
    is_scalar,
    remove_exception_hook,
)
from sbagents.callbacks.episodes import ACTED

#: zlib level of ``.csv.gz`` logs (1 is ~3x faster than gzip's default 9, files ~25% larger).
GZIP_LEVEL = 1
#: Observation components larger than this are not dumped (like images).
MAX_OBS_COLUMNS = 512


@functools.lru_cache(maxsize=4096)
def csv_quote(text: str) -> str:
    """CSV-quote ``text`` if needed (cached: info strings such as event names repeat every step)."""
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def csv_cell(value: Any, float_format: str = "%.7g") -> str:
    """One CSV cell: empty for None, quoted strings, floats with ``float_format``, numpy scalars as Python's."""
    if value is None:
        return ""
    if isinstance(value, str):
        return csv_quote(value)
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.item()
    if isinstance(value, float):
        return float_format % value
    return str(value)


def observation_layout(space: spaces.Space) -> list[tuple[str | None, int]]:
    """``(dict key or None, flat size)`` of every dumped observation component; images are skipped."""
    if isinstance(space, spaces.Dict):
        return [(k, sz) for k, sub in space.spaces.items() for _, sz in observation_layout(sub) if sz > 0]
    if isinstance(space, spaces.Box) and (is_image_space(space, check_channels=False) or space.shape == ()):
        return [(None, 0 if space.shape != () else 1)]
    size = int(np.prod(space.shape)) if space.shape else 1
    return [(None, size if size <= MAX_OBS_COLUMNS else 0)]


def flat_observations(obs: Any, layout: list[tuple[str | None, int]], num_envs: int) -> np.ndarray:
    """The dumped components of a batch of observations (``obs``: array or dict of arrays, first axis the env)
    flattened into ``(num_envs, columns)``, key by key as :func:`observation_layout` lists them."""
    parts = []
    for key, size in layout:
        if size:
            arr = np.asarray(obs[key] if key is not None else obs)
            parts.append(arr.reshape(arr.shape[0], -1))
    if not parts:
        return np.zeros((num_envs, 0))
    return parts[0].copy() if len(parts) == 1 else np.concatenate(parts, axis=1)


def column_names(venv: Any, attr: str, count: int, stem: str, given: Sequence[str] | None = None) -> list[str]:
    """``given`` names, else the env's ``attr`` (``obs_names`` / ``action_names``), when there are ``count`` of them;
    otherwise ``<stem>_0 .. <stem>_<count-1>``."""
    if given is None:
        found = env_attr(venv, attr)
        given = [str(x) for x in found] if found is not None else None
    if given is None or len(given) != count:
        return [f"{stem}_{i}" for i in range(count)]
    return list(given)


class _CsvSink:
    """Buffered text sink: rows wait in memory and are written at :meth:`flush`; ``.gz`` compresses.

    Reopens in append mode after :meth:`close`, so one sink survives several ``learn`` calls.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.compress = path.suffix == ".gz"
        self.pending: list[str] = []
        self.fh: IO[str] | None = None

    def open(self) -> None:
        if self.fh is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.compress:
                self.fh = gzip.open(  # noqa: SIM115
                    self.path, "at", compresslevel=GZIP_LEVEL, encoding="utf-8", newline=""
                )
            else:
                self.fh = open(self.path, "a", encoding="utf-8", newline="")  # noqa: SIM115

    def flush(self, sync: bool = True) -> None:
        if self.pending:
            self.open()
            assert self.fh is not None
            self.fh.write("".join(self.pending))
            self.pending.clear()
        if sync and self.fh is not None:
            self.fh.flush()

    def close(self) -> None:
        self.flush(sync=False)
        if self.fh is not None:
            self.fh.close()
            self.fh = None


def _read_head_tail(path: Path, n_tail: int = 4096) -> tuple[str, list[str]]:
    """First line (without newline) and up to ``n_tail`` last lines of a CSV or CSV.gz file."""
    if path.suffix == ".gz":
        with gzip.open(path, "rt", encoding="utf-8", newline="") as fh:
            header = fh.readline().rstrip("\r\n")
            tail = deque(fh, maxlen=n_tail)
        return header, list(tail)
    with open(path, "rb") as fb:
        header = fb.readline().decode("utf-8").rstrip("\r\n")
        size = fb.seek(0, io.SEEK_END)
        fb.seek(max(size - 256 * 1024, 0))
        lines = fb.read().decode("utf-8", errors="replace").splitlines()
    return header, lines[1:][-n_tail:] if len(lines) > 1 else []


class TransparencyCSVCallback(BaseCallback):
    """Write one CSV row per env (and agent) per step: the observation the action was taken in, the action,
    the reward, the done flags and selected ``info`` values. A PettingZoo agent gets rows while it is present
    (none after it left or before it arrived).

    Columns: ``env``, ``agent`` (multi-agent VecEnvs only), ``episode`` and ``step`` (0-based counters per
    env), one column per observation component (names from the env's ``obs_names``, else ``obs_0..``;
    image observations and components with more than 512 numbers are not dumped; Dict observations are
    flattened key by key), one per action component (``action_names``, else ``action_0..``), ``reward``,
    ``terminated``, ``truncated`` and the info keys.

    - Observations are RAW: under ``VecNormalize`` the original observation is logged, and the row of a
      step shows the observation the action was taken in (for a done step: the last observation of the
      episode, never the reset observation). Rewards are unnormalized (``get_original_reward``).
    - Info columns: ``info_keys`` if given, else every scalar key (None, str, bool, number) found in the
      infos of the first logged step, minus SB3's own keys (``terminal_observation``, ``episode``,
      ``TimeLimit.truncated``). The columns are then fixed: keys that appear later (e.g. ``is_success`` at
      episode end) are not added, so pass ``info_keys`` to log those. Missing values are empty cells. An
      info key that clashes with another column is named ``info.<key>``.
    - ``book_header=True`` writes the book's capitalised layout (SmartHome: ``Episode, Step, Temperature,
      Light_Level, Time, Preferred_Temp, Preferred_Light, Action_Temp, Action_Light, Reward``): no
      done flags, info columns only if ``info_keys`` is given, ``Env``/``Agent`` columns only when there
      are several envs/agents.
    - Floats are written with ``float_format`` (``"%.7g"``, float32 precision, by default; ``"%r"`` for
      exact float64), integers as integers, booleans as ``True``/``False``.
    - Writes are buffered and flushed at every episode end, every rollout end, at training end, and when
      an exception (Ctrl-C included) leaves ``learn`` (see :func:`install_exception_hook`); the file is
      also closed at garbage collection and interpreter exit. ``.csv.gz`` paths are gzip-compressed
      (complete after training end, an exception or exit).
    - An existing file with the same header is appended to (no second header) and episode numbers
      continue after the largest one in its last rows; a different header raises ``ValueError``.

    :param path: output file (``.csv`` or ``.csv.gz``).
    :param info_keys: info keys to log (a comma-separated string or a sequence); None: see above.
    :param every: log every ``every``-th vec step (all envs of that step).
    :param book_header: use the book's column names (see above).
    :param obs_names: override the observation column names.
    :param action_names: override the action column names.
    :param float_format: %-format of floats.
    """

    def __init__(
        self,
        path: str | Path,
        info_keys: str | Sequence[str] | None = None,
        every: int = 1,
        book_header: bool = False,
        obs_names: Sequence[str] | None = None,
        action_names: Sequence[str] | None = None,
        float_format: str = "%.7g",
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.path = Path(path)
        if isinstance(info_keys, str):
            info_keys = [k.strip() for k in info_keys.split(",") if k.strip()]
        self.info_keys: list[str] | None = None if info_keys is None else list(info_keys)
        self.every = int(every)
        self.book_header = bool(book_header)
        self._obs_names_arg = None if obs_names is None else list(obs_names)
        self._action_names_arg = None if action_names is None else list(action_names)
        self._sink = _CsvSink(self.path)
        self._finalizer = weakref.finalize(self, self._sink.close)
        self.header: list[str] | None = None
        self.rows_written = 0
        self._episode: np.ndarray = np.zeros(0, dtype=np.int64)
        self._step: np.ndarray = np.zeros(0, dtype=np.int64)
        self._obs: Any = None
        self._prefix: list[str] = []
        self._info_cols: list[str] = []
        self._layout: list[tuple[str | None, int]] | None = None
        self._num_fmt: str | None = None
        self.float_format = float_format
        float_format % 1.5  # fail early on a bad format

    # ------------------------------------------------------------------ setup
    def _on_training_start(self) -> None:
        env = self.training_env
        n = env.num_envs
        if len(self._episode) != n:
            self._episode = np.zeros(n, dtype=np.int64)
            self._step = np.zeros(n, dtype=np.int64)
        elif self.model.num_timesteps == 0:  # learn() reset the envs: unfinished episodes are over
            self._episode += self._step > 0
            self._step[:] = 0
        self._vn = find_vec_normalize(env)
        raw = self._vn.get_original_obs() if self._vn is not None else self.model._last_obs
        self._obs = self._flat_obs(raw)
        n_agents, agents = agent_layout(env)
        self._n_agents, self._agents = n_agents, agents
        show_env = n > 1 or not self.book_header
        self._id_cols = (["env"] if show_env else []) + (["agent"] if agents else [])
        self._prefix = []
        for k in range(n):
            ids = [str(k // n_agents)] if show_env else []
            if agents is not None:
                ids.append(csv_quote(agents[k % n_agents]))
            self._prefix.append(",".join(ids))
        install_exception_hook(self.model, self, self._sink.close)

    def _flat_obs(self, obs: Any) -> np.ndarray:
        if self._layout is None:
            self._layout = observation_layout(self.training_env.observation_space)
        return flat_observations(obs, self._layout, self.training_env.num_envs)

    def _build_header(self, actions: np.ndarray, infos: Sequence[dict[str, Any]]) -> list[str]:
        obs_cols = column_names(self.training_env, "obs_names", self._obs.shape[1], "obs", self._obs_names_arg)
        act_cols = column_names(self.training_env, "action_names", actions.shape[1], "action", self._action_names_arg)
        if self.book_header:
            ids = [c.capitalize() for c in self._id_cols]
            fixed = [*ids, "Episode", "Step", *obs_cols, *act_cols, "Reward"]
        else:
            ids = self._id_cols
            fixed = [*ids, "episode", "step", *obs_cols, *act_cols, "reward", "terminated", "truncated"]
        keys = self.info_keys
        if keys is None:
            keys = []
            if not self.book_header:
                for info in infos:
                    for k, v in info.items():
                        if k not in INTERNAL_INFO_KEYS and k not in keys and is_scalar(v):
                            keys.append(k)
            self.info_keys = keys
        self._info_cols = list(keys)
        taken = set(fixed)
        return fixed + [f"info.{k}" if k in taken else k for k in keys]

    def _open(self) -> None:
        """Check an existing file's header (append) and continue its episode numbering."""
        assert self.header is not None
        header_line = ",".join(csv_quote(h) for h in self.header)
        if self.path.exists() and self.path.stat().st_size > 0:
            existing, tail = _read_head_tail(self.path)
            if existing != header_line:
                raise ValueError(
                    f"{self.path} exists with another header ({existing[:120]!r}); "
                    f"choose another path or remove it (new header: {header_line[:120]!r})"
                )
            col = self.header.index("episode" if not self.book_header else "Episode")
            last = [int(row.split(",")[col]) for row in tail if row.count(",") >= col]
            if last and self.rows_written == 0:
                self._episode += max(last) + 1
        else:
            self._sink.pending.append(header_line + "\n")
        self._sink.flush()

    # ------------------------------------------------------------------ per step
    def _on_step(self) -> bool:
        loc = self.locals
        dones = np.asarray(loc["dones"], dtype=bool)
        infos: Sequence[dict[str, Any]] = loc["infos"]
        if self._vn is not None:
            new_obs, rewards = self._vn.get_original_obs(), self._vn.get_original_reward()
        else:
            new_obs, rewards = loc["new_obs"], loc["rewards"]
        if self.n_calls % self.every == 0:
            actions = np.asarray(loc["clipped_actions"] if "clipped_actions" in loc else loc["actions"])
            actions = actions.reshape(len(dones), -1)
            if self.header is None:
                self.header = self._build_header(actions, infos)
                self._open()
            self._write_rows(actions, np.asarray(rewards), dones, infos)
        self._obs = self._flat_obs(new_obs)
        acted = acted_slots(infos)
        self._step += acted
        ended = dones & acted  # an absent agent's slot keeps its counters until the agent is back
        if ended.any():
            self._step[ended] = 0
            self._episode[ended] += 1
            self._sink.flush()
        return True

    def _numbers_format(self, actions: np.ndarray) -> str:
        """%-format of ``episode, step, obs..., actions..., reward`` (ints stay ints)."""
        ff = self.float_format

        def fmt(arr: np.ndarray) -> list[str]:
            return [ff if arr.dtype.kind in "fc" else "%d"] * arr.shape[1]

        return ",".join(["%d", "%d", *fmt(self._obs), *fmt(actions), ff])

    def _write_rows(
        self, actions: np.ndarray, rewards: np.ndarray, dones: np.ndarray, infos: Sequence[dict[str, Any]]
    ) -> None:
        if self._num_fmt is None:
            self._num_fmt = self._numbers_format(actions)
        num_fmt, ff = self._num_fmt, self.float_format
        obs_l, act_l, rew_l = self._obs.tolist(), actions.tolist(), rewards.astype(np.float64).tolist()
        episode, step = self._episode.tolist(), self._step.tolist()
        book, keys = self.book_header, self._info_cols
        lines = []
        for i, info in enumerate(infos):
            if not info.get(ACTED, True):
                continue  # an absent agent: no decision was made
            line = num_fmt % (episode[i], step[i], *obs_l[i], *act_l[i], rew_l[i])
            if self._prefix[i]:
                line = f"{self._prefix[i]},{line}"
            if not book:
                trunc = bool(dones[i] and info.get("TimeLimit.truncated", False))
                line += ",False,True" if trunc else (",True,False" if dones[i] else ",False,False")
            if keys:
                cells = [ff % v if (v := info.get(k)).__class__ is float else csv_cell(v, ff) for k in keys]
                line += "," + ",".join(cells)
            lines.append(line + "\n")
        self._sink.pending.extend(lines)
        self.rows_written += len(lines)

    def _on_rollout_end(self) -> None:
        self._sink.flush(sync=not self._sink.compress)

    def _on_training_end(self) -> None:
        self._sink.close()
        remove_exception_hook(self.model, self)

    def close(self) -> None:
        """Flush and close the file (it is reopened in append mode if training continues)."""
        self._sink.close()
