"""A run's transparency log (``train --transparency-log``,
:class:`~sbagents.callbacks.transparency.TransparencyCSVCallback`) -> recorded episodes for a dataset
(``python -m sbagents.collect --from-log PATH``).

The log holds, per env and step, the raw observation the action was taken on, the action, the reward, the done flags
and scalar infos, so a run's training experience can become a dataset after the fact. What a log cannot give:

- the observation after an episode's last step (the log has none: the next row is the next episode's reset). The
  episode's last observation is repeated in its place; cloning never reads it, and a terminated step's value ignores
  it.
- observations the log skipped (images, components of more than 512 numbers) and steps it skipped
  (``TransparencyCSVCallback(every=N)``, N > 1): such logs are refused, as are team logs (an ``agent`` column) and
  the book's layout (no done flags).

Episodes are read per env in the order the log wrote them; an episode the log holds without its end (training stopped
within it) is left out.
"""

from __future__ import annotations

import csv
import gzip
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from sbagents.callbacks.transparency import observation_layout
from sbagents.datasets.writing import INFO_KEYS, EpisodeRecorder
from sbagents.errors import UsageError

_FIXED = ("episode", "step")
_DONE = ("reward", "terminated", "truncated")


def _rows(path: Path) -> Iterator[list[str]]:
    opener: Any = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt", newline="") as handle:
            yield from csv.reader(handle)
    except (OSError, EOFError, UnicodeDecodeError, csv.Error) as exc:
        raise UsageError(f"--from-log {path}: cannot read the log ({type(exc).__name__}: {exc})") from None


def _flat_size(space: spaces.Space[Any]) -> int:
    return int(np.prod(space.shape)) if space.shape else 1


def _observation_parser(space: spaces.Space[Any], path: Path) -> tuple[int, Any]:
    """How many columns an observation of ``space`` takes, and a function of those cells -> the observation.

    :raises UsageError: the log does not hold the whole observation (images, large components, nested dicts).
    """
    parts = list(space.spaces.items()) if isinstance(space, spaces.Dict) else [(None, space)]
    layout = observation_layout(space)
    full = [(key, _flat_size(sub)) for key, sub in parts]
    if any(isinstance(sub, spaces.Dict) for _, sub in parts) or layout != full:
        raise UsageError(f"--from-log {path}: the log does not hold this env's whole observation {space} (images and "
                         "components of more than 512 numbers are not logged)")

    def parse(cells: list[str]) -> Any:
        values, start = {}, 0
        for key, sub in parts:
            size = _flat_size(sub)
            chunk = np.asarray([float(c) for c in cells[start:start + size]])
            start += size
            values[key] = chunk.astype(sub.dtype).reshape(sub.shape) if sub.shape else chunk.astype(sub.dtype)[0]
        return values if isinstance(space, spaces.Dict) else values[None]

    return sum(size for _, size in full), parse


def _action_parser(space: spaces.Space[Any]) -> tuple[int, Any]:
    size = _flat_size(space)

    def parse(cells: list[str]) -> np.ndarray:
        chunk = np.asarray([float(c) for c in cells]).astype(space.dtype)
        return chunk.reshape(space.shape) if space.shape else chunk[0]

    return size, parse


def _flag(cell: str) -> bool:
    return cell.strip() in ("True", "true", "1")


def _info(row: list[str], columns: dict[str, int]) -> dict[str, Any]:
    info: dict[str, Any] = {}
    for key, index in columns.items():
        cell = row[index] if index < len(row) else ""
        if cell == "":
            continue
        if key == "is_success":
            info[key] = _flag(cell)
        elif key == "cost":
            info[key] = float(cell)
        else:
            info[key] = cell
    return info


def episodes_from_log(path: str | Path, observation_space: spaces.Space[Any], action_space: spaces.Space[Any],
                      limit: int | None = None) -> tuple[list[EpisodeRecorder], int]:
    """The complete episodes of the transparency log at ``path`` (``.csv`` or ``.csv.gz``), for an env of these
    spaces, and how many incomplete ones were left out.

    :param limit: at most this many episodes (the first ones to end; None: all).
    :raises UsageError: (one line) a log that is not there or not a transparency log of such an env, a team's or the
        book's layout, skipped steps, or no complete episode.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"--from-log {path}: no such file (a run's transparency log, e.g. <run dir>/transparency.csv)")
    rows = _rows(path)
    header = next(rows, None)
    if header is None or not all(name in header for name in (*_FIXED, *_DONE)):
        raise UsageError(f"--from-log {path}: not a transparency log with done flags (columns episode, step, reward, "
                         "terminated, truncated; the book's layout has no done flags)")
    if "agent" in header:
        raise UsageError(f"--from-log {path}: a team's log; datasets from logs are single-agent for now")
    n_obs, parse_obs = _observation_parser(observation_space, path)
    n_act, parse_action = _action_parser(action_space)
    first, reward = header.index("step") + 1, header.index("reward")
    if reward - first != n_obs + n_act:
        raise UsageError(f"--from-log {path}: the log has {reward - first} observation and action columns; this env "
                         f"takes {n_obs} + {n_act} ({observation_space}, {action_space})")
    env_col = header.index("env") if "env" in header else None
    ep_col, step_col = header.index("episode"), header.index("step")
    term_col, trunc_col = header.index("terminated"), header.index("truncated")
    info_cols = {key: header.index(key) for key in INFO_KEYS if key in header}
    open_episodes: dict[tuple[str, str], EpisodeRecorder] = {}
    done: list[EpisodeRecorder] = []
    for line, row in enumerate(rows, start=2):
        if limit is not None and len(done) >= limit:
            break
        if len(row) < trunc_col + 1:
            continue  # a row cut off by a stopped run
        try:
            key = (row[env_col] if env_col is not None else "0", row[ep_col])
            step = int(row[step_col])
            obs = parse_obs(row[first:first + n_obs])
            action = parse_action(row[first + n_obs:reward])
            value, terminated, truncated = float(row[reward]), _flag(row[term_col]), _flag(row[trunc_col])
        except (ValueError, IndexError) as exc:
            raise UsageError(f"--from-log {path}: line {line} does not parse ({exc})") from None
        recorder = open_episodes.get(key)
        if recorder is None:
            if step != 0:
                continue  # the log starts within this episode (appended to, or cut): not a whole episode
            recorder = EpisodeRecorder()
            recorder.start(obs)
        elif step != len(recorder.actions):
            raise UsageError(f"--from-log {path}: line {line} is step {step} of an episode at step "
                             f"{len(recorder.actions)}; a log that skips steps (every > 1) cannot become a dataset")
        else:
            recorder.observations[-1] = obs  # the observation this step was taken on
        recorder.step(action, obs, value, terminated, truncated and not terminated, _info(row, info_cols))
        if terminated or truncated:
            done.append(recorder)
            open_episodes.pop(key, None)
        else:
            open_episodes[key] = recorder
    if not done:
        raise UsageError(f"--from-log {path}: the log holds no complete episode")
    return done, len(open_episodes)


def log_description(path: Path, episodes: int, dropped: int) -> str:
    """The dataset's description of episodes read from a log."""
    note = f"; {dropped} episodes without their end left out" if dropped else ""
    return (f"{episodes} episodes read from the transparency log {path.name} by python -m sbagents.collect "
            f"--from-log (the observation after each episode's last step is not logged: the last one is repeated"
            f"{note})")

