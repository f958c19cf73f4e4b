"""The homes of a federation: each home's user fixes ``preferred_temp`` / ``preferred_light`` of SmartHome.

Client homes are drawn non-IID: each has one of four tastes (cool or warm, dim or bright), the corners of the
preference ranges, so no single home sees the users of another taste. Held-out homes are users no client had:
drawn uniformly over the whole preference ranges, with their own seed (a new home joining the federation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Preferred temperature (C) and light (lux) ranges of the four tastes; together they cover the corners of
#: SmartHome's preference ranges (20-26 C, 50-80 lux), leaving the middle to no client.
TASTES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "cool-dim": ((20.0, 21.5), (50.0, 57.0)),
    "warm-bright": ((24.5, 26.0), (73.0, 80.0)),
    "cool-bright": ((20.0, 21.5), (73.0, 80.0)),
    "warm-dim": ((24.5, 26.0), (50.0, 57.0)),
}
#: The whole preference ranges (SmartHome's reset distribution): held-out homes are drawn from them.
PREFERENCE_RANGES = ((20.0, 26.0), (50.0, 80.0))
#: Offset of the held-out homes' seed, so they never share draws with the clients.
HELD_OUT_SEED_OFFSET = 7_919


@dataclass(frozen=True)
class Home:
    """One home's user.

    :param index: the home's number (0-based; the Flower partition id in simulation).
    :param taste: ``cool-dim``, ``warm-bright``, ``cool-bright``, ``warm-dim``, or ``any`` (held-out homes).
    """

    index: int
    taste: str
    preferred_temp: float
    preferred_light: float

    def env_kwargs(self) -> dict[str, float]:
        """SmartHome's constructor arguments for this user."""
        return {"preferred_temp": self.preferred_temp, "preferred_light": self.preferred_light}

    def describe(self) -> str:
        return f"home {self.index} ({self.taste}: {self.preferred_temp:.1f} C, {self.preferred_light:.0f} lux)"


def client_homes(n_homes: int, seed: int) -> list[Home]:
    """``n_homes`` homes, tastes in turn (cool-dim, warm-bright, cool-bright, warm-dim, ...), preferences drawn
    uniformly within the taste."""
    rng = np.random.default_rng(seed)
    names = list(TASTES)
    homes = []
    for i in range(n_homes):
        taste = names[i % len(names)]
        (t_lo, t_hi), (l_lo, l_hi) = TASTES[taste]
        homes.append(Home(i, taste, round(float(rng.uniform(t_lo, t_hi)), 2), round(float(rng.uniform(l_lo, l_hi)), 1)))
    return homes


def held_out_homes(n_homes: int, seed: int) -> list[Home]:
    """``n_homes`` users drawn uniformly over the whole preference ranges (seeded apart from the clients)."""
    rng = np.random.default_rng(seed + HELD_OUT_SEED_OFFSET)
    (t_lo, t_hi), (l_lo, l_hi) = PREFERENCE_RANGES
    return [Home(i, "any", round(float(rng.uniform(t_lo, t_hi)), 2), round(float(rng.uniform(l_lo, l_hi)), 1))
            for i in range(n_homes)]
