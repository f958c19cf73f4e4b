"""State-adversarial (SA) regularization for TD3 / DDPG (SA-DDPG, Zhang et al., NeurIPS 2020).

The actor loss gets the penalty ``kappa * E_s max_{|s~ - s| <= eps * scale} ||pi(s~) - pi(s)||^2``; the inner max
is approximated by PGD (random start in the L-inf ball, ``pgd_steps`` signed steps of ``2 eps scale / pgd_steps``,
projection onto the ball). ``eps`` ramps linearly from 0 to its final value over the first ``ramp_fraction`` of
training (``1 - progress_remaining``).

Units follow :mod:`sbagents.callbacks.attacks`: the regularized input is the actor's input (the VecNormalize-
normalized observation when ``norm_obs``, scale 1 per component, i.e. ``eps`` in running-std units; otherwise the raw
Box observation with scale ``high - low`` where finite, 1 where not), so a model trained with ``sa_eps=0.2`` is
regularized against the ball that ``--attack "pgd:0.2"`` searches. Unlike the attacks, perturbed points are not
clipped to the Box / ``clip_obs`` bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import DDPG, TD3
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.common import find_vec_normalize

Actor = Callable[[th.Tensor], th.Tensor]


def sa_scale(env: VecEnv | gym.Env) -> np.ndarray:
    """Per-component scale of the actor's input, as in ``ObservationAttacker`` (:mod:`sbagents.callbacks.attacks`).

    :param env: the training env (a VecEnv, possibly wrapped in ``VecNormalize``, or a Gymnasium env).
    :return: ``obs_shape`` float32 array: ones under ``VecNormalize(norm_obs=True)``, else ``high - low`` of the Box
        where both bounds are finite and 1 elsewhere.
    :raises ValueError: for non-Box observation spaces.
    """
    space = env.observation_space
    vn = find_vec_normalize(env) if isinstance(env, VecEnv) else None
    if vn is not None and vn.norm_obs:
        return np.ones_like(_box_scale(space))
    return _box_scale(space)


class SARegularizer:
    """The SA penalty ``kappa * mean_b max_{s~ in B(s_b)} ||pi(s~) - pi(s_b)||^2`` (PGD inner max).

    :param eps: final L-inf radius, relative to ``scale`` (the ball is ``|s~ - s| <= eps * scale`` per component).
    :param kappa: penalty weight.
    :param pgd_steps: PGD steps (step size ``2 eps scale / pgd_steps``).
    :param ramp_fraction: fraction of training over which eps ramps linearly from 0 to ``eps`` (0: no ramp).
    :param scale: ``obs_shape`` tensor in the actor's input units (None: 1 everywhere).
    :param generator: random numbers of the PGD random start (None: torch's global generator).
    """

    def __init__(
        self,
        eps: float,
        kappa: float = 1.0,
        pgd_steps: int = 5,
        ramp_fraction: float = 0.5,
        scale: th.Tensor | None = None,
        generator: th.Generator | None = None,
    ) -> None:
        if not (np.isfinite(eps) and eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {eps}")
        if pgd_steps < 1:
            raise ValueError(f"pgd_steps must be >= 1, got {pgd_steps}")
        if not 0.0 <= ramp_fraction <= 1.0:
            raise ValueError(f"ramp_fraction must be in [0, 1], got {ramp_fraction}")
        self.eps, self.kappa, self.pgd_steps, self.ramp_fraction = float(eps), float(kappa), pgd_steps, ramp_fraction
        self.scale, self.generator = scale, generator

    def eps_at(self, progress_remaining: float) -> float:
        """Scheduled radius: ``eps * min(1, (1 - progress_remaining) / ramp_fraction)`` (SB3's progress, 1 -> 0)."""
        if self.ramp_fraction == 0:
            return self.eps
        return self.eps * min(1.0, max(0.0, 1.0 - progress_remaining) / self.ramp_fraction)

    def _radius(self, obs: th.Tensor, eps: float) -> th.Tensor:
        scale = th.ones_like(obs[0]) if self.scale is None else self.scale.to(obs.device, obs.dtype)
        return eps * scale.expand_as(obs)

    def perturb(self, actor: Actor, obs: th.Tensor, eps: float) -> th.Tensor:
        """PGD approximation of ``argmax_{s~ in B(s)} ||pi(s~) - pi(s)||^2`` per sample.

        :param actor: maps ``(batch, *obs_shape)`` observations to ``(batch, act_dim)`` actions.
        :param obs: ``(batch, *obs_shape)`` actor inputs (already preprocessed / normalized).
        :param eps: radius relative to ``scale``.
        :return: ``(batch, *obs_shape)`` detached perturbed observations with ``|s~ - s| <= eps * scale``.
        """
        x = obs.detach()
        radius = self._radius(x, eps)
        with th.no_grad():
            ref = actor(x)
        noise = th.rand(x.shape, generator=self.generator, dtype=x.dtype).to(x.device) * 2 - 1
        xa = x + noise * radius
        step = 2.0 * radius / self.pgd_steps
        for _ in range(self.pgd_steps):
            xa = xa.detach().requires_grad_(True)
            (grad,) = th.autograd.grad((actor(xa) - ref).pow(2).sum(), xa)
            xa = th.max(th.min(xa.detach() + step * grad.sign(), x + radius), x - radius)
        return xa.detach()

    def __call__(self, actor: Actor, obs: th.Tensor, progress_remaining: float = 0.0) -> th.Tensor:
        """The penalty (scalar tensor, differentiable w.r.t. the actor's parameters through both ``pi(s~)`` and
        ``pi(s)``) at the scheduled radius ``eps_at(progress_remaining)``; exactly 0 when that radius is 0.

        :param obs: ``(batch, *obs_shape)`` actor inputs.
        """
        eps = self.eps_at(progress_remaining)
        if eps == 0 or self.kappa == 0:
            return th.zeros((), device=obs.device)
        xa = self.perturb(actor, obs, eps)
        return self.kappa * (actor(xa) - actor(obs)).pow(2).sum(dim=-1).mean()


class SATD3(TD3):
    """TD3 with the SA penalty added to the actor loss of each delayed actor update.

    SB3's ``TD3.train`` is not copied: while it runs, a forward hook on ``self.actor`` records its latest input
    (the replay batch of the actor loss) and a step pre-hook on the actor optimizer back-propagates the penalty on
    that batch before the step, so the step uses the gradient of ``actor_loss + penalty``. Logs ``robust/sa_penalty``
    (mean over the train call's actor updates) and ``robust/eps``.

    :param sa_eps: final radius (relative to ``sa_scale``); ``sa_kappa``, ``sa_pgd_steps``, ``sa_ramp_fraction``: see
        :class:`SARegularizer`.
    :param sa_scale: ``obs_shape`` scale (None: :func:`sa_scale` of the env, falling back to the observation Box
        range without an env); saved with the model.
    Other arguments go to :class:`~stable_baselines3.TD3`.
    """

    def __init__(
        self,
        *args: Any,
        sa_eps: float = 0.1,
        sa_kappa: float = 1.0,
        sa_pgd_steps: int = 5,
        sa_ramp_fraction: float = 0.5,
        sa_scale: np.ndarray | None = None,
        **kwargs: Any,
    ) -> None:
        self.sa_eps, self.sa_kappa, self.sa_pgd_steps = sa_eps, sa_kappa, sa_pgd_steps
        self.sa_ramp_fraction = sa_ramp_fraction
        self.sa_scale = None if sa_scale is None else np.asarray(sa_scale, dtype=np.float32)
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.sa_scale is None:
            self.sa_scale = sa_scale(self.env) if self.env is not None else _box_scale(self.observation_space)
        scale = th.as_tensor(self.sa_scale, dtype=th.float32, device=self.device)
        self.sa_regularizer = SARegularizer(self.sa_eps, self.sa_kappa, self.sa_pgd_steps, self.sa_ramp_fraction, scale)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "sa_regularizer"]

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        last_obs: list[th.Tensor] = []
        penalties: list[float] = []

        def record_input(_module: th.nn.Module, inputs: tuple[Any, ...]) -> None:
            last_obs[:] = [inputs[0]]

        def add_penalty(*_: Any) -> None:
            if not last_obs:
                return
            obs = last_obs.pop()
            with th.enable_grad():
                penalty = self.sa_regularizer(self.actor, obs, self._current_progress_remaining)
                if penalty.requires_grad:
                    penalty.backward()
            last_obs.clear()  # the penalty's own actor calls
            penalties.append(float(penalty.item()))

        handles = [
            self.actor.register_forward_pre_hook(record_input),
            self.actor.optimizer.register_step_pre_hook(add_penalty),
        ]
        try:
            super().train(gradient_steps, batch_size)
        finally:
            for handle in handles:
                handle.remove()
        if penalties:
            self.logger.record("robust/sa_penalty", float(np.mean(penalties)))
        self.logger.record("robust/eps", self.sa_regularizer.eps_at(self._current_progress_remaining))


class SADDPG(SATD3, DDPG):
    """DDPG (SB3's TD3 with one critic, no target smoothing, ``policy_delay=1``) with the SA penalty; see
    :class:`SATD3` (an ``SADDPG`` is also an ``SATD3``)."""


def _box_scale(space: spaces.Space) -> np.ndarray:
    """``high - low`` of a Box where finite, 1 elsewhere (float32, ``obs_shape``)."""
    if not isinstance(space, spaces.Box):
        raise ValueError(f"SA regularization needs a Box observation space, not {type(space).__name__}")
    finite = np.isfinite(space.low) & np.isfinite(space.high)
    return np.where(finite, space.high - space.low, 1.0).astype(np.float32)
