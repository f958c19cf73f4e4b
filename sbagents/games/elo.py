"""Elo ratings of a self-play run: snapshots against each other and against the fixed opponents.

Every rating round (``self_play.elo_freq`` env steps) the current model becomes a rated player and plays ``elo_games``
games (seats alternated) against each fixed opponent (``random``, plus the game's built-ins) and the last three
rated snapshots. Ratings are the Bradley-Terry maximum-likelihood fit of all games so far (draws count half;
one virtual draw per pairing keeps a player that won every game finite), on the Elo scale with ``random`` at 0.
Written after each round: ``elo.csv`` (player, timesteps, elo, games, score), ``elo.png``, and ``best_model.zip``
(the highest-rated snapshot).
"""

from __future__ import annotations

import shutil
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from sbagents.atomic import save_figure, write_csv, write_with
from sbagents.games.matches import play_games
from sbagents.games.players import Player, load_player, snapshot_player
from sbagents.games.selfplay import SelfPlayEnv

ANCHOR = "random"
ELO_CSV, ELO_PNG, BEST_MODEL = "elo.csv", "elo.png", "best_model.zip"
#: How many of the latest rated snapshots each new one plays.
PREVIOUS_OPPONENTS = 3


def fit_elo(scores: dict[tuple[str, str], tuple[float, int]], anchor: str = ANCHOR,
            iterations: int = 500) -> dict[str, float]:
    """Bradley-Terry ratings on the Elo scale (400 log10 strength), ``anchor`` at 0.

    :param scores: ``(a, b) -> (a's points, games)``: wins 1, draws 0.5, each pairing listed once.
    :return: player -> rating.
    """
    players = sorted({p for pair in scores for p in pair})
    index = {p: i for i, p in enumerate(players)}
    n = len(players)
    wins, games = np.zeros(n), np.zeros((n, n))
    for (a, b), (points, count) in scores.items():
        i, j = index[a], index[b]
        wins[i] += points + 0.5  # + one virtual draw per pairing
        wins[j] += count - points + 0.5
        games[i, j] += count + 1
        games[j, i] += count + 1
    strength = np.ones(n)
    for _ in range(iterations):  # Hunter's MM algorithm
        denom = (games / (strength[:, None] + strength[None, :])).sum(axis=1)
        strength = np.where(denom > 0, wins / np.maximum(denom, 1e-12), strength)
        strength /= np.exp(np.mean(np.log(strength)))
    ratings = 400 * np.log10(strength)
    if anchor in index:
        ratings -= ratings[index[anchor]]
    return {p: float(r) for p, r in zip(players, ratings, strict=True)}


class EloCallback(BaseCallback):
    """Rating rounds during training (see the module docstring).

    :param make_env: ``(opponent: Player) -> SelfPlayEnv`` of the game (a fresh env for each match).
    :param fixed: fixed opponents by name (``random``, ``heuristic``, ...), built with :func:`load_player`.
    :param snapshot: ``() -> Path`` saving the current model as a snapshot (the self-play pool's saver).
    :param eval_freq: callback calls between rounds (``elo_freq`` env steps / n_envs).
    :param deterministic: the rated models act greedily.
    """

    def __init__(self, make_env: Callable[[Player], SelfPlayEnv], fixed: list[str], game: str, run_dir: Path,
                 snapshot: Callable[[], Path], eval_freq: int, n_games: int, deterministic: bool = True,
                 seed: int = 0) -> None:
        super().__init__()
        self.make_env, self.fixed, self.game, self.run_dir = make_env, fixed, game, Path(run_dir)
        self.snapshot, self.eval_freq, self.n_games = snapshot, eval_freq, n_games
        self.deterministic, self.seed = deterministic, seed
        self.scores: dict[tuple[str, str], tuple[float, int]] = {}
        self.rated: dict[str, tuple[int, Path]] = {}  # snapshot name -> (timesteps, model file)
        self.ratings: dict[str, float] = {}
        self.best: str | None = None
        self.rounds = 0

    def _on_step(self) -> bool:
        if self.n_calls % self.eval_freq == 0:
            self.rate_current()
        return True

    def _player(self, name: str, rng: np.random.Generator) -> Player:
        if name in self.rated:
            return snapshot_player(self.rated[name][1], self.deterministic, rng)
        return load_player(name, self.game, rng)

    def rate_current(self) -> dict[str, float]:
        """One round: snapshot the model, play its matches, refit, write the files; the new ratings."""
        path = self.snapshot()
        name = f"step_{self.num_timesteps}"
        me = snapshot_player(path, self.deterministic, np.random.default_rng([self.seed, self.rounds]))
        previous = list(self.rated)[-PREVIOUS_OPPONENTS:]
        self.rated[name] = (self.num_timesteps, path)
        for k, other in enumerate([*self.fixed, *previous]):
            rng = np.random.default_rng([self.seed, self.rounds, k])
            env = self.make_env(self._player(other, rng))
            result = play_games(env, me, self.n_games, seed=int(rng.integers(2**31 - 1)))
            env.close()
            self.scores[(name, other)] = (result.score() * len(result.games), len(result.games))
        self.rounds += 1
        self.ratings = fit_elo(self.scores)
        self.logger.record("elo/current", self.ratings[name])
        for other in self.fixed:
            self.logger.record(f"elo/score_vs_{other}", self.scores[(name, other)][0] / self.n_games)
        self._write()
        return self.ratings

    def _write(self) -> None:
        games: dict[str, int] = defaultdict(int)
        points: dict[str, float] = defaultdict(float)
        for (a, b), (p, count) in self.scores.items():
            games[a] += count
            games[b] += count
            points[a] += p
            points[b] += count - p
        rows = sorted(self.ratings.items(), key=lambda kv: -kv[1])
        write_csv(self.run_dir / ELO_CSV, ["player", "timesteps", "elo", "games", "score"], (
            {"player": player, "timesteps": self.rated[player][0] if player in self.rated else "",
             "elo": f"{rating:.1f}", "games": games[player],
             "score": f"{points[player] / max(games[player], 1):.3f}"} for player, rating in rows))
        best = max(self.rated, key=lambda p: self.ratings[p])
        if best != self.best:
            source = self.rated[best][1]
            write_with(self.run_dir / BEST_MODEL, lambda tmp: shutil.copyfile(source, tmp))
            self.best = best
        plot_elo(self.run_dir / ELO_PNG, self.ratings, {p: s for p, (s, _) in self.rated.items()}, self.game)


def plot_elo(path: Path, ratings: dict[str, float], steps: dict[str, int], title: str) -> None:
    """Snapshot ratings against training steps, fixed opponents as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4))
    snaps = sorted(steps, key=steps.__getitem__)
    ax.plot([steps[p] for p in snaps], [ratings[p] for p in snaps], "o-", label="snapshots")
    for k, (player, rating) in enumerate(sorted((p, r) for p, r in ratings.items() if p not in steps)):
        ax.axhline(rating, linestyle="--", color=f"C{k + 1}", label=player)
    ax.set_xlabel("timesteps")
    ax.set_ylabel(f"Elo ({ANCHOR} = 0)")
    ax.set_title(f"{title}: self-play ratings")
    ax.legend(loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def fixed_opponents(game: str) -> list[str]:
    """``random`` and the built-in opponents this game has."""
    from sbagents.games.builtin import BUILTIN_OPPONENTS, builtin_for

    return ["random", *(name for name in BUILTIN_OPPONENTS if builtin_for(name, game) is not None)]
