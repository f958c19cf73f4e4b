"""A masked MLP policy as numpy arrays: self-play opponents act in microseconds instead of a torch call.

An opponent move costs one forward pass of batch 1; through SB3's ``predict`` that is ~0.5 ms of torch overhead,
a third of a connect four training run. :func:`numpy_actor` copies the actor of an SB3 ``ActorCriticPolicy``
(flattened observations, the ``mlp_extractor.policy_net`` layers, ``action_net``) into numpy; the same logits,
masked as sb3-contrib masks them, then the argmax or a sample. Other architectures return None (callers fall back
to ``model.predict``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch.nn as nn
from gymnasium import spaces

_ACTIVATIONS: dict[type[nn.Module], Callable[[np.ndarray], np.ndarray]] = {
    nn.Tanh: np.tanh,
    nn.ReLU: lambda x: np.maximum(x, 0.0),
    nn.Identity: lambda x: x,
}


class NumpyActor:
    """Logits of a feed-forward actor: ``layers`` of ``(weight (out, in), bias (out,), activation)``."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], np.ndarray]]]) -> None:
        self.layers = layers

    def logits(self, observation: np.ndarray) -> np.ndarray:
        """Logits (n_actions,) of one observation (any shape; flattened)."""
        x = np.asarray(observation, np.float32).reshape(-1)
        for weight, bias, activation in self.layers:
            x = activation(weight @ x + bias)
        return x

    def act(self, observation: np.ndarray, action_mask: np.ndarray, deterministic: bool,
            rng: np.random.Generator) -> int:
        """The argmax or a sample of the masked softmax (illegal actions have probability 0)."""
        logits = np.where(np.asarray(action_mask, bool), self.logits(observation).astype(np.float64), -np.inf)
        if deterministic:
            return int(np.argmax(logits))
        probs = np.exp(logits - logits.max())
        cumulative = np.cumsum(probs)
        return int(min(np.searchsorted(cumulative, rng.random() * cumulative[-1], side="right"),
                       len(probs) - 1))


def numpy_actor(policy: nn.Module) -> NumpyActor | None:
    """The numpy copy of an SB3 actor-critic policy's actor, or None when its architecture is not a plain MLP on
    a flattened Box observation."""
    extractor = getattr(policy, "pi_features_extractor", None) or getattr(policy, "features_extractor", None)
    mlp = getattr(getattr(policy, "mlp_extractor", None), "policy_net", None)
    head = getattr(policy, "action_net", None)
    observation_space = getattr(policy, "observation_space", None)
    if (type(extractor).__name__ != "FlattenExtractor" or not isinstance(mlp, nn.Sequential)
            or not isinstance(head, nn.Linear) or not isinstance(observation_space, spaces.Box)
            or getattr(policy, "normalize_images", False) and observation_space.dtype == np.uint8):
        return None
    layers = []
    modules = [*mlp, head]
    for k, module in enumerate(modules):
        if isinstance(module, nn.Linear):
            following = modules[k + 1] if k + 1 < len(modules) else nn.Identity()
            activation = _ACTIVATIONS.get(type(following)) if not isinstance(following, nn.Linear) else None
            if activation is None and not isinstance(following, nn.Linear):
                return None
            layers.append((module.weight.detach().cpu().numpy().astype(np.float32),
                           module.bias.detach().cpu().numpy().astype(np.float32),
                           activation or _ACTIVATIONS[nn.Identity]))
        elif type(module) not in _ACTIVATIONS:
            return None
    return NumpyActor(layers)
