"""PQN, parallel Q-learning (Gallici et al. 2024, "Simplifying Deep Temporal Difference Learning"), as an
SB3-compatible algorithm: DQN without a replay buffer and without a target network, made stable by LayerNorm in the
Q-network and by many parallel envs; the targets are Peng's Q(lambda) returns of each rollout.

Each iteration collects ``n_steps`` steps of every env acting epsilon-greedily (epsilon annealed linearly from
``exploration_initial_eps`` to ``exploration_final_eps`` over ``exploration_fraction`` of the budget), computes

    R_t = r_t + gamma * (lambda * R_{t+1} + (1 - lambda) * max_a Q(s_{t+1}, a))   (0 past an episode's end),

bootstrapped with ``max_a Q`` of the last observation, then takes ``n_epochs`` passes of minibatches of
``batch_size`` over the rollout, minimizing ``(Q(s_t, a_t) - R_t)^2`` with a clipped gradient. Episodes cut by a
time limit add ``gamma * max_a Q(terminal observation)`` to their last reward (SB3's on-policy rule).

The defaults are CleanRL's ``pqn_atari_envpool.py`` settings per env step (its 128 envs are the env's ``n_envs``):
32 steps per rollout, 2 epochs, gamma 0.99, lambda 0.65, RAdam at 2.5e-4 (annealed when a linear schedule is given),
gradient norm 10, epsilon 1 -> 0.001 over the first 10%. ``CnnPolicy`` is the Nature CNN with a LayerNorm after each
layer; ``MlpPolicy`` a 120-84 MLP with LayerNorm (CleanRL's ``pqn.py``).
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import get_action_dim, get_obs_shape
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, FlattenExtractor
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import LinearSchedule, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv, VecNormalize
from torch import nn
from torch.nn import functional as F  # noqa: N812 (torch's convention)


class LayerNormNatureCNN(BaseFeaturesExtractor):
    """The Nature DQN CNN (Mnih et al. 2015) with a LayerNorm after each convolution and after the linear layer, as
    PQN's Atari network: (N, C, 84, 84) images -> (N, ``features_dim``).

    :param observation_space: a channel-first image space.
    :param features_dim: the linear layer's width.
    :param normalized_image: the images are already in [0, 1] (SB3's flag).
    :param channels_last: run the convolutions in channels-last memory layout (the images and the convolution
        weights are converted; the results are the same up to float rounding). Whether it is faster depends on the
        batch size and the CPU: ``python -m benchmarks run pqn-pong-speed`` measures it.
    """

    def __init__(self, observation_space: spaces.Box, features_dim: int = 512, normalized_image: bool = False,
                 channels_last: bool = False) -> None:
        super().__init__(observation_space, features_dim)
        self.channels_last = channels_last
        channels = observation_space.shape[0]
        convs: list[nn.Module] = []
        shape = th.zeros(1, *observation_space.shape)
        for c_in, c_out, kernel, stride in ((channels, 32, 8, 4), (32, 64, 4, 2), (64, 64, 3, 1)):
            conv = nn.Conv2d(c_in, c_out, kernel, stride)
            shape = conv(shape)
            convs += [conv, nn.LayerNorm(list(shape.shape[1:])), nn.ReLU()]
        self.cnn = nn.Sequential(*convs, nn.Flatten())
        self.linear = nn.Sequential(nn.Linear(int(np.prod(shape.shape[1:])), features_dim), nn.LayerNorm(features_dim),
                                    nn.ReLU())
        if channels_last:
            self.cnn.to(memory_format=th.channels_last)  # type: ignore[call-overload]

    def forward(self, observations: th.Tensor) -> th.Tensor:
        if self.channels_last:
            observations = observations.contiguous(memory_format=th.channels_last)
        return self.linear(self.cnn(observations))  # type: ignore[no-any-return]


class PQNPolicy(BasePolicy):
    """A Q-network with LayerNorm: features -> (Linear -> LayerNorm -> activation) per ``net_arch`` layer ->
    one Q-value per action. Acting greedily is :meth:`predict`; PQN explores in its own rollouts.

    :param net_arch: hidden layer widths after the features extractor (default: 120-84 for vectors, none for the CNN).
    :param layer_norm: a LayerNorm after each hidden layer (PQN's; False: a plain MLP).
    """

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 net_arch: list[int] | None = None, activation_fn: type[nn.Module] = nn.ReLU,
                 features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
                 features_extractor_kwargs: dict[str, Any] | None = None, normalize_images: bool = True,
                 optimizer_class: type[th.optim.Optimizer] = th.optim.RAdam,
                 optimizer_kwargs: dict[str, Any] | None = None, layer_norm: bool = True) -> None:
        super().__init__(observation_space, action_space, features_extractor_class, features_extractor_kwargs,
                         optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                         normalize_images=normalize_images)
        if net_arch is None:
            net_arch = [] if features_extractor_class is LayerNormNatureCNN else [120, 84]
        self.net_arch, self.activation_fn, self.layer_norm = net_arch, activation_fn, layer_norm
        self.features_extractor = self.make_features_extractor()
        layers: list[nn.Module] = []
        width = self.features_extractor.features_dim
        for size in net_arch:
            layers += [nn.Linear(width, size), *([nn.LayerNorm(size)] if layer_norm else []), activation_fn()]
            width = size
        self.q_net = nn.Sequential(*layers, nn.Linear(width, int(action_space.n)))
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    def q_values(self, obs: th.Tensor | dict[str, th.Tensor]) -> th.Tensor:
        """(N, n_actions) Q-values of a batch of observations as the env gives them."""
        return self.q_net(self.extract_features(obs, self.features_extractor))  # type: ignore[no-any-return]

    def forward(self, obs: th.Tensor, deterministic: bool = True) -> th.Tensor:
        return self._predict(obs, deterministic)

    def _predict(self, observation: th.Tensor | dict[str, th.Tensor], deterministic: bool = True) -> th.Tensor:
        return self.q_values(observation).argmax(dim=1).reshape(-1)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(net_arch=self.net_arch, activation_fn=self.activation_fn, layer_norm=self.layer_norm,
                    features_extractor_class=self.features_extractor_class,
                    features_extractor_kwargs=self.features_extractor_kwargs,
                    optimizer_class=self.optimizer_class, optimizer_kwargs=self.optimizer_kwargs)
        return data


class PQNCnnPolicy(PQNPolicy):
    """:class:`PQNPolicy` on images: :class:`LayerNormNatureCNN` features, no further hidden layer."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Discrete, lr_schedule: Schedule,
                 net_arch: list[int] | None = None, activation_fn: type[nn.Module] = nn.ReLU,
                 features_extractor_class: type[BaseFeaturesExtractor] = LayerNormNatureCNN,
                 features_extractor_kwargs: dict[str, Any] | None = None, normalize_images: bool = True,
                 optimizer_class: type[th.optim.Optimizer] = th.optim.RAdam,
                 optimizer_kwargs: dict[str, Any] | None = None, layer_norm: bool = True) -> None:
        super().__init__(observation_space, action_space, lr_schedule, net_arch, activation_fn,
                         features_extractor_class, features_extractor_kwargs, normalize_images, optimizer_class,
                         optimizer_kwargs, layer_norm)


class QLambdaSamples(NamedTuple):
    """A minibatch: observations (B, *obs_shape), actions (B, 1) and Q(lambda) returns (B,)."""

    observations: th.Tensor
    actions: th.Tensor
    returns: th.Tensor


class QLambdaRolloutBuffer(BaseBuffer):
    """One rollout of every env, (n_steps, n_envs) per field, and its Q(lambda) returns
    (:meth:`compute_returns`)."""

    def __init__(self, buffer_size: int, observation_space: spaces.Space, action_space: spaces.Space,
                 device: th.device | str = "auto", n_envs: int = 1) -> None:
        super().__init__(buffer_size, observation_space, action_space, device, n_envs=n_envs)
        shape = get_obs_shape(observation_space)
        assert isinstance(shape, tuple), "PQN reads Box and Discrete observations"
        self.obs_shape: tuple[int, ...] = shape
        self.action_dim = get_action_dim(action_space)
        self.reset()

    def reset(self) -> None:
        shape = (self.buffer_size, self.n_envs)
        self.observations = np.zeros((*shape, *self.obs_shape), dtype=self.observation_space.dtype)
        self.actions = np.zeros((*shape, self.action_dim), dtype=np.int64)
        self.rewards = np.zeros(shape, dtype=np.float32)
        self.episode_starts = np.zeros(shape, dtype=np.float32)
        self.values = np.zeros(shape, dtype=np.float32)
        self.returns = np.zeros(shape, dtype=np.float32)
        super().reset()

    def add(self, obs: np.ndarray, action: np.ndarray, reward: np.ndarray, episode_start: np.ndarray,
            value: th.Tensor) -> None:
        """One step of every env: the observation acted on, the action, the reward, whether the observation starts
        an episode, and ``max_a Q`` of the observation."""
        self.observations[self.pos] = np.array(obs).reshape(self.n_envs, *self.obs_shape)
        self.actions[self.pos] = np.array(action).reshape(self.n_envs, self.action_dim)
        self.rewards[self.pos] = np.array(reward)
        self.episode_starts[self.pos] = np.array(episode_start)
        self.values[self.pos] = value.cpu().numpy().flatten()
        self.pos += 1
        self.full = self.pos == self.buffer_size

    def compute_returns(self, last_values: th.Tensor, dones: np.ndarray, gamma: float, q_lambda: float) -> None:
        """Peng's Q(lambda) returns, backwards from ``last_values`` (``max_a Q`` of the observation after the
        rollout; ``dones``: whether that observation starts a new episode)."""
        next_return = next_value = last_values.cpu().numpy().flatten()
        next_nonterminal = 1.0 - dones.astype(np.float32)
        for t in reversed(range(self.buffer_size)):
            if t < self.buffer_size - 1:
                next_nonterminal = 1.0 - self.episode_starts[t + 1]
                next_value, next_return = self.values[t + 1], self.returns[t + 1]
                target = q_lambda * next_return + (1 - q_lambda) * next_value
            else:
                target = next_value
            self.returns[t] = self.rewards[t] + gamma * target * next_nonterminal

    def get(self, batch_size: int | None = None) -> Generator[QLambdaSamples, None, None]:  # type: ignore[override]
        """Shuffled minibatches of ``batch_size`` transitions (None: one batch of all)."""
        assert self.full, "the rollout is not complete"
        total = self.buffer_size * self.n_envs
        indices = np.random.permutation(total)
        batch_size = batch_size or total
        for start in range(0, total, batch_size):
            yield self._get_samples(indices[start:start + batch_size])

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None  # type: ignore[override]
                     ) -> QLambdaSamples:
        flat = (self.buffer_size * self.n_envs,)
        return QLambdaSamples(self.to_torch(self.observations.reshape(*flat, *self.obs_shape)[batch_inds]),
                              self.to_torch(self.actions.reshape(*flat, self.action_dim)[batch_inds]),
                              self.to_torch(self.returns.reshape(flat)[batch_inds]))


class PQN(OnPolicyAlgorithm):
    """Parallel Q-learning (see the module docstring).

    :param n_steps: steps of every env per rollout.
    :param batch_size: transitions per gradient step (a rollout holds ``n_steps * n_envs``).
    :param n_epochs: passes over each rollout.
    :param q_lambda: the lambda of the Q(lambda) returns (0: one-step Q-learning, 1: Monte Carlo).
    :param exploration_fraction: share of the budget over which epsilon goes from the initial to the final value.
    :param max_grad_norm: the gradient's norm is clipped to this.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": PQNPolicy, "CnnPolicy": PQNCnnPolicy}
    policy: PQNPolicy  # type: ignore[assignment]
    rollout_buffer: QLambdaRolloutBuffer  # type: ignore[assignment]

    def __init__(self, policy: str | type[PQNPolicy], env: GymEnv | str, learning_rate: float | Schedule = 2.5e-4,
                 n_steps: int = 32, batch_size: int = 128, n_epochs: int = 2, gamma: float = 0.99,
                 q_lambda: float = 0.65, exploration_fraction: float = 0.1, exploration_initial_eps: float = 1.0,
                 exploration_final_eps: float = 0.001, max_grad_norm: float = 10.0, stats_window_size: int = 100,
                 tensorboard_log: str | None = None, policy_kwargs: dict[str, Any] | None = None, verbose: int = 0,
                 seed: int | None = None, device: th.device | str = "auto", _init_setup_model: bool = True) -> None:
        super().__init__(policy, env, learning_rate=learning_rate, n_steps=n_steps, gamma=gamma,  # type: ignore[arg-type]
                         gae_lambda=q_lambda, ent_coef=0.0, vf_coef=0.0, max_grad_norm=max_grad_norm, use_sde=False,
                         sde_sample_freq=-1, stats_window_size=stats_window_size, tensorboard_log=tensorboard_log,
                         policy_kwargs=policy_kwargs, verbose=verbose, seed=seed, device=device,
                         _init_setup_model=False, supported_action_spaces=(spaces.Discrete,))
        self.batch_size, self.n_epochs, self.q_lambda = batch_size, n_epochs, q_lambda
        self.exploration_fraction = exploration_fraction
        self.exploration_initial_eps, self.exploration_final_eps = exploration_initial_eps, exploration_final_eps
        self.exploration_rate = exploration_initial_eps
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.exploration_schedule = LinearSchedule(self.exploration_initial_eps, self.exploration_final_eps,
                                                   self.exploration_fraction)
        self.rollout_buffer = QLambdaRolloutBuffer(self.n_steps, self.observation_space, self.action_space,
                                                   self.device, n_envs=self.n_envs)
        self.policy = self.policy_class(self.observation_space, self.action_space, self.lr_schedule,  # type: ignore[assignment]
                                        **self.policy_kwargs).to(self.device)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, rollout_buffer: Any, n_rollout_steps: int
                         ) -> bool:
        """Fill the rollout buffer acting epsilon-greedily (SB3's :meth:`OnPolicyAlgorithm.collect_rollouts`
        contract: False when a callback stopped training)."""
        assert self._last_obs is not None, "no previous observation was provided"
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        n_steps = 0
        while n_steps < n_rollout_steps:
            self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
            with th.no_grad():
                q = self.policy.q_values(obs_as_tensor(self._last_obs, self.device))  # type: ignore[arg-type]
                values, greedy = q.max(dim=1)
            actions = greedy.cpu().numpy()
            explore = np.random.random(env.num_envs) < self.exploration_rate
            actions[explore] = np.random.randint(int(self.action_space.n), size=int(explore.sum()))  # type: ignore[attr-defined]
            new_obs, rewards, dones, infos = env.step(actions)
            self.num_timesteps += env.num_envs
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            n_steps += 1
            for idx, done in enumerate(dones):  # a time limit is not the end: bootstrap from the last observation
                if done and infos[idx].get("terminal_observation") is not None and infos[idx].get(
                        "TimeLimit.truncated", False):
                    terminal = self.policy.obs_to_tensor(infos[idx]["terminal_observation"])[0]
                    with th.no_grad():
                        rewards[idx] += self.gamma * float(self.policy.q_values(terminal).max())
            rollout_buffer.add(self._last_obs, actions, rewards, self._last_episode_starts, values)
            self._last_obs, self._last_episode_starts = new_obs, dones  # type: ignore[assignment]
        with th.no_grad():
            last_values = self.policy.q_values(obs_as_tensor(new_obs, self.device)).max(dim=1).values  # type: ignore[arg-type]
        rollout_buffer.compute_returns(last_values, dones, self.gamma, self.q_lambda)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    def train(self) -> None:
        """``n_epochs`` passes of minibatch regression of ``Q(s, a)`` on the rollout's Q(lambda) returns."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(self.n_epochs):
            for batch in self.rollout_buffer.get(self.batch_size):
                q = self.policy.q_values(batch.observations).gather(1, batch.actions.long()).flatten()
                loss = F.mse_loss(q, batch.returns)
                self.policy.optimizer.zero_grad()
                loss.backward()
                th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
                losses.append(loss.item())
        self._n_updates += self.n_epochs
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))
        self.logger.record("rollout/exploration_rate", self.exploration_rate)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "exploration_schedule"]

