"""PettingZoo's SB3 action-mask tutorial, rebuilt: the baseline side of the games benchmark.

Source: Farama-Foundation/PettingZoo, ``tutorials/SB3/connect_four/sb3_connect_four_action_mask.py`` (the
"SB3: Action Masked PPO for Connect Four" docs page includes it) and its test ``tutorials/SB3/test/
test_sb3_action_mask.py``. Its logic is rebuilt here in our own words, not copied.

The recipe (``train_action_mask``)
    ``env = connect_four_v3.env(**{})`` (default kwargs; today ``pettingzoo.make("aec", "classic/connect_four-v3")``,
    the same env), wrapped in ``SB3ActionMaskWrapper``, then ``env.reset(seed=0)`` (to set the spaces), then
    ``ActionMasker(env, mask_fn)`` with ``mask_fn = env.action_mask()``, then
    ``MaskablePPO(MaskableActorCriticPolicy, env, verbose=1)`` with every other hyperparameter at its SB3 /
    sb3-contrib default (n_steps 2048, batch 64, 10 epochs, lr 3e-4, gamma 0.99, GAE 0.95, clip 0.2, ent 0, vf 0.5,
    64x64 tanh MLP, one env), ``model.set_random_seed(0)`` *after* construction, ``model.learn(total_timesteps=
    20_480)`` (10 rollouts), ``model.save(...)``. One model plays both seats (self-play of one policy through a
    single-agent env). Its notes: "10k steps: Winrate 0.76; 20k: 0.86; 40k: 0.86" and "winrate should be ~80%".

Its evaluation (``eval_action_mask``, rebuilt as :func:`eval_tutorial_recipe`)
    100 games; game ``i`` is ``env.reset(seed=i)`` with ``env.action_space("player_0").seed(i)``. ``player_0`` (who
    moves first) is uniform random over the legal moves (``action_space.sample(mask)``); the trained model is always
    ``player_1`` (second to move), ``model.predict(obs, action_masks=mask, deterministic=True)``. A game with unequal
    final rewards adds the winner's reward to ``scores[winner]``; ``winrate = scores["player_1"] / sum(scores)``:
    wins over *decisive* games, draws left out, and only ever as the second player.

Two versions of the wrapper's ``step``
    ``variant="original"`` (the default, the behaviour our issue describes): the tutorial as published on 10 July
    2023 (PettingZoo PR #1017): ``step`` steps the AEC env and returns ``last()``: observation, cumulative reward,
    termination, truncation and info all of the agent to move *next*. Its test noted that tic-tac-toe "still loses
    every time (most likely an error somewhere)". ``variant="fixed"``: PettingZoo PR #1203 ("Fix bug in SB3 tutorial
    ActionMask", May 2024), upstream's version ever since: the observation of the agent to move next, but the
    reward, termination, truncation and info of the agent that just acted; its test then moved tic-tac-toe to the
    envs that beat random (at 32,768 steps) and texas hold'em to the hard ones.

    History that matters for the numbers: the tutorial's "20k steps: Winrate 0.86" was measured on the connect four
    of that day, which did *not* pass the turn after a winning move, so ``last()`` was the winner's own +1. PR #1020
    (11 July 2023, released with the tutorial in PettingZoo 1.24.0) made connect four pass the turn on every move,
    as tic-tac-toe always did; from then on the ``original`` step scores a winning move with the loser's -1 (below).
    The gymnasium <= 0.29.1 guard (PR #1243, Dec 2024) came after PR #1203 and was lifted by PR #1272 (Mar 2025,
    gymnasium 1.0: the wrapper also subclasses ``gymnasium.Env``); no upstream version has both the ``last()`` step
    and the guard.

The flaw (which agent's reward SB3 sees)
    ``original``: after the learner moves, SB3 gets the *next* agent's reward. A winning move ends the game with
    ``rewards = {mover: +1, other: -1}`` and the turn already passed to the other seat, so the winning move is
    scored -1 (connect four and tic-tac-toe give no other reward). Every decisive game is an episode of return -1,
    whoever won; only draws score 0: the policy is taught that winning is bad (tests/test_games_tutorial.py steps
    the wrapper through a won game to check it).
    ``fixed``: the winning move is scored +1, but nothing tells the loser it lost: its last move is scored 0, and
    every decisive game is an episode of return +1 whoever won. In both versions the one "agent" SB3 sees plays both
    seats in one episode, so returns and PPO's value bootstrap (the next state is the *opponent's* view, its value
    added with a + sign) mix both sides' outcomes; a zero-sum game needs the sign flipped at every turn, and neither
    version does. What ``fixed`` can learn is that the move which ends the game is worth more than the ones before
    (+1 now against discounted +1 later): enough to beat random play, not the one-ply win-or-block ``heuristic``.

Measured (connect four, 20,480 steps, seed 0, pettingzoo 1.27 / sb3-contrib 2.9 / torch 2.13 CPU, one thread,
~30 s wall on a shared 2-core machine; 200 games of ``sbagents.games.matches.play_games``, seats alternating;
the tutorial's metric over its 100 games; the ``random`` row is a uniformly random player, for scale):

    =========  ==================  ====================  ==================
    variant    vs random W/D/L     vs heuristic W/D/L    tutorial winrate
    =========  ==================  ====================  ==================
    original   43.5 / 0 / 56.5 %   1.0 / 0 / 99.0 %      0.39 (39 of 100)
    fixed      81.5 / 0 / 18.5 %   0.5 / 0 / 99.5 %      0.88 (88 of 100)
    random     48.5 / 0 / 51.5 %   1.5 / 0 / 98.5 %
    =========  ==================  ====================  ==================

Adaptations to today's stack (gymnasium 1.x, pettingzoo 1.27, sb3-contrib 2.9); the logic is unchanged
    * The wrapper also subclasses ``gymnasium.Env``: gymnasium 1.x's ``Wrapper.__init__`` (so sb3-contrib's
      ``ActionMasker`` and SB3's ``Monitor``) raises ``TypeError: Expected env to be a gymnasium.Env``; this is
      exactly upstream's own fix (PR #1272). A side effect upstream has too: ``gymnasium.Env``'s class attributes
      ``metadata`` and ``render_mode`` shadow the AEC env's (``env.unwrapped.metadata`` still has the game's).
    * Any masked AEC classic game module (``"pettingzoo.classic.tictactoe_v3"``...) instead of ``connect_four_v3``:
      its ``env(**kwargs)`` is called as the tutorial's ``env_fn.env(**env_kwargs)`` is.
    * ``verbose=0`` instead of 1 (nothing printed), no ``model.save`` (the model is returned), and
      ``torch.set_num_threads(1)`` before training (our benchmarks' CPU budget).
    * Seeding: the tutorial calls ``model.set_random_seed(seed)`` only after ``MaskablePPO(...)`` has built the
      policy, so its initial weights come from torch's unseeded global generator and two runs differ. We seed the
      global generators (SB3's ``set_random_seed(seed)``) once before construction too, so a seed gives one model;
      everything after construction is the tutorial's order (``set_random_seed`` again, then ``learn``).
    * :func:`eval_tutorial_recipe` takes the model (the tutorial loads its newest saved zip) and returns its
      numbers instead of printing them.

The model's observation space is the game's ``observation`` sub-space as is (connect four: ``Box(0, 1, (6, 7, 2),
int8)``); ``predict`` checks shapes, not dtypes, so :class:`sbagents.games.players.ModelPlayer`'s float32 batch of
the same shape is accepted and gives the same actions (the policy casts to float either way).

    model = train_tutorial_recipe("pettingzoo.classic.connect_four_v3")          # 20,480 steps, seed 0
    eval_tutorial_recipe(model, "pettingzoo.classic.connect_four_v3")["winrate"]  # the tutorial's own metric
"""

from __future__ import annotations

import importlib
from typing import Any, Literal, cast

import gymnasium as gym
import numpy as np
import pettingzoo.utils
import torch
from sb3_contrib import MaskablePPO
from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
from sb3_contrib.common.wrappers import ActionMasker
from stable_baselines3.common.utils import set_random_seed

#: The tutorial's training budget (``train_action_mask(env_fn, steps=20_480, seed=0)``).
TUTORIAL_STEPS = 20_480
#: The tutorial's seed.
TUTORIAL_SEED = 0
#: The tutorial's evaluation: games against a random first player.
TUTORIAL_EVAL_GAMES = 100
#: ``original``: step returns ``last()`` (July 2023, PR #1017); ``fixed``: the acting agent's reward (PR #1203).
Variant = Literal["original", "fixed"]
TUTORIAL_VARIANTS: tuple[Variant, ...] = ("original", "fixed")


class SB3ActionMaskWrapper(pettingzoo.utils.BaseWrapper, gym.Env):  # type: ignore[misc]
    """An AEC game as a single-agent Gymnasium env for MaskablePPO, as the tutorial first published it.

    One policy plays every seat: each ``step`` is one move of whichever agent is to move. ``reset`` fixes the
    spaces to the first agent's (``observation`` sub-space, actions) and returns the observation of the agent to
    move; ``step`` plays the move and returns ``last()``: everything of the agent that moves next.
    """

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None  # type: ignore[override]
              ) -> tuple[Any, dict[str, Any]]:
        super().reset(seed, options)  # type: ignore[call-arg]  # (mypy resolves super() to gymnasium.Env)
        first = self.possible_agents[0]
        # A masked game's observation space is a Dict of its "observation" and its "action_mask".
        observations = cast(gym.spaces.Dict, super().observation_space(first))
        # Instance attributes: SB3 needs spaces, not the AEC env's per-agent space functions. They shadow
        # PettingZoo's methods on purpose: this class is both an AECEnv (methods) and a gym.Env (attributes), whose
        # declarations of these names conflict (the class's ignore[misc]); no annotation can express the shadowing.
        self.observation_space = observations["observation"]  # type: ignore[method-assign, assignment]
        self.action_space = super().action_space(first)  # type: ignore[method-assign, assignment]
        return self.observe(self.agent_selection), {}  # AEC reset returns nothing: observe, and no info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        super().step(action)
        observation, reward, terminated, truncated, info = super().last()  # all of the NEXT agent to move
        return observation, reward, terminated, truncated, info

    def observe(self, agent: Any) -> Any:
        """The agent's ``observation`` alone (the action mask stripped off)."""
        return super().observe(agent)["observation"]  # type: ignore[index]

    def action_mask(self) -> np.ndarray:
        """The legal moves of the agent to move."""
        return super().observe(self.agent_selection)["action_mask"]  # type: ignore[index, no-any-return]


class FixedSB3ActionMaskWrapper(SB3ActionMaskWrapper):
    """The tutorial after PettingZoo PR #1203: the next agent's observation, the acting agent's outcome."""

    # Gymnasium's step (a 5-tuple), like the original's, not the AEC step (None): the same conflict of the two bases.
    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        actor = self.agent_selection
        super(SB3ActionMaskWrapper, self).step(action)  # the AEC step (skipping the original's return)
        return (self.observe(self.agent_selection), self._cumulative_rewards[actor], self.terminations[actor],
                self.truncations[actor], self.infos[actor])


_WRAPPERS: dict[str, type[SB3ActionMaskWrapper]] = {"original": SB3ActionMaskWrapper,
                                                     "fixed": FixedSB3ActionMaskWrapper}


def _mask_fn(env: gym.Env) -> np.ndarray:
    """``ActionMasker``'s mask function: the wrapper's own ``action_mask``."""
    return env.action_mask()  # type: ignore[attr-defined, no-any-return]


def make_game(game_module: str, **game_kwargs: Any) -> Any:
    """The AEC env of ``game_module`` (``"pettingzoo.classic.connect_four_v3"``): its ``env(**game_kwargs)``."""
    return importlib.import_module(game_module).env(**game_kwargs)


def make_tutorial_env(game_module: str, *, seed: int | None = TUTORIAL_SEED, variant: Variant = "original",
                      **game_kwargs: Any) -> ActionMasker:
    """The tutorial's training env: ``ActionMasker(SB3ActionMaskWrapper(game), mask_fn)``, reset once with ``seed``
    before ``ActionMasker`` (the tutorial's ``env.reset(seed=seed)``, which sets the spaces).

    :param game_module: a masked AEC game module (``pettingzoo.classic.tictactoe_v3``, ``texas_holdem_v4``...).
    :param variant: ``original`` (step returns ``last()``) or ``fixed`` (PettingZoo PR #1203), see the module doc.
    :param game_kwargs: the game's ``env()`` kwargs (the tutorial passes none).
    """
    if variant not in _WRAPPERS:
        raise ValueError(f"variant {variant!r}: one of {TUTORIAL_VARIANTS}")
    env = _WRAPPERS[variant](make_game(game_module, **game_kwargs))
    env.reset(seed=seed)
    return ActionMasker(env, _mask_fn)


def train_tutorial_recipe(game_module: str, steps: int = TUTORIAL_STEPS, seed: int = TUTORIAL_SEED, *,
                          variant: Variant = "original", **game_kwargs: Any) -> MaskablePPO:
    """Train the tutorial's recipe on ``game_module`` and return the model (nothing saved, nothing printed).

    ``MaskablePPO(MaskableActorCriticPolicy, env)`` at the SB3 / sb3-contrib defaults, ``set_random_seed(seed)``,
    ``learn(steps)``, on one thread. Deterministic for a seed (see the module doc's seeding note).
    """
    torch.set_num_threads(1)
    env = make_tutorial_env(game_module, seed=seed, variant=variant, **game_kwargs)
    set_random_seed(seed)  # ours: the tutorial leaves the initial weights to the unseeded global generator
    model = MaskablePPO(MaskableActorCriticPolicy, env, verbose=0)  # the tutorial: verbose=1
    model.set_random_seed(seed)
    model.learn(total_timesteps=steps)
    env.close()
    return model


def eval_tutorial_recipe(model: Any, game_module: str, num_games: int = TUTORIAL_EVAL_GAMES,
                         **game_kwargs: Any) -> dict[str, Any]:
    """The tutorial's evaluation: ``model`` (greedy, masked) as the second seat against a random first seat.

    Game ``i`` resets with ``seed=i`` and seeds the random player's action space with ``i``. A game with unequal
    final rewards adds the winner's reward to its score. Returns ``winrate`` (the model's score over all scores:
    decisive games only), ``scores``, ``total_rewards`` and, beside the tutorial's numbers, ``wins`` / ``draws`` /
    ``losses`` of the model over all games.
    """
    env = make_game(game_module, **game_kwargs)
    random_seat, model_seat = env.possible_agents[0], env.possible_agents[1]
    scores = dict.fromkeys(env.possible_agents, 0.0)
    total_rewards = dict.fromkeys(env.possible_agents, 0.0)
    outcomes = {"wins": 0, "draws": 0, "losses": 0}
    for game in range(num_games):
        env.reset(seed=game)
        env.action_space(random_seat).seed(game)
        for agent in env.agent_iter():
            seen, _, terminated, truncated, _ = env.last()
            if terminated or truncated:
                final = {a: float(r) for a, r in env.rewards.items()}
                if final[random_seat] != final[model_seat]:
                    winner = max(final, key=lambda a: final[a])
                    scores[winner] += final[winner]
                for a in env.possible_agents:
                    total_rewards[a] += final[a]
                sign = np.sign(final[model_seat])
                outcomes["wins" if sign > 0 else "losses" if sign < 0 else "draws"] += 1
                break
            observation, mask = seen["observation"], seen["action_mask"]
            if agent == random_seat:
                action = env.action_space(agent).sample(mask)
            else:
                action = int(model.predict(observation, action_masks=mask, deterministic=True)[0])
            env.step(action)
    env.close()
    total = sum(scores.values())
    return {"winrate": scores[model_seat] / total if total else 0.0, "scores": scores,
            "total_rewards": total_rewards, "n_games": num_games, **outcomes}
