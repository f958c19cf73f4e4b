"""State-adversarial (SA) regularization for TD3 / DDPG (SA-DDPG, Zhang et al., NeurIPS 2020).

The actor loss gets the penalty ``kappa * E_s max_{|s~ - s| <= eps * scale} ||pi(s~) - pi(s)||^2``; the inner max
is approximated by PGD (random start in the L-inf ball, ``pgd_steps`` signed steps of ``2 eps scale / pgd_steps``,
projection onto the ball). Optionally (``critic_weight`` > 0) a critic-aware term in the spirit of the critic attack
of :mod:`sbagents.callbacks.attacks`: ``critic_weight * E_s [Q(s, pi(s)) - min_{s~} Q(s, pi(s~))]`` (the value the
worst nearby observation costs; ``Q(s, pi(s))`` is detached, so the term trains the actor to act well on ``s~``).
``eps`` ramps linearly from 0 to its final value over the first ``ramp_fraction`` of training
(``1 - progress_remaining``).

Units follow :mod:`sbagents.callbacks.attacks`: the regularized input is the actor's input (the VecNormalize-
normalized observation when ``norm_obs``, scale 1 per component, i.e. ``eps`` in running-std units; otherwise the raw
Box observation with scale ``high - low`` where finite, 1 where not), so a model trained with ``sa_eps=0.2`` is
regularized against the ball that ``--attack "pgd:0.2"`` searches. Unlike the attacks, perturbed points are not
clipped to the Box / ``clip_obs`` bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import DDPG, TD3

from sbagents.callbacks.attacks import observation_scale

Actor = Callable[[th.Tensor], th.Tensor]
Critic = Callable[[th.Tensor, th.Tensor], th.Tensor]


def ramped_eps(eps: float, ramp_fraction: float, progress_remaining: float) -> float:
    """``eps * min(1, (1 - progress_remaining) / ramp_fraction)``: a linear ramp from 0 over the first
    ``ramp_fraction`` of training (SB3's ``progress_remaining`` goes 1 -> 0; ``ramp_fraction`` 0: no ramp)."""
    if ramp_fraction == 0:
        return eps
    return eps * min(1.0, max(0.0, 1.0 - progress_remaining) / ramp_fraction)


class SARegularizer:
    """The SA penalty ``kappa * mean_b max_{s~ in B(s_b)} ||pi(s~) - pi(s_b)||^2`` (PGD inner max).

    :param eps: final L-inf radius, relative to ``scale`` (the ball is ``|s~ - s| <= eps * scale`` per component).
    :param kappa: penalty weight.
    :param pgd_steps: PGD steps (step size ``2 eps scale / pgd_steps``).
    :param ramp_fraction: fraction of training over which eps ramps linearly from 0 to ``eps`` (0: no ramp).
    :param scale: ``obs_shape`` tensor in the actor's input units (None: 1 everywhere).
    :param generator: random numbers of the PGD random start (None: torch's global generator).
    :param critic_weight: weight of the critic-aware term (0: none; it needs ``critic`` in :meth:`__call__`).
    """

    def __init__(
        self,
        eps: float,
        kappa: float = 1.0,
        pgd_steps: int = 5,
        ramp_fraction: float = 0.5,
        scale: th.Tensor | None = None,
        generator: th.Generator | None = None,
        critic_weight: float = 0.0,
    ) -> None:
        if not (np.isfinite(eps) and eps >= 0):
            raise ValueError(f"eps must be a finite number >= 0, got {eps}")
        if pgd_steps < 1:
            raise ValueError(f"pgd_steps must be >= 1, got {pgd_steps}")
        if not 0.0 <= ramp_fraction <= 1.0:
            raise ValueError(f"ramp_fraction must be in [0, 1], got {ramp_fraction}")
        if not (np.isfinite(critic_weight) and critic_weight >= 0):
            raise ValueError(f"critic_weight must be a finite number >= 0, got {critic_weight}")
        self.eps, self.kappa, self.pgd_steps, self.ramp_fraction = float(eps), float(kappa), pgd_steps, ramp_fraction
        self.scale, self.generator, self.critic_weight = scale, generator, float(critic_weight)

    def eps_at(self, progress_remaining: float) -> float:
        """Scheduled radius (:func:`ramped_eps`)."""
        return ramped_eps(self.eps, self.ramp_fraction, progress_remaining)

    def _radius(self, obs: th.Tensor, eps: float) -> th.Tensor:
        scale = th.ones_like(obs[0]) if self.scale is None else self.scale.to(obs.device, obs.dtype)
        return eps * scale.expand_as(obs)

    def perturb(
        self, actor: Actor, obs: th.Tensor, eps: float, objective: Callable[[th.Tensor], th.Tensor] | None = None
    ) -> th.Tensor:
        """PGD approximation of ``argmax_{s~ in B(s)} ||pi(s~) - pi(s)||^2`` (or of ``objective``) per sample.

        :param actor: maps ``(batch, *obs_shape)`` observations to ``(batch, act_dim)`` actions.
        :param obs: ``(batch, *obs_shape)`` actor inputs (already preprocessed / normalized).
        :param eps: radius relative to ``scale``.
        :param objective: ``(batch, *obs_shape)`` -> ``(batch,)`` values to maximize (None: the action distance).
        :return: ``(batch, *obs_shape)`` detached perturbed observations with ``|s~ - s| <= eps * scale``.
        """
        x = obs.detach()
        radius = self._radius(x, eps)
        if objective is None:
            with th.no_grad():
                ref = actor(x)

            def objective(xa: th.Tensor) -> th.Tensor:
                return (actor(xa) - ref).pow(2).sum(dim=-1)

        noise = th.rand(x.shape, generator=self.generator, dtype=x.dtype).to(x.device) * 2 - 1
        xa = x + noise * radius
        step = 2.0 * radius / self.pgd_steps
        for _ in range(self.pgd_steps):
            xa = xa.detach().requires_grad_(True)
            (grad,) = th.autograd.grad(objective(xa).sum(), xa)
            xa = th.max(th.min(xa.detach() + step * grad.sign(), x + radius), x - radius)
        return xa.detach()

    def __call__(
        self, actor: Actor, obs: th.Tensor, progress_remaining: float = 0.0, critic: Critic | None = None
    ) -> th.Tensor:
        """The penalty (scalar tensor, differentiable w.r.t. the actor's parameters through both ``pi(s~)`` and
        ``pi(s)``) at the scheduled radius ``eps_at(progress_remaining)``; exactly 0 when that radius is 0.

        :param obs: ``(batch, *obs_shape)`` actor inputs.
        :param critic: ``(obs, action) -> (batch, 1)`` Q-values, for the critic-aware term (None: no such term).
        """
        eps = self.eps_at(progress_remaining)
        penalty = th.zeros((), device=obs.device)
        if eps == 0:
            return penalty
        if self.kappa != 0:
            xa = self.perturb(actor, obs, eps)
            penalty = self.kappa * (actor(xa) - actor(obs)).pow(2).sum(dim=-1).mean()
        if self.critic_weight != 0 and critic is not None:
            x = obs.detach()
            xq = self.perturb(actor, x, eps, lambda xa: -critic(x, actor(xa)).sum(dim=-1))
            with th.no_grad():
                clean = critic(x, actor(x))
            penalty = penalty + self.critic_weight * (clean - critic(x, actor(xq))).mean()
        return penalty


class SATD3(TD3):
    """TD3 with the SA penalty added to the actor loss of each delayed actor update.

    SB3's ``TD3.train`` is not copied: while it runs, a forward hook on ``self.actor`` records its latest input
    (the replay batch of the actor loss) and a step pre-hook on the actor optimizer back-propagates the penalty on
    that batch before the step, so the step uses the gradient of ``actor_loss + penalty``. Logs ``robust/sa_penalty``
    (mean over the train call's actor updates) and ``robust/eps``.

    :param sa_eps: final radius (relative to ``sa_scale``); ``sa_kappa``, ``sa_pgd_steps``, ``sa_ramp_fraction``,
        ``sa_critic_weight`` (the critic-aware term, on the first critic ``Q1``): see :class:`SARegularizer`.
    :param sa_scale: ``obs_shape`` scale (None: :func:`~sbagents.callbacks.attacks.observation_scale` of the
        observation space and env, the Box range without an env); saved with the model.
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
        sa_critic_weight: float = 0.0,
        **kwargs: Any,
    ) -> None:
        self.sa_eps, self.sa_kappa, self.sa_pgd_steps = sa_eps, sa_kappa, sa_pgd_steps
        self.sa_ramp_fraction, self.sa_critic_weight = sa_ramp_fraction, sa_critic_weight
        self.sa_scale = None if sa_scale is None else np.asarray(sa_scale, dtype=np.float32)
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.sa_scale is None:
            self.sa_scale = observation_scale(self.observation_space, self.env)
        scale = th.as_tensor(self.sa_scale, dtype=th.float32, device=self.device)
        self.sa_regularizer = SARegularizer(self.sa_eps, self.sa_kappa, self.sa_pgd_steps, self.sa_ramp_fraction, scale,
                                            critic_weight=self.sa_critic_weight)

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
                penalty = self.sa_regularizer(self.actor, obs, self._current_progress_remaining, self.critic.q1_forward)
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
