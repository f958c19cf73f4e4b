"""A turn-based game seen from one seat: :class:`SelfPlayEnv`, a Gymnasium env for MaskablePPO.

The learner plays one seat; every other seat is played by an opponent inside :meth:`SelfPlayEnv.step`, so one
learner step is the learner's move plus the opponents' replies. The learner's seat alternates from game to game
(it plays first and second). Opponents are a fixed player, or a :class:`~sbagents.games.pool.OpponentPool` of the
learner's own past snapshots drawn anew each game. ``action_masks()`` is the mask of the seat to move
(sb3-contrib's MaskablePPO reads it); an illegal move is counted (``info["illegal_moves"]``), and the game
itself decides its outcome (PettingZoo's classic games end it with a loss for the offender).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

# the game keys of the info-key contract: UNPLAYED_KEY at a reset, the others at a game's last step
from sbagents.core.info_keys import ILLEGAL_KEY, OUTCOME_KEY, RETURN_KEY, SEAT_KEY, UNPLAYED_KEY
from sbagents.games.aec import MASK_KEY, OBS_KEY, game_name, make_game, masked_spaces
from sbagents.games.players import Player, load_player

#: Keyword arguments of :func:`make_selfplay_env` that are not the game's own.
SELFPLAY_KWARGS = frozenset({"opponent", "pool", "pool_dir", "seat", "greedy_opponent"})


class OpponentDraw(Protocol):
    """A source of opponents drawn anew every game (an opponent pool)."""

    def draw(self, rng: np.random.Generator) -> Player: ...


class SelfPlayEnv(gym.Env):
    """One seat of an AEC game against opponents.

    :param game_fn: ``(**game_kwargs) -> AECEnv`` with Dict observations ``{observation, action_mask}``.
    :param opponent: a player, an opponent spec (:func:`~sbagents.games.players.load_player`), or an object with
        ``draw(rng) -> Player`` called at every reset (an opponent pool).
    :param seat: always play this seat index (None: alternate, starting from a seed-drawn seat).
    :param greedy_opponent: a model named by an ``opponent`` spec acts greedily (default: it samples).
    :param name: the game's short name (for built-in opponents).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, game_fn: Callable[..., Any], opponent: Player | str | OpponentDraw = "random",
                 seat: int | None = None, name: str = "", render_mode: str | None = None,
                 greedy_opponent: bool = False, **game_kwargs: Any) -> None:
        kwargs = dict(game_kwargs)
        if render_mode is not None:
            kwargs["render_mode"] = render_mode
        self.game = game_fn(**kwargs)
        self._raw = _legal_move_env(self.game)
        self.render_mode = render_mode
        self.name = name
        self.observation_space, self.action_space = masked_spaces(self.game, name)
        self.seats: list[str] = list(self.game.possible_agents)
        self._opponent_spec = opponent
        self._greedy_opponent = greedy_opponent
        self._loaded: Player | None = None
        self._fixed_seat = seat
        self._seat_offset, self._games = 0, 0
        self.learner = self.seats[0]
        self.opponents: dict[str, Player] = {}
        self._mask = np.ones(self.action_space.n, bool)
        self._return = 0.0
        self.illegal_moves = 0  # the learner's, over this env's life
        self.opponent_illegal_moves = 0

    # -- opponents ---------------------------------------------------------------------------------------------
    def _draw_opponent(self) -> Player:
        spec = self._opponent_spec
        if isinstance(spec, str):
            if self._loaded is None:
                self._loaded = load_player(spec, self.name, self.np_random, self._greedy_opponent, len(self.seats),
                                           self.observation_space.shape)  # load once
            return self._loaded
        draw = getattr(spec, "draw", None)
        return draw(self.np_random) if callable(draw) else spec  # type: ignore[return-value,no-any-return]

    # -- gymnasium API ---------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._loaded = None  # fixed players draw from the new generator
            self._seat_offset = int(self.np_random.integers(len(self.seats)))
            self._games = 0
        unplayed: list[tuple[int, float]] = []
        while True:
            self.game.reset(seed=int(self.np_random.integers(2**31 - 1)))
            seat = self._fixed_seat if self._fixed_seat is not None else (
                self._seat_offset + self._games) % len(self.seats)
            self._games += 1
            self.learner = self.seats[seat]
            opponent = self._draw_opponent()
            self.opponents = {agent: opponent for agent in self.seats if agent != self.learner}
            self._return = self._play_opponents()
            if not self._over():
                return self._observe(), {SEAT_KEY: seat, UNPLAYED_KEY: unplayed}
            unplayed.append((seat, self._return))  # e.g. a poker hand folded before the learner acted
            if len(unplayed) >= 1000:
                raise RuntimeError(f"{self.name}: 1000 games in a row ended before the learner's seat moved")

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        action = int(np.asarray(action).reshape(-1)[0])
        illegal = not _legal(action, self._mask)
        self.illegal_moves += int(illegal)
        (self.game if illegal else self._raw).step(action)  # the game's own wrappers rule on illegal moves
        reward = float(self._raw.rewards[self.learner])
        if not self._over():
            reward += self._play_opponents()
        terminated = bool(self._raw.terminations.get(self.learner, False))
        truncated = bool(self._raw.truncations.get(self.learner, False)) and not terminated
        self._return += reward
        info: dict[str, Any] = {ILLEGAL_KEY: int(illegal)}
        if terminated or truncated:
            info.update({SEAT_KEY: self.seats.index(self.learner), RETURN_KEY: self._return,
                         OUTCOME_KEY: int(np.sign(self._return)), "is_success": self._return > 0})
        return self._observe(), reward, terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        """The legal actions of the learner's current position, (n_actions,) bool."""
        return self._mask.copy()

    def render(self) -> Any:
        return self.game.render() if self.render_mode is not None else None

    def close(self) -> None:
        self.game.close()

    # -- internals ---------------------------------------------------------------------------------------------
    def _over(self) -> bool:
        return bool(self._raw.terminations.get(self.learner, False) or self._raw.truncations.get(self.learner,
                                                                                                   False))

    def _observe(self) -> np.ndarray:
        seen = self._raw.observe(self.learner)
        self._mask = np.asarray(seen[MASK_KEY], bool)
        return np.asarray(seen[OBS_KEY], np.float32)

    def _play_opponents(self) -> float:
        """Opponents move until it is the learner's turn or the game is over; the learner's reward meanwhile."""
        reward = 0.0
        raw = self._raw
        while not self._over() and raw.agent_selection != self.learner:
            agent = raw.agent_selection
            if raw.terminations[agent] or raw.truncations[agent]:
                self.game.step(None)  # a seat out of the game (games of more than two seats)
                continue
            seen = raw.observe(agent)
            mask = np.asarray(seen[MASK_KEY])
            action = int(self.opponents[agent](seen[OBS_KEY], mask))
            illegal = not _legal(action, mask)
            self.opponent_illegal_moves += int(illegal)
            (self.game if illegal else raw).step(action)
            reward += float(raw.rewards[self.learner])
        return reward


def make_selfplay_env(source: str, modules: tuple[str, ...] = (), opponent: Any = "random",
                      pool: dict[str, Any] | None = None, pool_dir: str | None = None, seat: int | None = None,
                      greedy_opponent: bool = False, **game_kwargs: Any) -> SelfPlayEnv:
    """A picklable constructor of :class:`SelfPlayEnv` for the game ``source`` (SB3's ``make_vec_env``).

    :param opponent: a fixed opponent spec (used when ``pool_dir`` is None, and as the pool's mixed-in player).
    :param pool: the self-play pool settings (:class:`~sbagents.core.selfplay_options.SelfPlayOptions` as a mapping).
    :param pool_dir: the run's snapshot folder: opponents are drawn from it every game.
    """
    name = game_name(source)
    game_fn = _GameFn(source, modules)
    if pool_dir is not None:
        from sbagents.core.selfplay_options import SelfPlayOptions
        from sbagents.games.pool import OpponentPool

        options = SelfPlayOptions.from_mapping(pool or {})
        return SelfPlayEnv(game_fn, OpponentPool(pool_dir, options, name), seat=seat, name=name, **game_kwargs)
    return SelfPlayEnv(game_fn, opponent, seat=seat, name=name, greedy_opponent=greedy_opponent, **game_kwargs)


def _legal(action: int, mask: np.ndarray) -> bool:
    """Whether ``action`` is in range and allowed by ``mask`` (n_actions,)."""
    return 0 <= action < len(mask) and bool(mask[action])


class _GameFn:
    """Picklable ``(**kwargs) -> AECEnv`` of a game source."""

    def __init__(self, source: str, modules: tuple[str, ...]) -> None:
        self.source, self.modules = source, modules

    def __call__(self, **kwargs: Any) -> Any:
        return make_game(self.source, self.modules, **kwargs)


#: PettingZoo's standard AEC wrappers: for a legal move they only check what the self-play env checks itself.
_CHECK_ONLY_WRAPPERS = ("OrderEnforcingWrapper", "AssertOutOfBoundsWrapper", "TerminateIllegalWrapper")


def _legal_move_env(game: Any) -> Any:
    """The env legal moves are stepped and read on: the unwrapped game when every wrapper around it is one of
    PettingZoo's checking wrappers (3 wrapper layers cost as much as the game itself), else the game as given.
    Illegal moves always go through the given env, so its wrappers decide what they mean."""
    env = game
    while hasattr(env, "env") and env is not getattr(env, "unwrapped", env):
        if type(env).__name__ not in _CHECK_ONLY_WRAPPERS:
            return game
        env = env.env
    return env
