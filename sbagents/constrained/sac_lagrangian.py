"""SAC-Lagrangian: SB3's SAC under an episode-cost constraint (Ha et al. 2020; OmniSafe's ``SACLag``).

The env reports a per-step cost in ``info["cost"]`` (missing means 0). On top of SAC this adds:

- :class:`CostReplayBuffer`: SB3's replay buffer with the step costs stored beside the rewards;
- a cost critic ``Q_c`` (an SB3 ``ContinuousCritic`` with its own features extractor and a Polyak target) trained
  by TD on the costs: ``Q_c(s, a) <- c + cost_gamma * (1 - done) * Q_c'(s', a' ~ pi(s'))`` (no entropy term);
- the actor loss ``(alpha * log pi - Q_r + lambda * Q_c) / (1 + lambda)`` (OmniSafe's normalisation);
- one multiplier update per ``train`` call from the mean cost of the training episodes that ended since the last
  update (none ended: unchanged; the episodes of the ``learning_starts`` warm-up give one update), with
  ``LagrangeMultiplier`` or ``PIDLagrangeMultiplier``.

SAC's ``train`` is reused unchanged: the cost terms are added in a step pre-hook of the actor's optimizer
(``torch.optim.Optimizer.register_step_pre_hook``), which runs once per gradient step after SAC's reward critic
update and actor backward pass, on the batch SAC just sampled. The hook fits ``Q_c`` on that batch, rescales the
actor's gradients by ``1 / (1 + lambda)`` and adds the gradient of ``lambda / (1 + lambda) * Q_c(s, pi(s))``
(a fresh reparameterised action: an unbiased estimate of the same gradient), then Polyak-updates the cost target
(``tau``, every gradient step).
This keeps SB3's loop (entropy tuning, target updates, logging) instead of copying it.

Logs ``constraint/multiplier``, ``constraint/ep_cost`` (the multiplier's input), ``rollout/ep_cost_mean`` (last
100 episodes) and ``train/cost_critic_loss``. Box observations only (no Dict, no HER).
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.common.vec_env import VecNormalize
from torch.nn import functional as F

from sbagents.constrained.episode_costs import EPISODE_STATE, EpisodeCostConstraint

Constraint = Literal["lagrangian", "pid"]


class CostReplayBufferSamples(NamedTuple):
    """SB3's ``ReplayBufferSamples`` plus ``costs``: ``observations``/``next_observations`` ``(batch, *obs_shape)``,
    ``actions`` ``(batch, action_dim)``, ``dones``, ``rewards`` and ``costs`` ``(batch, 1)``; ``discounts`` is
    always ``None`` (no n-step returns)."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    costs: th.Tensor
    discounts: th.Tensor | None = None


class CostReplayBuffer(ReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.ReplayBuffer` that also stores ``info["cost"]`` of each step
    (``costs``, shape ``(buffer_size, n_envs)``) and remembers the last sampled batch (``last_samples``).

    Parameters as SB3's ``ReplayBuffer``; ``optimize_memory_usage`` is not supported.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError("CostReplayBuffer does not support optimize_memory_usage")
        self.costs = np.zeros((self.buffer_size, self.n_envs), dtype=np.float32)
        self.last_samples: CostReplayBufferSamples | None = None

    def add(self, obs: Any, next_obs: Any, action: Any, reward: Any, done: Any, infos: list[dict[str, Any]]) -> None:
        """SB3's ``add``, with the costs read from ``infos``."""
        self.costs[self.pos] = np.array([float(info.get("cost", 0.0)) for info in infos], dtype=np.float32)
        super().add(obs, next_obs, action, reward, done, infos)

    def _get_samples(  # type: ignore[override]  # a NamedTuple with one more field
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> CostReplayBufferSamples:
        env_indices = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        done = self.dones[batch_inds, env_indices] * (1 - self.timeouts[batch_inds, env_indices])
        data = (
            self._normalize_obs(self.observations[batch_inds, env_indices, :], env),
            self.actions[batch_inds, env_indices, :],
            self._normalize_obs(self.next_observations[batch_inds, env_indices, :], env),
            done.reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_indices].reshape(-1, 1), env),
            self.costs[batch_inds, env_indices].reshape(-1, 1),
        )
        self.last_samples = CostReplayBufferSamples(*tuple(map(self.to_torch, data)))
        return self.last_samples


class SACLagrangian(EpisodeCostConstraint, SAC):
    """SAC with a Lagrangian episode-cost constraint ``E[sum_t cost_t] <= cost_limit``.

    :param cost_limit: the episode-cost budget ``d`` (undiscounted sum of ``info["cost"]`` per episode).
    :param constraint: ``"lagrangian"`` (``LagrangeMultiplier``) or ``"pid"`` (``PIDLagrangeMultiplier``).
    :param multiplier_kwargs: keyword arguments of the multiplier, e.g. ``{"lr": 0.01}`` or ``{"kp": 0.1}``.
    :param cost_gamma: discount of the cost critic's TD target (default: ``gamma``).
    :param cost_critic_learning_rate: learning rate of the cost critic (default: SAC's initial learning rate).
    :param cost_n_critics: number of cost Q-networks; their maximum is used (pessimistic about cost).
    Other parameters as :class:`~stable_baselines3.SAC` (``replay_buffer_class`` is fixed to
    :class:`CostReplayBuffer`).
    """

    replay_buffer: CostReplayBuffer  # type: ignore[assignment]
    cost_critic: ContinuousCritic
    cost_critic_target: ContinuousCritic

    def __init__(
        self,
        policy: Any,
        env: Any,
        cost_limit: float = 25.0,
        constraint: Constraint = "lagrangian",
        multiplier_kwargs: dict[str, Any] | None = None,
        cost_gamma: float | None = None,
        cost_critic_learning_rate: float | None = None,
        cost_n_critics: int = 1,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        self._init_constraint(cost_limit, constraint, multiplier_kwargs)
        if kwargs.get("replay_buffer_class") not in (None, CostReplayBuffer):
            raise ValueError("SACLagrangian uses its own CostReplayBuffer; do not pass replay_buffer_class (nor a "
                             "flag that sets it, such as --demos, with --constraint)")
        if cost_n_critics < 1:
            raise ValueError(f"cost_n_critics must be >= 1, got {cost_n_critics}")
        kwargs["replay_buffer_class"] = CostReplayBuffer
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        self.cost_gamma = self.gamma if cost_gamma is None else float(cost_gamma)
        self.cost_critic_learning_rate = cost_critic_learning_rate
        self.cost_n_critics = int(cost_n_critics)
        if _init_setup_model:
            self._setup_model()

    # -- model -----------------------------------------------------------------------------------------------
    def _setup_model(self) -> None:
        if isinstance(self.observation_space, spaces.Dict):
            raise ValueError("SACLagrangian does not support Dict observation spaces")
        super()._setup_model()
        self.cost_critic = self._make_cost_critic()
        self.cost_critic_target = self._make_cost_critic()
        self.cost_critic_target.load_state_dict(self.cost_critic.state_dict())
        self.cost_critic_target.set_training_mode(False)
        lr = self.lr_schedule(1.0) if self.cost_critic_learning_rate is None else self.cost_critic_learning_rate
        optimizer_class: Any = self.policy.optimizer_class
        self.cost_critic.optimizer = optimizer_class(
            self.cost_critic.parameters(), lr=lr, **self.policy.optimizer_kwargs
        )
        self._cost_losses: list[float] = []
        self._hook_handle = self.actor.optimizer.register_step_pre_hook(self._before_actor_step)

    def _make_cost_critic(self) -> ContinuousCritic:
        """A ``ContinuousCritic`` like SAC's (same ``net_arch``), ``cost_n_critics`` heads, own features extractor."""
        features = self.policy.make_features_extractor()
        kwargs: dict[str, Any] = {**self.policy.critic_kwargs, "n_critics": self.cost_n_critics,
                                  "features_extractor": features, "features_dim": features.features_dim}
        return ContinuousCritic(**kwargs).to(self.device)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "cost_critic", "cost_critic_target", "cost_critic.optimizer"], variables

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            *EPISODE_STATE,
            "_cost_losses",
            "_hook_handle",
        ]

    def predict_cost_values(self, obs: th.Tensor, actions: th.Tensor, target: bool = False) -> th.Tensor:
        """``Q_c(obs, actions)`` ``(batch, 1)`` (maximum over the cost critics) for tensors on the device."""
        critic = self.cost_critic_target if target else self.cost_critic
        return th.max(th.cat(critic(obs, actions), dim=1), dim=1, keepdim=True)[0]

    # -- episode costs and the multiplier ----------------------------------------------------------------------
    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: Any,
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """SB3's ``_store_transition`` (the buffer stores the costs), plus the running episode costs."""
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)
        self._add_step_costs(dones, infos)

    # -- update ----------------------------------------------------------------------------------------------
    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """Update the multiplier from the finished episodes, then SAC's update (cost terms in the actor hook)."""
        self._update_multiplier()
        self._cost_losses = []
        self.cost_critic.set_training_mode(True)
        super().train(gradient_steps, batch_size)
        if self._cost_losses:
            self.logger.record("train/cost_critic_loss", float(np.mean(self._cost_losses)))

    def _before_actor_step(self, optimizer: th.optim.Optimizer, args: Any, kwargs: Any) -> None:
        """Fit ``Q_c`` on SAC's batch; turn the actor's gradients into those of the Lagrangian actor loss."""
        data = self.replay_buffer.last_samples
        if data is None:
            return
        self._train_cost_critic(data)
        lam = self.multiplier.value
        for param in self.actor.parameters():
            if param.grad is not None:
                param.grad.mul_(1.0 / (1.0 + lam))
        if lam > 0.0:
            actions_pi, _ = self.actor.action_log_prob(data.observations)
            cost_loss = lam / (1.0 + lam) * self.predict_cost_values(data.observations, actions_pi).mean()
            cost_loss.backward()
            self.cost_critic.optimizer.zero_grad()
        polyak_update(self.cost_critic.parameters(), self.cost_critic_target.parameters(), self.tau)

    def _train_cost_critic(self, data: CostReplayBufferSamples) -> None:
        with th.no_grad():
            next_actions, _ = self.actor.action_log_prob(data.next_observations)
            next_q = self.predict_cost_values(data.next_observations, next_actions, target=True)
            target = data.costs + (1 - data.dones) * self.cost_gamma * next_q
        current = self.cost_critic(data.observations, data.actions)
        loss = 0.5 * sum(F.mse_loss(q, target) for q in current)
        assert isinstance(loss, th.Tensor)
        self.cost_critic.optimizer.zero_grad()
        loss.backward()
        self.cost_critic.optimizer.step()
        self._cost_losses.append(loss.item())
