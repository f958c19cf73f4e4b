"""Gymnasium envs (one agent) on Ray RLlib: the env every env runner builds, the algorithm config, and greedy
evaluation episodes with the learned RLModule.

One function builds the env for training, for rebuilding a checkpoint's module (its spaces) and for evaluation
(:func:`build_env`), so the three always see the same observations:

- any registered Gymnasium id (``--gym-packages`` modules imported first, in every env runner);
- ALE ids get RLlib's own Atari preprocessing (``wrap_atari_for_new_api_stack``: 64x64 grey frames scaled to
  [0, 1], a stack of 4, 4 frames per step with a max over the last two, up to 30 no-ops at reset, one life per
  episode, FIRE at reset), the input of RLlib's tuned Atari PPO (``tuned_examples/ppo/atari_ppo.py``);
- observation spaces RLlib's default encoders do not take (``Discrete``, ``Dict``, ``Tuple``, ...) are flattened
  (:class:`gymnasium.wrappers.FlattenObservation`: GridWorld's cell becomes a one-hot vector, a goal env's dict one
  vector), and integer observations become float32 (the encoders' input).

The module acts for RLlib's single agent (``default_agent``) under RLlib's single module id (``default_policy``).
Evaluation plays its episodes with sbagents' one episode runner (:func:`~sbagents.callbacks.episodes.play_episodes`)
and SB3's ``Monitor`` under the Atari preprocessing, so an Atari return is a whole game's score (all lives).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from ray.rllib.core import DEFAULT_AGENT_ID, DEFAULT_MODULE_ID, Columns
from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
from ray.rllib.core.rl_module.rl_module import RLModule
from ray.rllib.env.wrappers.atari_wrappers import wrap_atari_for_new_api_stack
from ray.rllib.utils.spaces.space_utils import clip_action, unsquash_action
from ray.tune.registry import register_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sbagents.callbacks.episodes import episode_metrics_of, play_episodes, stateless, summarize_records
from sbagents.core.env_names import EnvRef, make_registered
from sbagents.core.options import EvaluateOptions
from sbagents.errors import UsageError

#: Module id and agent id of a single-agent run (RLlib's own).
SINGLE_MODULE: str = DEFAULT_MODULE_ID
SINGLE_AGENT: str = str(DEFAULT_AGENT_ID)
#: How a run's Box actions reach the env unless its checkpoint says otherwise: RLlib's defaults of
#: ``normalize_actions`` (unsquash from [-1, 1] to the bounds) and ``clip_actions``.
DEFAULT_ACTIONS: dict[str, bool] = {"normalize": True, "clip": False}
#: Atari preprocessing: frame size and stack (RLlib's own defaults for its tuned Atari examples).
ATARI_DIM, ATARI_STACK = 64, 4
#: Observation spaces RLlib's default encoders build on without flattening.
_NATIVE_OBS = (spaces.Box,)


def build_env(env_id: str, modules: tuple[str, ...] = (), env_kwargs: Mapping[str, Any] | None = None,
              atari: bool = False, monitor: bool = False) -> gym.Env:
    """One env as RLlib's env runners and sbagents' evaluation see it (see the module docstring).

    :param modules: imported first (``--gym-packages``, ``ale_py``, the module of ``module:EnvId``).
    :param atari: apply RLlib's Atari preprocessing.
    :param monitor: wrap SB3's ``Monitor`` around the raw env (evaluation: whole-game returns and lengths).
    :raises UsageError: ``env_kwargs`` the env does not take.
    """
    try:
        env = make_registered(env_id, modules, **dict(env_kwargs or {}))
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid env_kwargs for {env_id}: {exc}".splitlines()[0]) from None
    if monitor:
        env = Monitor(env)
    if atari:
        skip = 4 if int((env.spec.kwargs if env.spec else {}).get("frameskip", 1)) == 1 else 1  # ALE/...-v5 skips
        return wrap_atari_for_new_api_stack(env, dim=ATARI_DIM, frameskip=skip, framestack=ATARI_STACK)
    if not isinstance(env.observation_space, _NATIVE_OBS):
        env = gym.wrappers.FlattenObservation(env)
    if not np.issubdtype(env.observation_space.dtype, np.floating):  # one-hot ints, int Boxes: the encoders take floats
        env = gym.wrappers.DtypeObservation(env, np.float32)
    return env


def make_env(config: Mapping[str, Any]) -> gym.Env:
    """RLlib env creator (runs in every env runner): :func:`build_env` of ``config`` (``env_id``, ``modules``,
    ``env_kwargs``, ``atari``), with ``num_threads`` torch threads in the runner process (<= 0: torch's default)."""
    threads = int(config.get("num_threads", 1))
    if threads > 0 and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return build_env(config["env_id"], tuple(config.get("modules", ())), config.get("env_kwargs") or {},
                     bool(config.get("atari")))


def single_vec_env(ref: EnvRef, env_kwargs: Mapping[str, Any], monitor: bool = False) -> DummyVecEnv:
    """One copy of :func:`build_env` of ``ref`` as a VecEnv (evaluation, recording, export parity)."""
    return DummyVecEnv([lambda: build_env(ref.env_id, ref.modules, env_kwargs, ref.is_atari, monitor)])


def env_spaces(ref: EnvRef, env_kwargs: Mapping[str, Any]) -> tuple[spaces.Space[Any], spaces.Space[Any]]:
    """Observation and action space of the module that acts in ``ref`` (after :func:`build_env`'s wrappers)."""
    env = build_env(ref.env_id, ref.modules, env_kwargs, ref.is_atari)
    try:
        return env.observation_space, env.action_space
    finally:
        env.close()


def build_single_config(config_cls: type[Any], exp: Any, ref: EnvRef, seed: int, num_threads: int = 1
                        ) -> tuple[Any, dict[str, list[str]]]:
    """The RLlib ``AlgorithmConfig`` of the experiment ``exp`` (an :class:`~sbagents.rllib.experiment.RllibExperiment`)
    on the Gymnasium env ``ref``: RLlib's single-agent env runners (``num_env_runners`` of them, each with
    ``num_envs_per_env_runner`` envs in a Gymnasium vector env), one local learner, one RLModule
    (:data:`SINGLE_MODULE`); and the module -> agents mapping of the run."""
    _, action_space = env_spaces(ref, exp.env_kwargs)  # a bad env_kwargs is one line here, before Ray starts
    if not isinstance(action_space, (spaces.Discrete, spaces.Box)):
        raise UsageError(f"--backend rllib trains Gymnasium envs with Discrete or Box actions; {ref.env_id} acts in "
                         f"{action_space}")
    env_name = f"sbagents_{exp.env_id}"
    register_env(env_name, make_env)
    env_config = {"env_id": ref.env_id, "modules": list(ref.modules), "env_kwargs": exp.env_kwargs,
                  "num_threads": num_threads, "atari": ref.is_atari}
    config = (
        config_cls()
        .environment(env_name, env_config=env_config, **exp.environment)
        .env_runners(**{"num_env_runners": 2, **exp.env_runners})
        .learners(num_learners=0)
        .training(**exp.training)
        .rl_module(model_config=DefaultModelConfig(**exp.model))
        .debugging(seed=seed, log_level="ERROR")
    )
    return config, {SINGLE_MODULE: [SINGLE_AGENT]}


def greedy_actions(module: RLModule, obs: torch.Tensor) -> torch.Tensor:
    """The module's greedy actions for observations ``(batch, *obs_shape)``: its own ``actions`` output (DQN's
    argmax), else its inference distribution's deterministic action (a Categorical's argmax, a Gaussian's mean), as
    RLlib's env runner takes them, before the env's action bounds (``(batch,)`` indices or ``(batch, act_dim)``)."""
    out = module.forward_inference({Columns.OBS: obs})
    if Columns.ACTIONS in out:
        return out[Columns.ACTIONS]  # type: ignore[no-any-return]
    dist = module.get_inference_action_dist_cls().from_logits(out[Columns.ACTION_DIST_INPUTS])
    return dist.to_deterministic().sample()  # type: ignore[no-any-return]


def module_policy(module: RLModule, action_space: spaces.Space[Any], deterministic: bool = True,
                  actions: Mapping[str, bool] | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """``obs batch (n_envs, *obs_shape) -> actions (n_envs, *action_shape)`` of an RLModule, as RLlib's env runner
    acts: greedy (the distribution's deterministic action, or the module's own ``actions`` output, e.g. DQN's
    argmax) or sampled (DQN's modules act greedily either way); Box actions unsquashed from [-1, 1] to the
    space's bounds (``actions["normalize"]``) or clipped to them (``actions["clip"]``), as RLlib's module-to-env
    pipeline does (the run's settings: :func:`~sbagents.rllib.checkpoints.action_settings`; default
    :data:`DEFAULT_ACTIONS`)."""
    settings = {**DEFAULT_ACTIONS, **(actions or {})}
    normalize_actions, clip_actions = settings["normalize"], settings["clip"]
    if not deterministic and "t" in inspect.signature(module._forward_exploration).parameters:
        deterministic = True  # DQN explores by its training's epsilon schedule (step t): it has nothing to sample
    dist_cls = module.get_exploration_action_dist_cls()

    def act(obs: np.ndarray) -> np.ndarray:
        batch = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        with torch.no_grad():
            if deterministic:
                actions = greedy_actions(module, batch)
            else:
                out = module.forward_exploration({Columns.OBS: batch})
                actions = dist_cls.from_logits(out[Columns.ACTION_DIST_INPUTS]).sample()
        found = np.asarray(actions.numpy())
        if isinstance(action_space, spaces.Box):
            found = np.asarray(unsquash_action(found, action_space) if normalize_actions else
                               clip_action(found, action_space) if clip_actions else found,
                               dtype=action_space.dtype)
        return found

    return act


def evaluate_single(module: RLModule, ref: EnvRef, env_kwargs: Mapping[str, Any], algo: str,
                    options: EvaluateOptions, actions: Mapping[str, bool] | None = None) -> dict[str, Any]:
    """Play ``options.n_episodes`` episodes of ``ref`` with ``module`` (greedy unless ``options`` says to sample)
    and summarize them as every sbagents evaluation (``evaluate --json``'s keys).

    :param actions: the run's ``normalize`` / ``clip`` action settings (RLlib's ``normalize_actions`` and
        ``clip_actions``; default: :data:`DEFAULT_ACTIONS`).
    """
    kwargs = dict(env_kwargs)
    if options.render:
        kwargs["render_mode"] = "human"
    venv = single_vec_env(ref, kwargs, monitor=True)
    try:
        if options.seed is not None:
            torch.manual_seed(options.seed)  # sampled actions (not greedy) repeat for a seed
        actor = module_policy(module, venv.action_space, options.greedy(), actions)
        records = play_episodes(venv, stateless(actor), options.n_episodes, options.seed, monitor_episodes=True,
                                episode_metrics=episode_metrics_of(venv))
    finally:
        venv.close()
    return {"env": ref.env_id, "algo": algo, **summarize_records(records)}
