"""Self-play training and evaluation of turn-based games inside the SB3 run pipeline.

:func:`training_env_kwargs` points the training envs at the run's snapshot pool; :func:`game_callbacks` adds the
pool's :class:`~sbagents.games.pool.SnapshotCallback`, sb3-contrib's ``MaskableEvalCallback`` against the config's
``eval_opponent`` (``evaluations.npz``; success = win) and the :class:`~sbagents.games.elo.EloCallback` (which owns
``best_model.zip``); :func:`evaluate_game` is ``evaluate`` for games: a match against an opponent.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from sb3_contrib.common.maskable.callbacks import MaskableEvalCallback
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.run_files import AtomicEvalOutputs
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.options import EvaluateOptions
from sbagents.core.selfplay_options import SelfPlayOptions
from sbagents.errors import UsageError
from sbagents.games.builtin import builtin_for
from sbagents.games.elo import EloCallback, fixed_opponents
from sbagents.games.matches import match_summary, play_games
from sbagents.games.numpy_policy import numpy_actor
from sbagents.games.players import ModelPlayer, Player, load_player
from sbagents.games.pool import SNAPSHOT_DIR, IllegalMovesCallback, SnapshotCallback
from sbagents.games.recording import record_games  # noqa: F401 (collect's, through game_operations())
from sbagents.games.selfplay import SelfPlayEnv, make_selfplay_env

#: Seed offset of the rating matches (apart from training and evaluation envs).
ELO_SEED_OFFSET = 20_000


def self_play_options(exp: Experiment) -> SelfPlayOptions:
    """The experiment's ``self_play`` settings (defaults when the config has none)."""
    return exp.kind_options if isinstance(exp.kind_options, SelfPlayOptions) else SelfPlayOptions()


def training_env_kwargs(exp: Experiment, ref: EnvRef, run_dir: Path) -> dict[str, Any]:
    """Env kwargs of the training envs: opponents drawn from ``<run_dir>/opponents`` with the config's pool.

    :raises UsageError: a ``mix`` opponent that does not load for this game.
    """
    options = self_play_options(exp)
    probe = make_selfplay_env(ref.source, ref.modules, **exp.env_kwargs)
    for name in options.mix:
        load_player(name, ref.env_id, None, False, len(probe.seats), probe.observation_space.shape)
    probe.close()
    return {"pool": options.as_mapping(), "pool_dir": str(run_dir / SNAPSHOT_DIR)}


def game_env(exp: Experiment, ref: EnvRef, opponent: Player | str, seat: int | None = None) -> SelfPlayEnv:
    """One :class:`SelfPlayEnv` of the experiment's game against a fixed opponent."""
    return make_selfplay_env(ref.source, ref.modules, opponent=opponent, seat=seat, **exp.env_kwargs)


class AtomicMaskableEvalCallback(AtomicEvalOutputs, MaskableEvalCallback):
    """sb3-contrib's ``MaskableEvalCallback`` with atomic ``evaluations.npz`` (:mod:`sbagents.callbacks.run_files`)."""


def game_callbacks(exp: Experiment, ref: EnvRef, run_dir: Path, seed: int, n_envs: int,
                   eval_calls: int, eval_episodes: int, after_eval: BaseCallback | None, *,
                   make_eval_env: Callable[..., VecEnv]) -> list[BaseCallback]:
    """Snapshot pool, illegal-move count, periodic evaluation against ``eval_opponent`` (every ``eval_calls``
    callback calls; 0: none) and rating rounds (every ``elo_freq`` env steps while evaluations are on).

    :param make_eval_env: builds the evaluation env as training wraps it
        (:func:`sbagents.env_factory.make_eval_vec`, which knows every kind of env and so sits above this package).
    """
    options = self_play_options(exp)
    snapshots = SnapshotCallback(run_dir / SNAPSHOT_DIR, options.snapshot_freq)
    callbacks: list[BaseCallback] = [snapshots, IllegalMovesCallback()]
    if eval_calls <= 0:
        return callbacks
    eval_env = make_eval_env(exp, ref, 1, seed + ELO_SEED_OFFSET // 2, vec_env="dummy",
                             env_kwargs={"opponent": options.eval_opponent})
    callbacks.append(AtomicMaskableEvalCallback(
        eval_env, n_eval_episodes=eval_episodes, eval_freq=eval_calls, log_path=str(run_dir),
        best_model_save_path=None, deterministic=exp.deterministic_eval, verbose=0, callback_after_eval=after_eval))
    if options.elo_games > 0:
        callbacks.append(EloCallback(
            functools.partial(game_env, exp, ref), fixed_opponents(ref.env_id), ref.env_id, run_dir,
            snapshots.save, max(options.elo_freq // n_envs, 1), options.elo_games, exp.deterministic_eval,
            seed + ELO_SEED_OFFSET))
    return callbacks


#: The built-in players ``--policy scripted`` tries, strongest first.
SCRIPTED_PLAYERS = ("minimax", "heuristic", "opportunist")


def evaluate_game_baseline(policy: str, exp: Experiment, ref: EnvRef, options: EvaluateOptions) -> dict[str, Any]:
    """:func:`evaluate_game` of a baseline (:func:`game_player`) in the learner's seats, against ``options.opponent``
    (default: random).

    :raises UsageError: ``scripted`` for a game without a built-in player.
    """
    player = game_player(policy, ref, options.seed)
    return evaluate_game(player, exp, ref, replace(options, opponent=options.opponent or "random"), algo=policy)


def game_player(acting: str | BaseAlgorithm, ref: EnvRef, seed: int | None, deterministic: bool = True) -> Player:
    """The player of a baseline, ``random`` (random legal moves) or ``scripted`` (the strongest built-in player of the
    game, :data:`SCRIPTED_PLAYERS`), or of a model (greedy when ``deterministic``, with the mask).

    :raises UsageError: ``scripted`` for a game without a built-in player.
    """
    rng = np.random.default_rng(seed)
    if isinstance(acting, BaseAlgorithm):
        return ModelPlayer(acting, deterministic, numpy_actor(acting.policy), rng)
    name = "random"
    if acting == "scripted":
        name = next((n for n in SCRIPTED_PLAYERS if builtin_for(n, ref.env_id) is not None), "")
        if not name:
            raise UsageError(f"{ref.env_id} has no scripted player; --policy scripted plays the built-in players of "
                             "connect four and tic-tac-toe; --policy random plays any game")
    return load_player(name, ref.env_id, rng)


def evaluate_game(model: BaseAlgorithm | Player, exp: Experiment, ref: EnvRef, options: EvaluateOptions,
                  algo: str = "") -> dict[str, Any]:
    """Play ``options.n_episodes`` games against ``options.opponent`` (default: the config's ``eval_opponent``),
    seats alternated; the summary of :func:`~sbagents.games.matches.match_summary`."""
    if options.render:
        raise UsageError("--render does not draw turn-based games; play against the agent with python -m sbagents.play")
    opponent = options.opponent or self_play_options(exp).eval_opponent
    rng = np.random.default_rng(options.seed)
    player = (ModelPlayer(model, options.greedy(exp.deterministic_eval), numpy_actor(model.policy), rng)
              if isinstance(model, BaseAlgorithm) else model)
    env = make_selfplay_env(ref.source, ref.modules, opponent=opponent, greedy_opponent=True, **exp.env_kwargs)
    result = play_games(env, player, options.n_episodes, seed=options.seed)
    env.close()
    return match_summary(result, ref.env_id, algo or exp.algo, opponent)
