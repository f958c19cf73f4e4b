"""Players of a turn-based game: anything that maps ``(observation, action_mask) -> action``.

``observation`` is the game's own observation of the seat to move (PettingZoo's classic games show the board from
that seat), ``action_mask`` a 0/1 array over the Discrete actions. :func:`load_player` turns an ``--opponent``
spec into a player: ``random``, a built-in (``heuristic`` for connect four, ``minimax`` for tic-tac-toe), a run
dir, a model zip, or ``module:callable`` (a user's function with that signature).
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sbagents.errors import UsageError
from sbagents.games.numpy_policy import NumpyActor, numpy_actor

#: Built-in opponent names that work in every game.
GENERIC_OPPONENTS = ("random",)
#: Built-in opponent names tied to one game (see :mod:`sbagents.games.builtin`).
GAME_OPPONENTS = ("heuristic", "opportunist", "minimax")


class Player(Protocol):
    """A game player: ``observation`` (the seat to move's view), ``action_mask`` (n_actions,) -> action index."""

    def __call__(self, observation: np.ndarray, action_mask: np.ndarray) -> int: ...


class RandomPlayer:
    """Uniform over the legal actions."""

    def __init__(self, rng: np.random.Generator | None = None) -> None:
        self.rng = rng if rng is not None else np.random.default_rng()

    def __call__(self, observation: np.ndarray, action_mask: np.ndarray) -> int:
        return int(self.rng.choice(np.flatnonzero(action_mask)))


class BuiltinPlayer:
    """A built-in ``fn(observation, action_mask, rng) -> action`` with its own random generator."""

    def __init__(self, fn: Callable[[np.ndarray, np.ndarray, np.random.Generator], int],
                 rng: np.random.Generator | None = None) -> None:
        self.fn, self.rng = fn, rng if rng is not None else np.random.default_rng()

    def __call__(self, observation: np.ndarray, action_mask: np.ndarray) -> int:
        return int(self.fn(observation, action_mask, self.rng))


class ModelPlayer:
    """An SB3 model acting with the mask (MaskablePPO) or, for models without masking, its argmax/sample.

    :param deterministic: greedy actions (False: sample from the policy, as self-play opponents do).
    :param actor: the model's actor as numpy (:func:`~sbagents.games.numpy_policy.numpy_actor`): the same
        distribution without a torch call per move. None: ``model.predict``.
    """

    def __init__(self, model: Any, deterministic: bool = True, actor: NumpyActor | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.model, self.deterministic, self.actor = model, deterministic, actor
        self.rng = rng if rng is not None else np.random.default_rng()
        self.masked = "action_masks" in _parameters(model.predict)

    def __call__(self, observation: np.ndarray, action_mask: np.ndarray) -> int:
        if self.actor is not None and self.masked:
            return self.actor.act(observation, action_mask, self.deterministic, self.rng)
        obs = np.asarray(observation, np.float32)[None]
        if self.masked:
            action, _ = self.model.predict(obs, deterministic=self.deterministic,
                                           action_masks=np.asarray(action_mask, bool)[None])
        else:
            action, _ = self.model.predict(obs, deterministic=self.deterministic)
        return int(np.asarray(action).reshape(-1)[0])


def snapshot_player(path: str | Path, deterministic: bool, rng: np.random.Generator | None = None) -> ModelPlayer:
    """A player of a saved model (loaded once per path, acting through its numpy actor when it has one)."""
    key = str(Path(path).resolve())
    return ModelPlayer(load_model(key), deterministic, _load_actor(key), rng)


@functools.lru_cache(maxsize=32)
def _load_actor(path: str) -> NumpyActor | None:
    return numpy_actor(load_model(path).policy)


def _parameters(fn: Callable[..., Any]) -> tuple[str, ...]:
    import inspect

    return tuple(inspect.signature(fn).parameters)


@functools.lru_cache(maxsize=32)
def load_model(path: str) -> Any:
    """Load a game model zip on the CPU (MaskablePPO first, then the other Discrete-action algorithms), without
    running code from the file (:mod:`sbagents.safe_load`: an opponent's zip may come from anyone).

    Cached by path: self-play envs load the same snapshot many times.
    """
    from sbagents.algos import ALGOS
    from sbagents.safe_load import UntrustedContentError, load_model, read_model_data

    read_model_data(path)  # one line for a missing, empty or truncated file
    errors = []
    for name in ("ppo_mask", "ppo", "a2c", "dqn", "qrdqn", "trpo"):
        if name not in ALGOS:
            continue
        try:
            return load_model(ALGOS[name].cls, path, device="cpu")
        except UntrustedContentError:
            raise
        except UsageError:  # the model of another class: try the next one
            errors.append(name)
    raise UsageError(f"cannot load a model from {path} (tried {', '.join(errors)})")


def run_dir_model(path: Path) -> Path:
    """The model a run dir's opponent plays with: ``best_model.zip`` when training rated one, else the final one."""
    best = path / "best_model.zip"
    if best.is_file():
        return best
    finals = [p for p in sorted(path.glob("*.zip")) if not p.name.startswith(("rl_model_", "best_model"))]
    if not finals:
        raise UsageError(f"--opponent {path}: no model zip in this run dir")
    return finals[0]


def load_player(spec: str | Player, game: str, rng: np.random.Generator | None = None,
                deterministic: bool = False, n_seats: int = 2, obs_shape: tuple[int, ...] | None = None) -> Player:
    """The player an opponent spec names.

    :param spec: ``random``, ``heuristic``, ``minimax``, a run dir, a ``.zip`` model, ``module:callable``, or a
        player object (returned as is).
    :param game: the game's short name (``connect_four_v3``), for the built-ins.
    :param deterministic: model players act greedily (False: sample, the default for self-play opponents).
    :param n_seats: the game's seats (the built-ins play two-seat games).
    :param obs_shape: the game's observation shape, checked against a model's.
    :raises UsageError: a spec that does not load, a built-in that does not exist for this game or its seats, or
        a model that observes another shape.
    """
    if not isinstance(spec, str):
        return spec
    if spec == "random":
        return RandomPlayer(rng)
    if spec in GAME_OPPONENTS:
        from sbagents.games.builtin import builtin_for

        if n_seats != 2:
            raise UsageError(f"the {spec} opponent plays two-seat games (connect four, tic-tac-toe); this {game} has "
                             f"{n_seats} seats: use random, a run dir, a model .zip or module:function")
        fn = builtin_for(spec, game)
        if fn is None:
            raise UsageError(f"no built-in {spec!r} opponent for {game}; built-ins: random everywhere, heuristic "
                             "and opportunist for connect four, minimax and opportunist for tic-tac-toe")
        return BuiltinPlayer(fn, rng)
    path = Path(spec)
    if path.is_dir() or path.suffix == ".zip":
        if path.suffix == ".zip" and not path.is_file():
            raise UsageError(f"--opponent {spec}: no such model file")
        player = snapshot_player(run_dir_model(path) if path.is_dir() else path, deterministic, rng)
        shape = tuple(player.model.observation_space.shape)
        if obs_shape is not None and shape != tuple(obs_shape):
            raise UsageError(f"--opponent {spec} observes shape {shape}; the seats of this {game} observe "
                             f"{tuple(obs_shape)} (a model of another game or seat count)")
        return player
    if ":" in spec:
        return _import_callable(spec)
    raise UsageError(f"--opponent {spec!r} is not an opponent; accepted: random, heuristic (connect four), "
                     "opportunist (connect four, tic-tac-toe), minimax (tic-tac-toe), a run dir, a model .zip, or "
                     "module:function")


def _import_callable(spec: str) -> Player:
    module_name, _, attr = spec.partition(":")
    try:
        fn = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise UsageError(f"--opponent {spec}: cannot import it ({exc})") from None
    if not callable(fn):
        raise UsageError(f"--opponent {spec} is not callable; it must be a function (observation, action_mask) "
                         "-> action")
    return fn  # type: ignore[no-any-return]
