"""Relational features for policies of agents that see other entities by relative position:
:class:`EntityAttentionFeatures` (the shipped ``mpe2.simple_spread_v3`` entry's) and :class:`PairwiseDistanceFeatures`.

In MPE-style observations an agent sees the targets (landmarks) and the other agents as positions relative to its
own. Which target an agent should take depends on how far *every* agent is from *every* target (a landmark is
mine when I am the closest to it), and a small MLP learns that function of the raw offsets slowly.

- :class:`PairwiseDistanceFeatures` hands the network those distances: it keeps the observation and appends
  ``|t_i - a_j|`` for every target ``i`` and every agent ``j`` (the observer itself first, at the origin, then the
  others in observation order).
- :class:`EntityAttentionFeatures` turns every target into a token (its offset, its distance to me, the nearest and
  farthest other agent's distance to it) and pools the tokens with attention over targets, so "the target I am
  closest to" is one learned lookup whatever order the env lists targets in (``spread-ablation`` in
  ``BENCHMARKS.md``: what it is worth against the MLP and the pairwise distances).

Both only read the observation (no env change, nothing extra to feed at inference), so an exported policy takes the
same observation as the env gives.

Use one from a zoo entry, e.g. ``mpe2.simple_spread_v3`` with ``N=3`` (observation ``[vel 2, pos 2, landmarks 6,
other agents 4, communication 4]``)::

    policy_kwargs:
      features_extractor_class: sbagents.multiagent.relational:EntityAttentionFeatures
      features_extractor_kwargs: {targets: [4, 10], agents: [10, 14], own: [0, 4], hidden: 32, heads: 2}
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


def _slice(value: Sequence[int], name: str, dim: int, owner: str = "PairwiseDistanceFeatures") -> tuple[int, int]:
    """``(start, stop)`` of a block of ``(x, y)`` pairs inside an observation of ``dim`` values."""
    if len(value) != 2 or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        raise ValueError(f"{owner}: {name} must be [start, stop] (two integers), got {value!r}")
    start, stop = int(value[0]), int(value[1])
    if not 0 <= start < stop <= dim or (stop - start) % 2:
        raise ValueError(f"{owner}: {name} [{start}, {stop}] must be a non-empty, even-length "
                         f"range inside the observation's {dim} values (x, y pairs)")
    return start, stop


class PairwiseDistanceFeatures(BaseFeaturesExtractor):
    """The flat observation followed by the distances between every target and every agent.

    :param observation_space: a flat ``Box`` of shape ``(dim,)``.
    :param targets: ``[start, stop)`` of the targets' positions relative to the observer: ``n_t`` ``(x, y)`` pairs.
    :param agents: ``[start, stop)`` of the other agents' positions relative to the observer: ``n_o`` pairs.
    :raises ValueError: a non-flat space or a range that is empty, odd-length or outside the observation.

    ``forward``: observations ``(batch, dim)`` -> features ``(batch, dim + n_t * (n_o + 1))``: the observation,
    then for each target ``i`` its distances to the observer and to each other agent in order.
    """

    def __init__(self, observation_space: spaces.Space[Any], targets: Sequence[int] = (4, 10),
                 agents: Sequence[int] = (10, 14)) -> None:
        if not (isinstance(observation_space, spaces.Box) and len(observation_space.shape) == 1):
            raise ValueError("PairwiseDistanceFeatures needs a flat Box observation space, got "
                             f"{observation_space}")
        dim = int(observation_space.shape[0])
        self.targets = _slice(targets, "targets", dim)
        self.agents = _slice(agents, "agents", dim)
        self.n_targets = (self.targets[1] - self.targets[0]) // 2
        self.n_points = (self.agents[1] - self.agents[0]) // 2 + 1  # the observer, then the others
        super().__init__(observation_space, dim + self.n_targets * self.n_points)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        obs = th.flatten(observations, start_dim=1)
        batch = obs.shape[0]
        targets = obs[:, self.targets[0] : self.targets[1]].reshape(batch, self.n_targets, 1, 2)
        others = obs[:, self.agents[0] : self.agents[1]].reshape(batch, self.n_points - 1, 2)
        points = th.cat([th.zeros_like(others[:, :1]), others], dim=1).unsqueeze(1)  # (batch, 1, n_points, 2)
        dist = th.linalg.vector_norm(targets - points, dim=-1)  # (batch, n_targets, n_points)
        return th.cat([obs, dist.reshape(batch, -1)], dim=1)


class EntityAttentionFeatures(BaseFeaturesExtractor):
    """Permutation-invariant features of targets and other agents seen by relative position.

    Every target ``i`` becomes a token ``[t_i (2), |t_i|, min_j |t_i - a_j|, max_j |t_i - a_j|, own]`` (its offset,
    its distance to the observer, the nearest and farthest other agent's distance to it, and the observer's own
    features); a shared layer embeds the tokens and ``heads`` attention heads pool them (softmax over targets), so
    the network can single out "the target I am closest to" whatever the order the env lists targets in. Every other
    agent becomes ``[a_j (2), |a_j|, own]``, embedded by a shared layer and pooled by mean and max. Output:
    ``[own, target heads, agent mean, agent max]``.

    :param observation_space: a flat ``Box`` of shape ``(dim,)``.
    :param targets: ``[start, stop)`` of the targets' positions relative to the observer (``n_t`` ``(x, y)`` pairs).
    :param agents: ``[start, stop)`` of the other agents' positions relative to the observer (``n_o >= 1`` pairs).
    :param own: ``[start, stop)`` of the observer's own features (e.g. velocity and position).
    :param hidden: embedding width ``H``.
    :param heads: attention heads ``K`` over the targets.
    :raises ValueError: a non-flat space, a bad range, or ``hidden``/``heads`` below 1.

    ``forward``: ``(batch, dim)`` -> ``(batch, n_own + K * H + 2 * H)``.
    """

    def __init__(self, observation_space: spaces.Space[Any], targets: Sequence[int] = (4, 10),
                 agents: Sequence[int] = (10, 14), own: Sequence[int] = (0, 4), hidden: int = 32,
                 heads: int = 2) -> None:
        if not (isinstance(observation_space, spaces.Box) and len(observation_space.shape) == 1):
            raise ValueError("EntityAttentionFeatures needs a flat Box observation space, got "
                             f"{observation_space}")
        if not (isinstance(hidden, int) and isinstance(heads, int) and hidden >= 1 and heads >= 1):
            raise ValueError(f"EntityAttentionFeatures: hidden and heads must be integers >= 1, got {hidden}, {heads}")
        dim = int(observation_space.shape[0])
        self.targets = _slice(targets, "targets", dim, "EntityAttentionFeatures")
        self.agents = _slice(agents, "agents", dim, "EntityAttentionFeatures")
        start, stop = (int(own[0]), int(own[1])) if len(own) == 2 else (0, 0)
        if not 0 <= start < stop <= dim:
            raise ValueError(f"EntityAttentionFeatures: own must be [start, stop] inside the observation's {dim} "
                             f"values, got {list(own)!r}")
        self.own = (start, stop)
        n_own = stop - start
        self.n_targets = (self.targets[1] - self.targets[0]) // 2
        self.n_others = (self.agents[1] - self.agents[0]) // 2
        self.hidden, self.heads = hidden, heads
        super().__init__(observation_space, n_own + heads * hidden + 2 * hidden)
        # target tokens -> embedding, then per head an attention score and a value
        self.target_embed = nn.Sequential(nn.Linear(5 + n_own, hidden), nn.Tanh())
        self.target_heads = nn.Linear(hidden, heads * (1 + hidden))
        self.agent_embed = nn.Sequential(nn.Linear(3 + n_own, hidden), nn.Tanh())

    def forward(self, observations: th.Tensor) -> th.Tensor:
        obs = th.flatten(observations, start_dim=1)
        batch, n_t, n_o, h, k = obs.shape[0], self.n_targets, self.n_others, self.hidden, self.heads
        own = obs[:, self.own[0] : self.own[1]]
        targets = obs[:, self.targets[0] : self.targets[1]].reshape(batch, n_t, 2)
        others = obs[:, self.agents[0] : self.agents[1]].reshape(batch, n_o, 2)
        to_others = th.linalg.vector_norm(targets[:, :, None] - others[:, None], dim=-1)  # (batch, n_t, n_o)
        target_tokens = th.cat([targets, th.linalg.vector_norm(targets, dim=-1, keepdim=True),
                                to_others.min(dim=-1, keepdim=True).values,
                                to_others.max(dim=-1, keepdim=True).values,
                                own[:, None].expand(batch, n_t, own.shape[1])], dim=-1)
        heads = self.target_heads(self.target_embed(target_tokens))  # (batch, n_t, k * (1 + h))
        weights = th.softmax(heads[..., :k], dim=1)  # (batch, n_t, k): attention over the targets
        values = th.tanh(heads[..., k:]).reshape(batch, n_t, k, h)
        pooled_targets = (weights[..., None] * values).sum(dim=1).reshape(batch, k * h)
        agent_tokens = th.cat([others, th.linalg.vector_norm(others, dim=-1, keepdim=True),
                               own[:, None].expand(batch, n_o, own.shape[1])], dim=-1)
        agents = self.agent_embed(agent_tokens)  # (batch, n_o, h)
        return th.cat([own, pooled_targets, agents.mean(dim=1), agents.max(dim=1).values], dim=1)
