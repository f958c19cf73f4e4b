"""Recording a turn-based game into a dataset (``python -m sbagents.collect`` on a game): a baseline's or a model's
games from the learner's seat of a :class:`~sbagents.games.selfplay.SelfPlayEnv`, as training sees them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.progress import ProgressReporter
from sbagents.games.players import Player
from sbagents.games.selfplay import SelfPlayEnv, make_selfplay_env


class Recorder(Protocol):
    """One episode as it is played (:class:`sbagents.datasets.writing.EpisodeRecorder`)."""

    def start(self, observation: Any, info: dict[str, Any] | None = None) -> None: ...

    def step(self, action: Any, observation: Any, reward: float, terminated: bool, truncated: bool,
             info: dict[str, Any]) -> None: ...


def record_games(player: Player, exp: Experiment, ref: EnvRef, n_games: int, seed: int, opponent: str,
                 new_episode: Callable[[], Recorder], progress: bool | None = None
                 ) -> tuple[list[Recorder], Any, Any]:
    """Play ``n_games`` of ``ref``'s game with ``player`` in the learner's seat (it alternates from game to game;
    the first game is reset with ``seed``, the next ones go on unseeded) against ``opponent`` (a player spec, greedy
    where it is a model) in the other seats; the games as episodes (the seat's observations and moves, the other
    seats' replies inside each step, each observation's legal moves as the info ``action_mask``) and the seat's
    observation and action spaces.

    :param new_episode: makes the recorder of one game.

    :raises UsageError: (one line) an opponent spec that does not load.
    """
    env = make_selfplay_env(ref.source, ref.modules, opponent=opponent, greedy_opponent=True, **exp.env_kwargs)
    reporter = ProgressReporter(n_games, bar=progress)
    try:
        episodes = [_one_game(env, player, new_episode(), seed if i == 0 else None, reporter, i)
                    for i in range(n_games)]
    finally:
        reporter.close()
        env.close()
    return episodes, env.observation_space, env.action_space


def _one_game(env: SelfPlayEnv, player: Player, recorder: Recorder, seed: int | None, reporter: ProgressReporter,
              index: int) -> Recorder:
    obs, _ = env.reset(seed=seed)
    recorder.start(obs, {"action_mask": env.action_masks()})
    while True:
        action = int(player(obs, env.action_masks()))
        obs, reward, terminated, truncated, info = env.step(action)
        recorder.step(np.asarray(action), obs, float(reward), bool(terminated), bool(truncated),
                      {**info, "action_mask": env.action_masks()})  # the next observation's legal moves
        if terminated or truncated:
            reporter.update(index + 1)
            return recorder

