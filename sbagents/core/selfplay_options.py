"""The ``self_play`` entry of a turn-based game's zoo config (:mod:`sbagents.games` plays it)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from sbagents.errors import UsageError

#: How the opponent pool draws a snapshot: the newest one, or one of the last ``last_k``.
POOL_MODES = ("latest", "uniform")


@dataclass(frozen=True)
class SelfPlayOptions:
    """The ``self_play`` entry of a game's zoo config.

    :param opponents: ``latest`` (the newest snapshot) or ``uniform`` (one of the last ``last_k``).
    :param last_k: pool size for ``uniform``.
    :param snapshot_freq: env steps between snapshots.
    :param mix: share of games against fixed players, e.g. ``{random: 0.1, heuristic: 0.3}`` (sum <= 1).
    :param eval_opponent: the opponent of periodic and final evaluations (``random``, ``heuristic``, ...).
    :param elo_games: games per pairing in each rating round (0: no ratings).
    :param elo_freq: env steps between rating rounds (none when periodic evaluation is off, ``--eval-freq 0``).
    """

    opponents: str = "uniform"
    last_k: int = 10
    snapshot_freq: int = 20_000
    mix: dict[str, float] = field(default_factory=dict)
    eval_opponent: str = "random"
    elo_games: int = 40
    elo_freq: int = 100_000

    @classmethod
    def from_mapping(cls, value: Any, source: str = "self_play") -> SelfPlayOptions:
        """Validate a config mapping (unknown keys and bad values raise :class:`UsageError`)."""
        if value is None:
            return cls()
        if not isinstance(value, dict):
            raise UsageError(f"self_play must be a mapping, got {value!r} ({source})")
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(value) - set(known))
        if unknown:
            raise UsageError(f"unknown self_play key(s) {', '.join(unknown)}; accepted: {', '.join(known)} ({source})")
        options = cls(**value)
        options.validate(source)
        return options

    def validate(self, source: str = "self_play") -> None:
        """Raise :class:`UsageError` for values out of range."""
        if self.opponents not in POOL_MODES:
            raise UsageError(f"self_play.opponents must be one of {', '.join(POOL_MODES)}, got {self.opponents!r} "
                             f"({source})")
        for key in ("last_k", "snapshot_freq", "elo_freq"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise UsageError(f"self_play.{key} must be a positive integer, got {value!r} ({source})")
        if isinstance(self.elo_games, bool) or not isinstance(self.elo_games, int) or self.elo_games < 0:
            raise UsageError(f"self_play.elo_games must be an integer >= 0, got {self.elo_games!r} ({source})")
        if not isinstance(self.mix, dict) or not all(isinstance(v, int | float) and 0 <= v <= 1
                                                     for v in self.mix.values()):
            raise UsageError(f"self_play.mix must map opponents to shares in [0, 1], got {self.mix!r} ({source})")
        if sum(self.mix.values()) > 1 + 1e-9:
            raise UsageError(f"self_play.mix shares must sum to <= 1, got {sum(self.mix.values())} ({source})")

    def as_mapping(self) -> dict[str, Any]:
        """Plain data (the env kwargs of a SubprocVecEnv worker)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
