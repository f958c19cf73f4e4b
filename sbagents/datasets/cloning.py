"""Behaviour cloning of an SB3 model's policy from a dataset, before reinforcement learning (``train --pretrain``).

What is fitted depends on the algorithm: the actor-critic policy's log-likelihood of the dataset's actions (PPO, A2C,
TRPO; RecurrentPPO is refused: its state would need whole sequences), an off-policy actor's deterministic action by
mean squared error in the policy's action scale (TD3, DDPG, and SAC's and TQC's squashed Gaussian mean: experts often
act at the bounds, where a squashed log-likelihood diverges; their entropy tuning takes the spread from there), and a
Q-network's cross-entropy (DQN, QR-DQN: the Q-values as logits). Target networks are synced afterwards. Where the run
normalizes observations, the statistics first take in the dataset's observations, then cloning sees them normalized.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.errors import UsageError


@dataclass(frozen=True)
class Transitions:
    """A dataset's (observation, action) pairs: ``observations`` ``(N, *obs_shape)`` (a dict of such arrays for a
    ``Dict`` space), ``actions`` ``(N, *action_shape)``."""

    observations: Any
    actions: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    def take(self, index: np.ndarray) -> Transitions:
        """The pairs at ``index``."""
        obs = ({k: v[index] for k, v in self.observations.items()} if isinstance(self.observations, dict)
               else self.observations[index])
        return Transitions(obs, self.actions[index])


@dataclass(frozen=True)
class CloningResult:
    """What cloning did: the pairs it trained on and held out, and the mean loss on each at the end."""

    n_train: int
    n_holdout: int
    train_loss: float
    holdout_loss: float | None


def _loss(model: BaseAlgorithm) -> tuple[Callable[[Any, torch.Tensor], torch.Tensor], list[torch.nn.Parameter]]:
    """The cloning loss of ``model`` (observation tensor, action tensor -> scalar) and the parameters it trains."""
    policy: Any = model.policy
    if isinstance(model, OnPolicyAlgorithm):
        if getattr(policy, "lstm_actor", None) is not None:
            raise UsageError("--pretrain clones stateless policies; ppo_lstm's state would need whole sequences")

        def on_policy(obs: Any, actions: torch.Tensor) -> torch.Tensor:
            _, log_prob, _ = policy.evaluate_actions(obs, actions)
            return -log_prob.mean()

        return on_policy, list(policy.parameters())
    actor = getattr(model, "actor", None)
    if actor is not None:  # TD3, DDPG; SAC, TQC with their deterministic (mean) action; all in [-1, 1]
        stochastic = hasattr(actor, "action_dist")

        def deterministic(obs: Any, actions: torch.Tensor) -> torch.Tensor:
            taken = actor(obs, deterministic=True) if stochastic else actor(obs)
            return torch.nn.functional.mse_loss(taken, actions)

        return deterministic, list(actor.parameters())
    q_net = q_network(model)
    if q_net is not None and isinstance(model.action_space, spaces.Discrete):
        def q_logits(obs: Any, actions: torch.Tensor) -> torch.Tensor:
            values = q_net(obs)
            if values.dim() == 3:  # QR-DQN: quantiles (batch, n_quantiles, actions)
                values = values.mean(dim=1)
            return torch.nn.functional.cross_entropy(values, actions.long().flatten())

        return q_logits, list(q_net.parameters())
    raise UsageError(f"--pretrain does not know how to clone a {type(model).__name__} policy")


def q_network(model: BaseAlgorithm) -> Any:
    """The network of a Q-learning model's values (DQN's ``q_net``, QR-DQN's ``quantile_net``; None for others)."""
    return getattr(model, "q_net", None) or getattr(model, "quantile_net", None)


def _scaled(model: BaseAlgorithm, actions: np.ndarray) -> np.ndarray:
    """The actions in the scale the model's actor outputs (off-policy Box: [-1, 1])."""
    if isinstance(model.action_space, spaces.Box) and not isinstance(model, OnPolicyAlgorithm):
        return np.asarray(model.policy.scale_action(actions), dtype=np.float32)
    return actions


def clone(model: BaseAlgorithm, data: Transitions, *, steps: int = 2000, batch_size: int = 256,
          learning_rate: float = 1e-3, holdout: float = 0.1, seed: int = 0) -> CloningResult:
    """Fit ``model``'s policy to ``data`` in ``steps`` gradient steps on shuffled batches (see the module docstring);
    ``holdout`` of the pairs (when there are ten or more) are kept out of training to measure the loss on.

    :raises UsageError: a model this cannot clone, or an empty dataset.
    """
    if len(data) == 0:
        raise UsageError("the dataset has no transitions to clone")
    loss_fn, params = _loss(model)
    venv = model.get_vec_normalize_env()
    if isinstance(venv, VecNormalize) and venv.norm_obs:
        _update_statistics(venv, data.observations)
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(data))
    n_holdout = int(len(data) * holdout) if len(data) >= 10 else 0
    held, train = data.take(order[:n_holdout]), data.take(order[n_holdout:])
    optimizer = torch.optim.Adam(params, lr=learning_rate)
    model.policy.set_training_mode(True)
    shuffled, start = rng.permutation(len(train)), 0
    for _ in range(steps):
        if start >= len(train):  # a new pass over the pairs
            shuffled, start = rng.permutation(len(train)), 0
        loss = loss_fn(*as_tensors(model, train.take(shuffled[start:start + batch_size]), venv))
        start += batch_size
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.policy.set_training_mode(False)
    with torch.no_grad():
        train_loss = float(loss_fn(*as_tensors(model, train, venv)))
        holdout_loss = float(loss_fn(*as_tensors(model, held, venv))) if n_holdout else None
    _sync_targets(model)
    return CloningResult(len(train), n_holdout, train_loss, holdout_loss)


def as_tensors(model: BaseAlgorithm, batch: Transitions, venv: Any) -> tuple[Any, torch.Tensor]:
    """``batch`` as the model's tensors: observations normalized by ``venv`` (a ``VecNormalize`` that normalizes
    them, else as they are), actions in the scale its policy outputs (integers ``(batch,)`` for ``Discrete``)."""
    obs = batch.observations
    if isinstance(venv, VecNormalize) and venv.norm_obs:
        obs = venv.normalize_obs(obs)
    obs_tensor, _ = model.policy.obs_to_tensor(obs)
    actions = torch.as_tensor(_scaled(model, batch.actions), device=model.device)
    if isinstance(model.action_space, spaces.Discrete):
        actions = actions.long().reshape(-1)
    return obs_tensor, actions


def _update_statistics(venv: VecNormalize, observations: Any) -> None:
    """Let the observation statistics take in the dataset's observations (once, before cloning)."""
    if isinstance(observations, dict):
        for key, value in observations.items():
            if key in venv.obs_rms:  # type: ignore[operator]
                venv.obs_rms[key].update(np.asarray(value, dtype=np.float64))  # type: ignore[index]
    else:
        venv.obs_rms.update(np.asarray(observations, dtype=np.float64))  # type: ignore[union-attr]


def _sync_targets(model: BaseAlgorithm) -> None:
    """Copy the cloned networks into their targets (TD3, DDPG: the actor; DQN: the Q-network; QR-DQN: the quantile
    network)."""
    for net, target in (("actor", "actor_target"), ("q_net", "q_net_target"), ("quantile_net", "quantile_net_target")):
        if getattr(model, target, None) is not None and getattr(model, net, None) is not None:
            getattr(model, target).load_state_dict(getattr(model, net).state_dict())
