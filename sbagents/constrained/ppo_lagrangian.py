"""PPO-Lagrangian and PID-Lagrangian: SB3's PPO under an episode-cost constraint (Safety Gym, OmniSafe style).

The env reports a per-step cost in ``info["cost"]`` (Safety-Gymnasium's convention; missing means 0). On top of
PPO this adds:

- a cost critic ``V_c``: a separate MLP (the value net's ``net_arch``) on the value features
  (``policy.extract_features`` with the value features extractor, detached), trained by MSE on the cost returns with
  its own optimizer, after the PPO epochs of each update;
- per-step costs read from the infos while SB3's own ``collect_rollouts`` runs (the VecEnv is wrapped in a recorder
  for the rollout; no copy of SB3's loop), with GAE for costs and the same time-limit bootstrap SB3 uses for rewards
  (``cost += cost_gamma * V_c(terminal_observation)``);
- one multiplier update per rollout from the mean cost of the episodes that ended in it (none ended: unchanged);
- the policy loss of PPO on the combined advantage ``(A_r - lambda * A_c) / (1 + lambda)`` (OmniSafe), where with
  ``normalize_advantage`` ``A_r`` is standardised and ``A_c`` centred over the whole rollout, as OmniSafe's buffer.

Logs ``constraint/multiplier``, ``constraint/ep_cost`` (the rollout's mean episode cost, the multiplier's input) and
``rollout/ep_cost_mean`` (last 100 episodes). Only Box, Discrete (one-hot) and other non-Dict observations.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Literal, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import BaseModel
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.utils import obs_as_tensor, update_learning_rate
from stable_baselines3.common.vec_env import VecEnv
from torch import nn
from torch.nn import functional as F

from sbagents.constrained.buffers import CostRolloutBuffer
from sbagents.constrained.episode_costs import EPISODE_STATE, EpisodeCostConstraint

Constraint = Literal["lagrangian", "pid"]


class _CostRecordingEnv:
    """Forwards everything to the VecEnv and hands each ``step``'s ``(dones, infos)`` to ``record``."""

    def __init__(self, venv: VecEnv, record: Any) -> None:
        self._venv = venv
        self._record = record

    def step(self, actions: np.ndarray) -> Any:
        result = self._venv.step(actions)
        self._record(result[2], result[3])
        return result

    def __getattr__(self, name: str) -> Any:
        return getattr(self._venv, name)


class PPOLagrangian(EpisodeCostConstraint, PPO):
    """PPO with a Lagrangian episode-cost constraint ``E[sum_t cost_t] <= cost_limit``.

    :param cost_limit: the episode-cost budget ``d`` (undiscounted sum of ``info["cost"]`` per episode).
    :param constraint: ``"lagrangian"`` (:class:`LagrangeMultiplier`) or ``"pid"`` (:class:`PIDLagrangeMultiplier`).
    :param multiplier_kwargs: keyword arguments of the multiplier, e.g. ``{"lr": 0.05, "init": 0.0}`` or
        ``{"kp": 0.1, "ki": 0.01, "kd": 0.01}``.
    :param cost_gamma: discount of the cost returns (default: ``gamma``).
    :param cost_gae_lambda: GAE lambda of the cost advantages (default: ``gae_lambda``).
    :param cost_vf_learning_rate: learning rate of the cost critic (default: PPO's schedule).
    Other parameters as :class:`~stable_baselines3.PPO` (``rollout_buffer_class`` is fixed to
    :class:`~sbagents.constrained.buffers.CostRolloutBuffer`).
    """

    rollout_buffer: CostRolloutBuffer
    cost_critic: nn.Module
    cost_critic_optimizer: th.optim.Optimizer

    def __init__(
        self,
        policy: Any,
        env: Any,
        cost_limit: float = 25.0,
        constraint: Constraint = "lagrangian",
        multiplier_kwargs: dict[str, Any] | None = None,
        cost_gamma: float | None = None,
        cost_gae_lambda: float | None = None,
        cost_vf_learning_rate: float | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ) -> None:
        self._init_constraint(cost_limit, constraint, multiplier_kwargs)
        if kwargs.get("rollout_buffer_class") not in (None, CostRolloutBuffer):
            raise ValueError("PPOLagrangian uses its own CostRolloutBuffer; do not pass rollout_buffer_class")
        kwargs["rollout_buffer_class"] = CostRolloutBuffer
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        self.cost_gamma = self.gamma if cost_gamma is None else float(cost_gamma)
        self.cost_gae_lambda = self.gae_lambda if cost_gae_lambda is None else float(cost_gae_lambda)
        self.cost_vf_learning_rate = cost_vf_learning_rate
        self._rollout_costs: list[np.ndarray] = []
        self._rollout_truncations: list[tuple[int, int, Any]] = []
        if _init_setup_model:
            self._setup_model()

    # -- model -----------------------------------------------------------------------------------------------
    def _setup_model(self) -> None:
        if isinstance(self.observation_space, spaces.Dict):
            raise ValueError("PPOLagrangian does not support Dict observation spaces")
        self.rollout_buffer_kwargs = {
            **self.rollout_buffer_kwargs,
            "cost_gamma": self.cost_gamma,
            "cost_gae_lambda": self.cost_gae_lambda,
        }
        super()._setup_model()
        net_arch = self.policy.net_arch
        vf_arch = net_arch.get("vf", [64, 64]) if isinstance(net_arch, dict) else list(net_arch)
        features_dim = self.policy.vf_features_extractor.features_dim
        layers = create_mlp(features_dim, 1, list(vf_arch), self.policy.activation_fn)
        self.cost_critic = nn.Sequential(*layers).to(self.device)
        optimizer_class: Any = self.policy.optimizer_class
        self.cost_critic_optimizer = optimizer_class(
            self.cost_critic.parameters(), lr=self._cost_lr(), **self.policy.optimizer_kwargs
        )

    def _cost_lr(self) -> float:
        if self.cost_vf_learning_rate is not None:
            return float(self.cost_vf_learning_rate)
        return float(self.lr_schedule(self._current_progress_remaining))

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "cost_critic", "cost_critic_optimizer"], variables

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_rollout_costs", "_rollout_truncations", *EPISODE_STATE]

    def predict_cost_values(self, obs: th.Tensor) -> th.Tensor:
        """``V_c(obs)``, shape ``(batch,)``, for a batch of observations already on the device (unprocessed, as
        ``policy.obs_to_tensor`` returns them)."""
        features = BaseModel.extract_features(self.policy, obs, self.policy.vf_features_extractor)
        return self.cost_critic(features.detach()).flatten()

    def _cost_values_of(self, obs: np.ndarray) -> np.ndarray:
        """``V_c`` of a numpy batch ``(n, *obs_shape)`` -> ``(n,)``."""
        with th.no_grad():
            return self.predict_cost_values(obs_as_tensor(obs, self.device)).cpu().numpy()  # type: ignore[arg-type]

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        env_reset = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        if reset_num_timesteps:
            self.ep_cost_buffer = deque(maxlen=self.ep_cost_buffer.maxlen)
        if env_reset:  # the envs were reset: no episode is under way
            self._running_ep_cost = None
        return result

    # -- rollouts --------------------------------------------------------------------------------------------
    def _record_step(self, dones: np.ndarray, infos: list[dict[str, Any]]) -> None:
        step = len(self._rollout_costs)
        self._rollout_costs.append(self._add_step_costs(dones, infos))
        for idx in np.flatnonzero(dones):
            terminal_obs = infos[idx].get("terminal_observation")
            if terminal_obs is not None and infos[idx].get("TimeLimit.truncated", False):
                self._rollout_truncations.append((step, int(idx), terminal_obs))

    def collect_rollouts(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> bool:
        """SB3's rollout (with the costs recorded from the infos), then cost values, cost GAE and one multiplier
        update."""
        assert isinstance(rollout_buffer, CostRolloutBuffer), "PPOLagrangian needs a CostRolloutBuffer"
        self._rollout_costs, self._rollout_truncations = [], []
        recorder = cast(VecEnv, _CostRecordingEnv(env, self._record_step))
        if not super().collect_rollouts(recorder, callback, rollout_buffer, n_rollout_steps):
            return False
        buf = rollout_buffer
        n_steps, n_envs = buf.buffer_size, buf.n_envs
        costs = np.stack(self._rollout_costs).astype(np.float32)  # (n_steps, n_envs)
        self.policy.set_training_mode(False)
        flat_obs = buf.observations.reshape(n_steps * n_envs, *buf.obs_shape)
        buf.cost_values = self._cost_values_of(flat_obs).reshape(n_steps, n_envs).astype(np.float32)
        for step, idx, terminal_obs in self._rollout_truncations:
            obs_tensor = self.policy.obs_to_tensor(terminal_obs)[0]
            with th.no_grad():
                costs[step, idx] += self.cost_gamma * float(self.predict_cost_values(obs_tensor)[0])  # type: ignore[arg-type]
        buf.costs = costs
        last_obs = np.asarray(self._last_obs).reshape(n_envs, *buf.obs_shape)
        buf.compute_cost_returns_and_advantage(self._cost_values_of(last_obs), np.asarray(self._last_episode_starts))
        self._update_multiplier()
        return True

    # -- update ----------------------------------------------------------------------------------------------
    def train(self) -> None:
        """Combine the advantages, run PPO's update on them, then fit the cost critic."""
        buf = self.rollout_buffer
        adv_r = buf.advantages.astype(np.float64)
        adv_c = buf.cost_advantages.astype(np.float64)
        if self.normalize_advantage and adv_r.size > 1:
            adv_r = (adv_r - adv_r.mean()) / (adv_r.std() + 1e-8)
            adv_c = adv_c - adv_c.mean()
        lam = self.multiplier.value
        buf.reward_advantages = buf.advantages
        buf.advantages = ((adv_r - lam * adv_c) / (1.0 + lam)).astype(np.float32)
        normalize_advantage = self.normalize_advantage
        self.normalize_advantage = False  # done above, over the whole rollout
        try:
            super().train()
        finally:
            self.normalize_advantage = normalize_advantage
        self._train_cost_critic()

    def _train_cost_critic(self) -> None:
        update_learning_rate(self.cost_critic_optimizer, self._cost_lr())
        self.cost_critic.train()
        losses = []
        for _ in range(self.n_epochs):
            for data in self.rollout_buffer.get(self.batch_size):
                loss = F.mse_loss(self.predict_cost_values(data.observations), data.cost_returns)
                self.cost_critic_optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(self.cost_critic.parameters(), self.max_grad_norm)
                self.cost_critic_optimizer.step()
                losses.append(loss.item())
        self.logger.record("train/cost_value_loss", float(np.mean(losses)) if losses else math.nan)
