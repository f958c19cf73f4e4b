"""A centralized critic for PPO / A2C (CTDE, as MAPPO): :class:`CentralizedCriticPolicy`.

The team VecEnv gives ``Dict(obs=<the agent's own observation>, state=<the env's global state() + agent
one-hot>)`` (``critic: centralized``). The actor reads ``obs`` only, so acting (and an exported policy) needs
nothing but the agent's own observation; the value function reads ``state`` only, which is where the other agents'
situation helps credit assignment during training.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

OBS_KEY, STATE_KEY = "obs", "state"


class KeyFeatures(BaseFeaturesExtractor):
    """The flattened entry ``key`` of a Dict observation."""

    def __init__(self, observation_space: spaces.Dict, key: str) -> None:
        sub = observation_space.spaces[key]
        super().__init__(observation_space, int(th.tensor(sub.shape).prod()))
        self.key = key

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:  # type: ignore[override]
        return th.flatten(observations[self.key], start_dim=1)


def _mlp(in_dim: int, sizes: list[int], activation: type[nn.Module]) -> tuple[nn.Sequential, int]:
    layers: list[nn.Module] = []
    for size in sizes:
        layers += [nn.Linear(in_dim, size), activation()]
        in_dim = size
    return nn.Sequential(*layers), in_dim


class TwoInputMlpExtractor(nn.Module):
    """SB3's ``MlpExtractor`` with separate input sizes for the policy and the value network."""

    def __init__(self, pi_dim: int, vf_dim: int, net_arch: list[int] | dict[str, list[int]],
                 activation_fn: type[nn.Module], device: th.device | str = "auto") -> None:
        super().__init__()
        pi_sizes = net_arch.get("pi", []) if isinstance(net_arch, dict) else list(net_arch)
        vf_sizes = net_arch.get("vf", []) if isinstance(net_arch, dict) else list(net_arch)
        self.policy_net, self.latent_dim_pi = _mlp(pi_dim, pi_sizes, activation_fn)
        self.value_net, self.latent_dim_vf = _mlp(vf_dim, vf_sizes, activation_fn)

    def forward(self, features: tuple[th.Tensor, th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
        return self.forward_actor(features[0]), self.forward_critic(features[1])

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        return self.policy_net(features)  # type: ignore[no-any-return]

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        return self.value_net(features)  # type: ignore[no-any-return]


class CentralizedCriticPolicy(ActorCriticPolicy):
    """``ActorCriticPolicy`` whose actor sees ``obs["obs"]`` and whose critic sees ``obs["state"]``.

    Takes ActorCriticPolicy's keyword arguments (``net_arch``, ``activation_fn``, ...); the features extractors
    are fixed (one per key) and not shared.
    """

    def __init__(self, observation_space: spaces.Space[Any], action_space: spaces.Space[Any], lr_schedule: Any,
                 **kwargs: Any) -> None:
        if not (isinstance(observation_space, spaces.Dict) and {OBS_KEY, STATE_KEY} <= set(observation_space.spaces)):
            raise ValueError("CentralizedCriticPolicy needs Dict(obs=..., state=...) observations "
                             "(critic: centralized)")
        kwargs.pop("features_extractor_class", None)
        kwargs.pop("features_extractor_kwargs", None)
        kwargs["share_features_extractor"] = False
        self._next_key = OBS_KEY  # SB3 makes the actor's extractor first, then the critic's
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def make_features_extractor(self) -> BaseFeaturesExtractor:
        key, self._next_key = self._next_key, STATE_KEY
        assert isinstance(self.observation_space, spaces.Dict)
        return KeyFeatures(self.observation_space, key)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = TwoInputMlpExtractor(  # type: ignore[assignment]
            self.pi_features_extractor.features_dim, self.vf_features_extractor.features_dim, self.net_arch,
            self.activation_fn, self.device)

    @property
    def actor_observation_space(self) -> spaces.Space[Any]:
        """The actor's input: the agent's own observation (what an exported policy takes)."""
        assert isinstance(self.observation_space, spaces.Dict)
        return self.observation_space.spaces[OBS_KEY]

    def actor_actions(self, obs: th.Tensor, deterministic: bool = True) -> th.Tensor:
        """Actions ``(batch, *act_shape)`` from the agents' own observations ``(batch, *obs_shape)`` alone (the
        critic and its state are not needed to act)."""
        features = self.pi_features_extractor({OBS_KEY: obs})
        latent = self.mlp_extractor.forward_actor(features)  # type: ignore[operator]
        return self._get_action_dist_from_latent(latent).get_actions(deterministic=deterministic)

    def predict_actor(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """:meth:`actor_actions` for a numpy batch ``(batch, *obs_shape)``; returns numpy actions."""
        self.set_training_mode(False)
        with th.no_grad():
            actions = self.actor_actions(th.as_tensor(np.asarray(obs), dtype=th.float32, device=self.device),
                                         deterministic)
        return actions.cpu().numpy()  # type: ignore[no-any-return]
