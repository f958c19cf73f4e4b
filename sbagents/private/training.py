"""DP training in ``python -m sbagents.train`` (``--dp-epsilon`` / ``--dp-noise``): options, checks, and wiring.

Everything that reads the training data goes through the noisy steps: the replay buffer (off-policy) or the rollout
buffer (PPO, A2C) draws Poisson batches, the networks take DP-SGD steps, and observation normalization
(``normalize`` in the config) uses fixed statistics from the observation bounds instead of running statistics of
the data (which would leak). PPO's advantage normalization (statistics of the minibatch) is turned off unless the
config asks for it, which is refused, as are ``target_kl`` (early stopping on the batch) and gSDE.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sbagents.core.experiment import Experiment
from sbagents.errors import UsageError
from sbagents.private.dp_sgd import OFF_POLICY_DP_ALGOS
from sbagents.private.options import PrivacyOptions


def check_dp_experiment(options: PrivacyOptions, exp: Experiment, resuming: bool) -> None:
    """Refuse, in one line, what DP training cannot do with this experiment (before a run dir exists), beyond the
    algorithms and env kinds of :data:`~sbagents.private.options.DP_TRAINING`, which
    :func:`sbagents.extensions.prepare_extensions` checked first."""
    if resuming:
        raise UsageError("-i with DP training: the privacy already spent is not in the model file; train anew")
    if exp.algo not in OFF_POLICY_DP_ALGOS:
        check_on_policy_experiment(options, exp)
        return
    if exp.algo == "sac" and str(exp.algo_kwargs.get("ent_coef", "auto")).startswith("auto"):
        raise UsageError("DP training with sac needs a fixed ent_coef (e.g. -params ent_coef:0.05): the automatic "
                         "one is tuned on the batch without noise")
    if exp.algo_kwargs.get("optimize_memory_usage"):
        raise UsageError("DP training does not support optimize_memory_usage")
    transitions = min(int(exp.algo_kwargs.get("buffer_size", 1_000_000)), exp.n_timesteps)
    if options.delta >= 1 / transitions:
        raise UsageError(f"--dp-delta {options.delta:g} must be below 1 / {transitions:,} (the transitions trained "
                         f"on), e.g. {10 ** math.floor(math.log10(0.1 / transitions)):g}")
    freq = exp.algo_kwargs.get("train_freq")
    if options.epsilon is not None and isinstance(freq, list | tuple) and len(freq) == 2 and freq[1] != "step":
        # calibrating the noise and stopping at the budget both plan the run's draws, which needs steps
        raise UsageError("--dp-epsilon plans the run's batches, which needs train_freq in steps, not episodes; give "
                         "--dp-noise alone or train_freq in steps")


def check_on_policy_experiment(options: PrivacyOptions, exp: Experiment) -> None:
    """The checks of :func:`check_dp_experiment` for PPO and A2C."""
    kwargs = exp.algo_kwargs
    if kwargs.get("target_kl") is not None:
        raise UsageError("DP training cannot use target_kl: its early stopping reads the batch without noise; "
                         "drop it (-params target_kl:null)")
    if kwargs.get("normalize_advantage"):
        raise UsageError("DP training needs normalize_advantage: false (normalizing over the minibatch makes one "
                         "transition's loss depend on the others)")
    if kwargs.get("use_sde"):
        raise UsageError("DP training does not support use_sde (gSDE's exploration weights are not per-sample)")
    if exp.policy == "MultiInputPolicy":
        raise UsageError("DP training with ppo/a2c needs MlpPolicy or CnnPolicy (no dict observations)")
    if options.delta >= 1 / exp.n_timesteps:
        raise UsageError(f"--dp-delta {options.delta:g} must be below 1 / {exp.n_timesteps:,} (the transitions "
                         f"trained on), e.g. {10 ** math.floor(math.log10(0.1 / exp.n_timesteps)):g}")


def private_experiment(exp: Experiment) -> Experiment:
    """``exp`` with the buffer that draws Poisson batches (and, for PPO, no advantage normalization)."""
    if exp.algo in OFF_POLICY_DP_ALGOS:
        from sbagents.private.replay import PoissonReplayBuffer

        return dataclasses.replace(exp, algo_kwargs={**exp.algo_kwargs, "replay_buffer_class": PoissonReplayBuffer})
    from sbagents.private.rollout import PoissonRolloutBuffer

    algo_kwargs = {**exp.algo_kwargs, "rollout_buffer_class": PoissonRolloutBuffer}
    if exp.algo == "ppo":  # SB3's default is True; recorded in config.yml
        algo_kwargs["normalize_advantage"] = False
        return dataclasses.replace(exp, algo_kwargs=algo_kwargs,
                                   hyperparams={**exp.hyperparams, "normalize_advantage": False})
    return dataclasses.replace(exp, algo_kwargs=algo_kwargs)


def freeze_normalization(venv: VecEnv) -> VecEnv:
    """A :class:`VecNormalize` of the training env with statistics from the observation bounds, never updated:
    observations are scaled to [-1, 1] without reading the data; rewards are left unscaled.

    :raises UsageError: an unbounded observation space (no data-free statistics).
    """
    if not isinstance(venv, VecNormalize) or not venv.norm_obs:
        return venv
    space = venv.observation_space
    low, high = np.asarray(getattr(space, "low", -np.inf)), np.asarray(getattr(space, "high", np.inf))
    if not (np.isfinite(low).all() and np.isfinite(high).all()):
        raise UsageError("DP training with normalize needs a bounded observation space (the statistics come from "
                         "its bounds, not the data); set normalize: false")
    rms: Any = venv.obs_rms
    rms.mean = ((low + high) / 2).astype(np.float64)
    rms.var = (np.maximum((high - low) / 2, 1e-8) ** 2).astype(np.float64)
    venv.norm_reward = False
    venv.training = False
    return venv


def make_dp_callback(model: BaseAlgorithm, options: PrivacyOptions, n_timesteps: int) -> Any:
    """Make ``model`` private and return the :class:`~sbagents.private.callback.DPCallback` that reports it."""
    from sbagents.private.callback import DPCallback
    from sbagents.private.dp_sgd import make_private

    check_rollout_budget(model, options, n_timesteps)
    try:
        dp = make_private(model, options.clip, options.noise,
                          options.epsilon if options.noise is None else None, options.delta, n_timesteps)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    dp.target_epsilon = options.epsilon
    return DPCallback(dp, stop_at=options.epsilon if options.noise is not None else None,
                      total_timesteps=n_timesteps)


def check_rollout_budget(model: BaseAlgorithm, options: PrivacyOptions, n_timesteps: int) -> None:
    """On-policy, ``--dp-noise`` with ``--dp-epsilon``: every rollout spends the same epsilon, so a noise that passes
    the budget in one rollout would stop before the first update; refused in one line, with the noise that fits."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    from sbagents.private.accounting import noise_for_epsilon
    from sbagents.private.dp_sgd import exposure_draws, planned_epsilon

    if options.noise is None or options.epsilon is None or not isinstance(model, OnPolicyAlgorithm):
        return
    spent = planned_epsilon(model, n_timesteps, options.noise, options.delta)
    if spent > options.epsilon:
        needed = noise_for_epsilon(exposure_draws(model, n_timesteps), options.epsilon, options.delta)
        raise UsageError(f"--dp-noise {options.noise:g} spends epsilon {spent:.2f} per rollout, above --dp-epsilon "
                         f"{options.epsilon:g}: give --dp-noise {math.ceil(needed * 100) / 100:g} or more, or "
                         "--dp-epsilon alone")
