"""SuperSuit's PettingZoo observation wrappers against the preprocessing sbagents uses, on real pixel envs.

sbagents keeps its own pixel preprocessing (:mod:`sbagents.multiagent.preprocessing`, OpenCV) and SB3's
``VecFrameStack`` where SuperSuit 3.11 offers ``color_reduction_v0``, ``resize_v1``, ``frame_stack_v1``, ``dtype_v0``
and ``normalize_obs_v0``. These tests pin the measured reasons, wrapper by wrapper, so that a SuperSuit release that
changes them shows up here:

- ``color_reduction_v0("full")`` truncates ``float32`` luma to ``uint8`` (OpenCV, and SB3's ``WarpFrame`` on the
  Gymnasium side, round): equal on cooperative pong's black-and-white screen, one grey level darker on ~98% of
  pistonball's pixels, a -0.5 level bias on random colours; it takes RGB only (no RGBA, no 2-D image), drops the
  channel axis (``(H, W)``, not ``(H, W, 1)``) and leaves an image ``state()`` as it is.
- ``resize_v1`` resamples bilinearly or nearest (tinyscaler), not by area as ``INTER_AREA`` does: a 280x480 ->
  84x84 pong frame differs by up to ~170 grey levels, the ball dims (aliasing) and the mean brightness drifts.
- ``frame_stack_v1`` stacks the same values as SB3's ``VecFrameStack`` (also with agents that die), but returns one
  array that it overwrites in place at every step; frame stacking is SB3's, not hand-written code.
- ``dtype_v0`` + ``normalize_obs_v0`` give ``float32`` ``[0, 1]`` observations that SB3 no longer treats as images
  (``CnnPolicy`` scales ``uint8`` images itself).
- SuperSuit's observation wrappers run a ``ParallelEnv`` through ``parallel_to_aec`` and back: on KAZ, whose agents
  die, the round trip changes nothing (observations, rewards, terminations, truncations, infos, agents).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from typing import Any

import cv2
import numpy as np
import pytest
import supersuit as ss
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.butterfly import cooperative_pong_v6, knights_archers_zombies_v11, pistonball_v6
from stable_baselines3.common.preprocessing import is_image_space
from supersuit.utils.basic_transforms import color_reduction, resize

from sbagents.core.env_names import resolve_env
from sbagents.core.experiment import build_experiment
from sbagents.core.info_keys import ACTED
from sbagents.core.options import TrainSpec
from sbagents.env_factory import make_team_vecs
from sbagents.multiagent.preprocessing import GrayscaleObservation, ImagePreprocessing

PONG = "pettingzoo.butterfly.cooperative_pong_v6"
KAZ = "pettingzoo.butterfly.knights_archers_zombies_v11"
#: KAZ observing images, with enough zombies and line deaths that agents die within ~150 steps.
KAZ_KWARGS: dict[str, Any] = {"obs_method": "image", "max_zombies": 20, "spawn_delay": 3, "line_death": True}
RECIPE = {"sbagents.multiagent.preprocessing.ImagePreprocessing": {"grayscale": True, "shape": [84, 84]}}


@pytest.fixture(autouse=True)
def _quiet() -> Iterator[None]:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "You are calling render method without specifying any render mode")
        warnings.filterwarnings("ignore", r"The `infos` dictionary returned by `env.reset")
        yield


def pong(**kwargs: Any) -> ParallelEnv:
    return cooperative_pong_v6.parallel_env(render_mode="rgb_array", **kwargs)


def pistonball() -> ParallelEnv:
    return pistonball_v6.parallel_env(continuous=False, max_cycles=40)


def kaz(**kwargs: Any) -> ParallelEnv:
    return knights_archers_zombies_v11.parallel_env(**KAZ_KWARGS, **kwargs)


def supersuit_recipe(env: ParallelEnv) -> ParallelEnv:
    """SuperSuit's nearest equivalent of ``ImagePreprocessing(grayscale=True, shape=(84, 84))``."""
    return ss.reshape_v0(ss.resize_v1(ss.color_reduction_v0(env, "full"), 84, 84), (84, 84, 1))


def paired_observations(ours: ParallelEnv, theirs: ParallelEnv, n_steps: int, seed: int = 3
                        ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(ours, theirs) observations of every agent of two same-seed envs under the same seeded random actions, at
    every reset and step; a finished episode is reset with the next seed."""
    rng = np.random.default_rng(0)
    obs_a, _ = ours.reset(seed=seed)
    obs_b, _ = theirs.reset(seed=seed)
    for t in range(n_steps):
        assert set(obs_a) == set(obs_b) and ours.agents == theirs.agents
        for agent in obs_a:
            yield obs_a[agent], obs_b[agent]
        if not ours.agents:
            obs_a, _ = ours.reset(seed=seed + t)
            obs_b, _ = theirs.reset(seed=seed + t)
            continue
        actions = {a: int(rng.integers(ours.action_space(a).n)) for a in ours.agents}  # type: ignore[attr-defined]
        obs_a = ours.step(actions)[0]
        obs_b = theirs.step(actions)[0]


def grey_levels(pairs: Iterator[tuple[np.ndarray, np.ndarray]], shape: tuple[int, ...]) -> np.ndarray:
    """``theirs - ours`` of every pair (``theirs`` reshaped to ``shape``), stacked."""
    diffs = []
    for mine, other in pairs:
        assert mine.shape == shape and mine.dtype == np.uint8 and other.dtype == np.uint8
        diffs.append(other.reshape(shape).astype(np.int16) - mine.astype(np.int16))
    return np.stack(diffs)


# ------------------------------------------------------------------------------------------- color_reduction_v0
def test_color_reduction_v0_equals_opencv_on_pong() -> None:
    theirs = ss.color_reduction_v0(pong(max_cycles=100), "full")
    assert theirs.observation_space("paddle_0") == spaces.Box(0, 255, (280, 480), np.uint8)  # no channel axis
    diff = grey_levels(paired_observations(GrayscaleObservation(pong(max_cycles=100)), theirs, 300), (280, 480, 1))
    assert len(diff) == 2 * 300 and not diff.any()  # black, white and greys: exact


def test_color_reduction_v0_truncates_where_opencv_rounds() -> None:
    diff = grey_levels(paired_observations(GrayscaleObservation(pistonball()), ss.color_reduction_v0(pistonball()),
                                           40), (457, 120, 1))
    assert diff.min() == -1 and diff.max() == 0  # never brighter, one level darker ...
    assert (diff != 0).mean() > 0.9  # ... on almost every pistonball pixel (measured: 98%)
    colours = np.random.default_rng(0).integers(0, 256, (500, 500, 3), dtype=np.uint8)
    luma = colours.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    theirs = color_reduction.change_observation(colours, None, "full") - luma
    ours = cv2.cvtColor(colours, cv2.COLOR_RGB2GRAY) - luma
    assert theirs.mean() == pytest.approx(-0.5, abs=0.01) and np.abs(theirs).max() > 0.99  # floor
    assert abs(ours.mean()) < 0.01 and np.abs(ours).max() <= 0.51  # round to nearest


def test_color_reduction_v0_takes_rgb_only_and_leaves_an_image_state() -> None:
    with pytest.raises(AssertionError, match="last dimension of size 3"):  # a 2-D (or RGBA) image
        ss.color_reduction_v0(ss.color_reduction_v0(pong()))
    theirs, ours = ss.color_reduction_v0(pong()), GrayscaleObservation(pong())
    assert theirs.state_space == spaces.Box(0, 255, (280, 480, 3), np.uint8)  # state() stays RGB
    assert ours.state_space == spaces.Box(0, 255, (280, 480, 1), np.uint8)
    theirs.reset(seed=0)
    assert theirs.state().shape == (280, 480, 3)


# ---------------------------------------------------------------------------------------------------- resize_v1
def test_resize_v1_resamples_bilinearly_not_by_area() -> None:
    ours = ImagePreprocessing(pong(max_cycles=100), grayscale=True, shape=(84, 84))
    diff = grey_levels(paired_observations(ours, supersuit_recipe(pong(max_cycles=100)), 300), (84, 84, 1))
    assert np.abs(diff).max() > 100  # measured: 167 grey levels on the ball and paddle edges
    drift: dict[str, list[float]] = {"area": [], "bilinear": []}  # mean brightness: 84x84 frame - full frame
    ball: dict[str, list[int]] = {"area": [], "bilinear": []}  # brightest pixel away from the paddles: the ball
    env = GrayscaleObservation(pong(max_cycles=100))
    env.reset(seed=3)
    for t in range(300):
        if not env.agents:
            env.reset(seed=t)
        frame = env.step({a: t % 3 for a in env.agents})[0]["paddle_0"]
        box = spaces.Box(0, 255, frame.shape, np.uint8)
        for name, small in (("area", cv2.resize(frame, (84, 84), interpolation=cv2.INTER_AREA)),
                            ("bilinear", resize.change_observation(frame, box, (84, 84, True)))):  # resize_v1's
            drift[name].append(abs(float(small.mean()) - float(frame.mean())))
            ball[name].append(int(small[:, 10:-10].max()))
    assert max(drift["area"]) < 0.01 and max(drift["bilinear"]) > 0.1  # measured: 0.0009 vs 0.16
    assert min(ball["area"]) > 90 and min(ball["bilinear"]) < 50  # measured: 115 vs 31 (of 255)


def test_the_supersuit_recipe_keeps_shapes_and_dtype_but_not_values() -> None:
    ours = ImagePreprocessing(pong(), grayscale=True, shape=(84, 84))
    theirs = supersuit_recipe(pong())
    box = spaces.Box(0, 255, (84, 84, 1), np.uint8)
    assert all(ours.observation_space(a) == theirs.observation_space(a) == box for a in ours.possible_agents)


# ------------------------------------------------------------------------------------------------ frame_stack_v1
def stacked_pairs(env_id: str, hyperparams: dict[str, Any], reference: Callable[[], ParallelEnv], n_steps: int,
                  n_actions: int) -> tuple[list[float], int, bool]:
    """Observations of the team VecEnvs of ``env_id`` (``VecFrameStack`` over the group VecEnvs) and of
    ``frame_stack_v1(reference())`` under the same actions: (max difference per compared observation, number of
    terminal observations compared, whether ``frame_stack_v1`` returned the previous step's array again)."""
    ref = resolve_env(env_id)
    exp = build_experiment(TrainSpec(algo="ppo", env=env_id, hyperparams=hyperparams), ref)
    assert exp.frame_stack == 4
    venvs = make_team_vecs(exp, ref, 1, seed=0)
    stacked = ss.frame_stack_v1(reference(), 4)
    rng = np.random.default_rng(0)
    diffs: list[float] = []
    terminal, reused = 0, False
    try:
        agents = {g: list(v.unwrapped.possible_agents) for g, v in venvs.items()}  # type: ignore[attr-defined]
        last = {g: np.asarray(v.reset()) for g, v in venvs.items()}
        obs, _ = stacked.reset(seed=0)
        for _ in range(n_steps):
            for group, members in agents.items():
                for j, agent in enumerate(members):
                    if agent in stacked.agents:
                        diffs.append(float(np.abs(last[group][j].astype(int) - obs[agent].astype(int)).max()))
            actions = {a: int(rng.integers(n_actions)) for members in agents.values() for a in members}
            for group, venv in venvs.items():
                venv.step_async(np.array([actions[a] for a in agents[group]]))
            results = {group: venv.step_wait() for group, venv in venvs.items()}
            previous = dict(obs)
            obs, _, terms, truncs, _ = stacked.step({a: actions[a] for a in stacked.agents})
            reused = reused or any(obs[a] is previous.get(a) for a in obs)
            for group, (new, _, dones, infos) in results.items():
                for j, agent in enumerate(agents[group]):
                    if dones[j] and agent in obs and infos[j].get(ACTED, True):
                        diffs.append(float(np.abs(infos[j]["terminal_observation"].astype(int)
                                                  - obs[agent].astype(int)).max()))
                        terminal += 1
                last[group] = np.asarray(new)
            if not stacked.agents or all(terms.get(a) or truncs.get(a) for a in stacked.agents):
                obs, _ = stacked.reset()
    finally:
        for venv in venvs.values():
            venv.close()
    return diffs, terminal, reused


def test_frame_stack_v1_equals_vec_frame_stack_but_reuses_its_array() -> None:
    diffs, terminal, reused = stacked_pairs(
        PONG, {"env_kwargs": {"render_mode": "rgb_array", "max_cycles": 60}},
        lambda: ImagePreprocessing(pong(max_cycles=60), grayscale=True, shape=(84, 84)), 200, 3)
    assert len(diffs) > 2 * 200 and terminal >= 6 and max(diffs) == 0
    assert reused  # the observation of step t+1 is the array of step t, overwritten


@pytest.mark.slow
def test_frame_stack_v1_equals_vec_frame_stack_when_agents_die() -> None:
    diffs, terminal, _ = stacked_pairs(
        KAZ, {"env_kwargs": {**KAZ_KWARGS, "max_cycles": 200}, "env_wrapper": [RECIPE], "frame_stack": 4,
              "policy": "CnnPolicy"},
        lambda: ImagePreprocessing(kaz(max_cycles=200), grayscale=True, shape=(84, 84)), 300, 6)
    assert len(diffs) > 600 and terminal >= 4 and max(diffs) == 0


# ---------------------------------------------------------------------------------------- dtype_v0, normalize_obs_v0
def test_dtype_and_normalize_give_observations_sb3_does_not_take_as_images() -> None:
    with pytest.raises(AssertionError):  # normalize_obs_v0 needs float observations: dtype_v0 first
        ss.normalize_obs_v0(pong())
    env = ss.normalize_obs_v0(ss.dtype_v0(supersuit_recipe(pong()), np.float32))
    space = env.observation_space("paddle_0")
    assert space == spaces.Box(0.0, 1.0, (84, 84, 1), np.float32)
    assert not is_image_space(space)  # NatureCNN refuses it; uint8 images are scaled inside CnnPolicy instead
    assert is_image_space(ImagePreprocessing(pong()).observation_space("paddle_0"))


# ------------------------------------------------------------------------------- the parallel -> AEC -> parallel trip
def test_supersuit_observation_wrappers_round_trip_a_parallel_env_unchanged_as_agents_die() -> None:
    raw, tripped = kaz(max_cycles=300), ss.observation_lambda_v0(kaz(max_cycles=300), lambda obs, space: obs)
    assert type(tripped).__name__ == "aec_to_parallel_wrapper"  # no parallel wrapper of its own: via AEC
    raw.reset(seed=1)
    tripped.reset(seed=1)
    rng = np.random.default_rng(0)
    counts = []
    while raw.agents:
        actions = {a: int(rng.integers(6)) for a in raw.agents}
        mine, theirs = raw.step(actions), tripped.step(actions)
        assert [set(part) for part in mine] == [set(part) for part in theirs]
        assert all(np.array_equal(mine[0][a], theirs[0][a]) for a in mine[0])
        assert [dict(part) for part in mine[1:]] == [dict(part) for part in theirs[1:]]
        assert raw.agents == tripped.agents
        counts.append(len(raw.agents))
    assert len(set(counts)) >= 3  # agents died one by one before the end (measured: 4 -> 3 -> 2 -> 0)
