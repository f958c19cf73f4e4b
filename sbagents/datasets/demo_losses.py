"""Supervised losses on demonstrations during off-policy learning (``train --demos DATASET --demo-bc WEIGHT``).

- Actor-critic (SAC, TQC, TD3, DDPG): behaviour cloning of the actor's deterministic action (mean squared error in the
  actor's ``[-1, 1]`` scale) behind a Q-filter: a demonstrated action counts only where the critic values it above the
  actor's own, ``Q(s, a_demo) > Q(s, pi(s))`` (Nair et al. 2018, section 4.3).
- Q-learning (DQN, QR-DQN): DQfD's large-margin loss ``max_a [Q(s, a) + l(a_demo, a)] - Q(s, a_demo)`` with
  ``l = 0.8`` for every action but the demonstrated one (Hester et al. 2018, eq. 2; QR-DQN: the quantiles' mean).

The Q-filter needs a critic that has learned something: before that, a random critic prefers the actor's own action
as often as not and the actor's own updates pull it away from the demonstrations (seen on Kuka pick-and-place: a
cloned policy's success fell from 42% to 0% within 250 gradient steps). The filter therefore starts after
``filter_after`` gradient steps of the model (its own count, which a run continued with ``-i`` keeps); before, every
demonstration counts.

Both are taken as separate gradient steps of the actor's (the Q-network's) own optimizer, as many per rollout as the
model's gradient steps, on batches of demonstrations (their original goals in goal envs), once learning has started;
the weight scales the loss.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sbagents.datasets.cloning import Transitions, as_tensors, q_network
from sbagents.errors import UsageError

#: DQfD's margin between the demonstrated action's value and every other's.
MARGIN = 0.8


def q_filtered_cloning_loss(model: OffPolicyAlgorithm, obs: Any, actions: torch.Tensor, q_filter: bool = True
                            ) -> tuple[torch.Tensor, float]:
    """The actor's cloning loss on a batch of demonstrations behind the Q-filter, and the share of the batch the
    filter kept.

    :param obs: observation tensors ``(batch, *obs_shape)`` (normalized as the model sees them).
    :param actions: demonstrated actions ``(batch, action_dim)`` in ``[-1, 1]``.
    :param q_filter: filter (else every demonstration counts).
    """
    actor: Any = model.actor  # type: ignore[attr-defined]
    taken = actor(obs, deterministic=True) if hasattr(actor, "action_dist") else actor(obs)
    with torch.no_grad():
        keep = (_q_value(model, obs, actions) > _q_value(model, obs, taken.detach())).float() if q_filter else \
            torch.ones(len(actions), device=actions.device)
    squared = ((taken - actions) ** 2).sum(dim=1)
    return (squared * keep).mean(), float(keep.mean())


def margin_loss(model: OffPolicyAlgorithm, obs: Any, actions: torch.Tensor, q_filter: bool = True
                ) -> tuple[torch.Tensor, float]:
    """DQfD's large-margin loss on a batch of demonstrations, and the share of the batch where the demonstrated action
    is already the greedy one.

    :param actions: demonstrated actions ``(batch,)`` (integers).
    :param q_filter: unused (DQfD's loss has no filter).
    """
    values = q_network(model)(obs)
    if values.dim() == 3:  # QR-DQN: (batch, n_quantiles, actions)
        values = values.mean(dim=1)
    demo = values.gather(1, actions.long().reshape(-1, 1)).squeeze(1)
    margins = torch.full_like(values, MARGIN)
    margins.scatter_(1, actions.long().reshape(-1, 1), 0.0)
    loss = ((values + margins).max(dim=1).values - demo).mean()
    return loss, float((values.argmax(dim=1) == actions.long().reshape(-1)).float().mean())


def _q_value(model: OffPolicyAlgorithm, obs: Any, actions: torch.Tensor) -> torch.Tensor:
    """``(batch,)``: the critics' minimum (SAC, TD3, DDPG) or the mean of every critic's quantiles (TQC)."""
    values = model.critic(obs, actions)  # type: ignore[attr-defined]
    if isinstance(values, (tuple, list)):
        return torch.cat(values, dim=1).min(dim=1).values
    return values.flatten(start_dim=1).mean(dim=1)


class DemoLossCallback(BaseCallback):
    """Takes the demonstration loss's gradient steps (see the module docstring) after each rollout once learning has
    started; :attr:`steps` and :attr:`kept` say how many it took and the mean share of each batch that counted (the
    Q-filter's share, or the share already greedy for DQfD's loss).

    :param data: the demonstrations' (observation, action) pairs.
    :param weight: the loss's factor.
    :param filter_after: the model's gradient steps before the Q-filter starts (counted by the model, so a run
        continued with ``-i`` does not start unfiltered again).
    :param seed: seeds the batches.
    """

    def __init__(self, data: Transitions, weight: float, filter_after: int = 0, seed: int = 0) -> None:
        super().__init__()
        self.data, self.weight, self.filter_after = data, weight, filter_after
        self.rng = np.random.default_rng(seed)
        self.steps, self.kept = 0, 0.0
        self._loss: Callable[[Any, Any, torch.Tensor, bool], tuple[torch.Tensor, float]] = margin_loss
        self._optimizer: Any = None

    def _init_callback(self) -> None:
        model: Any = self.model
        if not isinstance(model, OffPolicyAlgorithm):
            raise UsageError("--demo-bc is for off-policy algorithms")
        if isinstance(model.action_space, spaces.Discrete):
            self._loss, self._optimizer = margin_loss, model.policy.optimizer
        elif getattr(model, "actor", None) is not None and getattr(model, "critic", None) is not None:
            self._loss, self._optimizer = q_filtered_cloning_loss, model.actor.optimizer
        else:
            raise UsageError(f"--demo-bc does not know the losses of a {type(model).__name__}")

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        model: Any = self.model
        if model.num_timesteps <= model.learning_starts:
            return
        steps = model.gradient_steps if model.gradient_steps > 0 else model.train_freq.frequency * model.n_envs
        venv = model.get_vec_normalize_env()
        done = int(getattr(model, "_n_updates", self.steps))  # the model's gradient steps: a resumed run goes on
        model.policy.set_training_mode(True)
        for i in range(steps):
            index = self.rng.integers(0, len(self.data), size=min(model.batch_size, len(self.data)))
            obs, actions = as_tensors(model, self.data.take(index), venv)
            loss, kept = self._loss(model, obs, actions, done + i >= self.filter_after)
            self._optimizer.zero_grad()
            (self.weight * loss).backward()
            self._optimizer.step()
            self.kept += (kept - self.kept) / (self.steps + 1)
            self.steps += 1
        model.policy.set_training_mode(False)
