"""Adversarial rollouts for off-policy actor-critics: a share of training steps act on attacked observations.

The baseline of ``--robust adv:EPS`` (issue 19): while collecting experience, each env's step is, with probability
``adv_share``, chosen from the observation perturbed by an attack of :mod:`sbagents.callbacks.attacks` (``pgd`` by
default, any of ``fgsm``/``pgd``/``critic``/``uniform``/``gaussian``) against the current policy. Only the action
changes: the replay buffer keeps the true observations (SB3 stores ``_last_obs`` / ``_last_original_obs``, which
are restored before the transition is stored), so the critic learns the true dynamics of acting on misread states.
``eps`` is in the attacks' units and ramps linearly from 0 over the first ``adv_ramp_fraction`` of training, like
the SA regularizer's. No step is attacked before ``learning_starts`` (those actions are uniform random anyway).

Usable from plain SB3 code::

    from sbagents.robust import AdvTD3

    model = AdvTD3("MlpPolicy", "Pendulum-v1", adv_eps=0.2, adv_attack="pgd", adv_share=0.5)
    model.learn(10_000)
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sbagents.callbacks.attacks import AttackSpec, ObservationAttacker
from sbagents.robust.sa_regularizer import SADDPG, SATD3, ramped_eps

#: Attacks an adversarial rollout can use (``none`` would be plain training).
ROLLOUT_ATTACKS: tuple[str, ...] = ("pgd", "fgsm", "critic", "uniform", "gaussian")

if TYPE_CHECKING:
    _Base = OffPolicyAlgorithm  # the mixin's host, for type checking only
else:
    _Base = object


class AdversarialRollouts(_Base):
    """Mixin for SB3 off-policy algorithms (``class AdvTD3(AdversarialRollouts, TD3)``): overrides
    ``_sample_action`` so that a share of the collection steps act on attacked observations.

    :param adv_eps: final attack radius (attack units: VecNormalize stds, else the Box range).
    :param adv_attack: attack name (:data:`ROLLOUT_ATTACKS`), with its default steps / step size.
    :param adv_share: probability that an env's step acts on the attacked observation.
    :param adv_ramp_fraction: fraction of training over which eps ramps linearly from 0.
    Other arguments go to the algorithm. Logs ``robust/adv_eps`` and ``robust/adv_share`` (attacked share of this
    run's steps after ``learning_starts``).
    """

    def __init__(
        self,
        *args: Any,
        adv_eps: float = 0.1,
        adv_attack: str = "pgd",
        adv_share: float = 0.5,
        adv_ramp_fraction: float = 0.5,
        **kwargs: Any,
    ) -> None:
        AttackSpec(adv_attack, adv_eps)  # ValueError for a bad name / eps
        if adv_attack not in ROLLOUT_ATTACKS:
            raise ValueError(f"adv_attack must be one of {', '.join(ROLLOUT_ATTACKS)}, got {adv_attack!r}")
        if not 0.0 <= adv_share <= 1.0 or not 0.0 <= adv_ramp_fraction <= 1.0:
            raise ValueError(f"adv_share and adv_ramp_fraction must be in [0, 1], got {adv_share}, {adv_ramp_fraction}")
        self.adv_eps, self.adv_attack, self.adv_share = float(adv_eps), adv_attack, float(adv_share)
        self.adv_ramp_fraction = float(adv_ramp_fraction)
        self._adv_attacker: ObservationAttacker | None = None
        self._adv_target: tuple[Any, Any] | None = None  # (policy, env) the attacker was built for
        self._adv_rng: np.random.Generator | None = None
        self._adv_counts = [0, 0]  # attacked, all env steps after learning_starts
        super().__init__(*args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_adv_attacker", "_adv_target", "_adv_rng", "_adv_counts"]

    def adv_eps_now(self) -> float:
        """The scheduled radius at the current training progress."""
        progress = self._current_progress_remaining
        return ramped_eps(self.adv_eps, self.adv_ramp_fraction, progress)

    def attacked_observations(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``obs`` (the policy's input batch, ``(n_envs, *obs_shape)``) with the attacked rows replaced.

        :return: ``(observations, attacked)``: same shape and dtype as ``obs``, and the ``(n_envs,)`` bool mask of the
            rows drawn for the attack (all False at eps 0).
        """
        env = self.env
        assert env is not None  # rollouts are collected from the model's env
        target = (self.policy, env)
        if self._adv_attacker is None or self._adv_target is None or any(
            a is not b for a, b in zip(target, self._adv_target, strict=True)
        ):
            if not isinstance(self.policy.observation_space, spaces.Box):
                raise ValueError("adversarial rollouts need a Box observation space")
            attack, seed = AttackSpec(self.adv_attack, self.adv_eps), self.seed
            self._adv_attacker = ObservationAttacker(target[0], target[1], attack, seed)
            self._adv_target, self._adv_rng = target, np.random.default_rng(seed)
        assert self._adv_rng is not None
        eps = self.adv_eps_now()
        attacked = self._adv_rng.random(len(obs)) < self.adv_share
        if eps == 0 or not attacked.any():
            return obs, np.zeros(len(obs), dtype=bool)
        attacker = self._adv_attacker
        attacker.attack = dataclasses.replace(attacker.attack, eps=eps)
        x = th.as_tensor(obs[attacked], dtype=th.float32, device=attacker.device)
        out = obs.copy()
        out[attacked] = attacker.perturb(x).cpu().numpy().astype(obs.dtype)
        return out, attacked

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.num_timesteps < learning_starts or self.adv_share == 0:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        true_obs = self._last_obs
        assert isinstance(true_obs, np.ndarray), "adversarial rollouts need a Box observation space"
        obs, attacked = self.attacked_observations(true_obs)
        self._adv_counts[0] += int(attacked.sum())
        self._adv_counts[1] += len(attacked)
        self.logger.record("robust/adv_eps", self.adv_eps_now())
        self.logger.record("robust/adv_share", self._adv_counts[0] / self._adv_counts[1])
        self._last_obs = obs
        try:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        finally:
            self._last_obs = true_obs  # what the replay buffer stores


class AdvTD3(AdversarialRollouts, TD3):
    """TD3 with adversarial rollouts (:class:`AdversarialRollouts`)."""


class AdvDDPG(AdversarialRollouts, DDPG):
    """DDPG with adversarial rollouts (:class:`AdversarialRollouts`)."""


class AdvSAC(AdversarialRollouts, SAC):
    """SAC with adversarial rollouts (:class:`AdversarialRollouts`; attacks act on the deterministic action)."""


class SAAdvTD3(AdversarialRollouts, SATD3):
    """TD3 with both the SA regularizer (:class:`~sbagents.robust.sa_regularizer.SATD3`) and adversarial rollouts."""


class SAAdvDDPG(AdversarialRollouts, SADDPG):
    """DDPG with both the SA regularizer (:class:`~sbagents.robust.sa_regularizer.SADDPG`) and adversarial rollouts."""

