"""Tabular Q-learning and SARSA (the book's first agent, chapter 2) as Stable-Baselines3 algorithms.

Both subclass SB3's ``BaseAlgorithm``: save/load, logger, tensorboard, callbacks, progress bar and Monitor
episode statistics work as for DQN. The Q-table is a CPU float64 torch parameter of :class:`TabularPolicy`,
shape ``(n_states, n_actions)``; training updates it in place through a numpy view sharing its memory, so
``save``/``predict`` always see the current values without copies.

Targets for ``(s, a, r, s')``: Q-learning ``r + gamma * max_b Q[s', b]``; SARSA ``r + gamma * Q[s', a']``
with ``a'`` the epsilon-greedy action then taken in ``s'``. Termination: target ``r``. Truncation
(``info["TimeLimit.truncated"]``): bootstrap from ``info["terminal_observation"]`` (SB3 auto-resets).
``k`` envs updating the same ``(s, a)`` in one vec step act as ``k`` sequential updates towards their mean
target: ``Q += (1 - (1 - alpha) ** k) * mean_td``. Acting breaks greedy ties at random (seeded);
``predict(deterministic=True)`` takes the lowest index.
"""

from __future__ import annotations

import time
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import BaseAlgorithm, maybe_make_env
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, PyTorchObs, Schedule
from stable_baselines3.common.utils import LinearSchedule, is_vectorized_observation, safe_mean
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from sbagents.errors import UsageError

SelfTabular = TypeVar("SelfTabular", bound="TabularAlgorithm")
RecurrentState = tuple[np.ndarray, ...] | None  # SB3's predict() state, unused here
Observation = np.ndarray | dict[str, np.ndarray] | int | np.integer  # one (shape ()) or a batch (shape (n,))


def check_tabular_spaces(algo_name: str, observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """Raise :class:`~sbagents.errors.UsageError` (a ``ValueError``) unless both spaces are ``Discrete``."""
    obs_ok, act_ok = isinstance(observation_space, spaces.Discrete), isinstance(action_space, spaces.Discrete)
    if obs_ok and act_ok:
        return
    bad = [f"observation space {observation_space}"] if not obs_ok else []
    bad += [f"action space {action_space}"] if not act_ok else []
    use = "dqn, ppo or a2c" if act_ok else "ppo"
    use = "ppo, sac or td3" if isinstance(action_space, spaces.Box) else use
    what = f"{type(observation_space).__name__} observations"
    what = what if not obs_ok else f"{type(action_space).__name__} actions"
    raise UsageError(f"{algo_name} needs Discrete observation and action spaces (tabular); "
                     f"got {' and '.join(bad)}. For {what} use {use}.")


class TabularPolicy(BasePolicy):
    """Greedy policy over a Q-table ``q_table`` of shape ``(n_states, n_actions)``.

    :param observation_space: ``Discrete(n_states, start=s0)``; row ``i`` is observation ``s0 + i``.
    :param action_space: ``Discrete(n_actions, start=a0)``; column ``j`` is action ``a0 + j``.
    :param lr_schedule: unused (no optimizer); SB3 passes it to every policy.
    :param initial_q: initial value of every entry (optimistic values encourage exploration).
    :param normalize_images: unused; kept for SB3's policy save/load.
    """

    q_table: nn.Parameter

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space,
                 lr_schedule: Schedule | None = None, initial_q: float = 0.0, normalize_images: bool = True
                 ) -> None:
        check_tabular_spaces(type(self).__name__, observation_space, action_space)
        assert isinstance(observation_space, spaces.Discrete) and isinstance(action_space, spaces.Discrete)
        super().__init__(observation_space, action_space, normalize_images=normalize_images)
        self.initial_q = float(initial_q)
        self.n_states, self.n_actions = int(observation_space.n), int(action_space.n)
        self.obs_start, self.action_start = int(observation_space.start), int(action_space.start)
        table = th.full((self.n_states, self.n_actions), self.initial_q, dtype=th.float64)
        self.q_table = nn.Parameter(table, requires_grad=False)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(lr_schedule=self._dummy_schedule, initial_q=self.initial_q)
        return data

    def table(self) -> np.ndarray:
        """Numpy view ``(n_states, n_actions)`` of the Q-table, sharing memory with ``q_table``."""
        return self.q_table.detach().cpu().numpy()

    def state_index(self, observation: np.ndarray) -> np.ndarray:
        """Row indices ``(n,)`` int64 of observations; ValueError when one is outside the space."""
        index = np.asarray(observation, dtype=np.int64).reshape(-1) - self.obs_start
        if index.size and (index.min() < 0 or index.max() >= self.n_states):
            raise ValueError(f"observation {observation!r} is outside the space {self.observation_space}")
        return index

    def q_values(self, obs: th.Tensor) -> th.Tensor:
        """Q-values of a batch of observations: ``(n,)`` -> ``(n, n_actions)``."""
        return self.q_table[th.as_tensor(self.state_index(obs.cpu().numpy()))]

    def forward(self, obs: th.Tensor, deterministic: bool = True) -> th.Tensor:
        """Greedy actions ``(n,)`` for observations ``(n,)``."""
        return self._predict(obs, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        assert isinstance(observation, th.Tensor)
        return self.q_values(observation).argmax(dim=1) + self.action_start  # first maximum on ties


class TabularAlgorithm(BaseAlgorithm):
    """Shared machinery of :class:`QLearning` and :class:`SARSA`: epsilon-greedy acting and TD updates.

    :param policy: ``"TabularPolicy"`` (``"MlpPolicy"`` is an alias) or a :class:`TabularPolicy` subclass.
    :param env: env (or Gymnasium ID) with ``Discrete`` observation and action spaces; any ``n_envs``.
    :param learning_rate: step size alpha, a float or a schedule of ``progress_remaining`` (1 -> 0).
    :param gamma: discount factor.
    :param exploration_initial_eps: epsilon at the start of training.
    :param exploration_final_eps: epsilon after ``exploration_fraction`` of the training budget.
    :param exploration_fraction: fraction of ``total_timesteps`` over which epsilon decays linearly.
    :param initial_q: initial value of every Q-table entry.
    :param policy_kwargs: extra keyword arguments of the policy class.
    :param tensorboard_log: tensorboard log folder (None: no tensorboard).
    :param verbose: 0 silent, 1 training logs, 2 debug.
    :param seed: seed of the env, the action space and the algorithm's numpy Generator (all its randomness).
    :param device: accepted for SB3 compatibility; the Q-table always lives on the CPU.
    :param _init_setup_model: whether to build the policy (False when loading).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = dict(TabularPolicy=TabularPolicy,
                                                                 MlpPolicy=TabularPolicy)
    policy: TabularPolicy
    exploration_schedule: Schedule
    #: True: bootstrap from the behaviour policy's next action (SARSA); False: from the greedy one.
    on_policy_target: ClassVar[bool] = False

    def __init__(
        self,
        policy: str | type[TabularPolicy] = "TabularPolicy",
        env: GymEnv | str | None = None,
        learning_rate: float | Schedule = 0.1,
        gamma: float = 0.9,
        exploration_initial_eps: float = 0.1,
        exploration_final_eps: float = 0.1,
        exploration_fraction: float = 1.0,
        initial_q: float = 0.0,
        policy_kwargs: dict[str, Any] | None = None,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "cpu",
        _init_setup_model: bool = True,
    ) -> None:
        name = type(self).__name__
        if not isinstance(policy, (str, type)):
            raise TypeError(f"{name}'s first argument is the policy name; pass the environment as env=...")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma}")
        if not (0.0 <= exploration_initial_eps <= 1.0 and 0.0 <= exploration_final_eps <= 1.0):
            raise ValueError(f"epsilons must be in [0, 1]: {exploration_initial_eps} {exploration_final_eps}")
        if exploration_fraction <= 0.0:
            raise ValueError(f"exploration_fraction must be > 0, got {exploration_fraction}")
        if env is not None:  # our clear error first, before SB3's asserts
            env = maybe_make_env(env, verbose)
            check_tabular_spaces(name, env.observation_space, env.action_space)
        del device  # a table lookup gains nothing from an accelerator
        super().__init__(policy, env, learning_rate, policy_kwargs, tensorboard_log=tensorboard_log,
                         verbose=verbose, device="cpu", support_multi_env=True, seed=seed,
                         supported_action_spaces=(spaces.Discrete,))
        self.gamma = gamma
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        self.initial_q = initial_q
        #: Current epsilon of the behaviour policy (also used by ``predict(deterministic=False)``).
        self.exploration_rate = exploration_initial_eps
        self._next_actions: np.ndarray | None = None  # SARSA: a' already chosen for the next vec step
        self._rng = np.random.default_rng(seed)
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        self.set_random_seed(self.seed)
        self.exploration_schedule = LinearSchedule(self.exploration_initial_eps, self.exploration_final_eps,
                                                   self.exploration_fraction)
        if not (isinstance(self.policy_class, type) and issubclass(self.policy_class, TabularPolicy)):
            raise ValueError(f"{type(self).__name__} needs a TabularPolicy, got {self.policy_class}")
        try:
            self.policy = self.policy_class(self.observation_space, self.action_space, self.lr_schedule,
                                            initial_q=self.initial_q, **self.policy_kwargs)
        except TypeError as err:
            msg = f"TabularPolicy has no network: bad policy_kwargs {self.policy_kwargs} ({err})"
            raise ValueError(msg) from err

    def set_random_seed(self, seed: int | None = None) -> None:
        """Seed python, numpy, torch, the action space, the env and the algorithm's own Generator."""
        super().set_random_seed(seed)
        self._rng = np.random.default_rng(seed) if seed is not None else self._rng

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_rng"]

    @property
    def q_table(self) -> np.ndarray:
        """The live Q-table ``(n_states, n_actions)`` float64 (writing to it changes the policy)."""
        return self.policy.table()

    def _act_one(self, row: list[float], eps: float) -> int:
        """Epsilon-greedy action index for one state's Q-values (random greedy tie-breaking)."""
        u = self._rng.random()
        if u < eps:  # u / eps is uniform on [0, 1) given u < eps
            return min(int(u / eps * len(row)), len(row) - 1)
        best = max(row)
        if row.count(best) == 1:
            return row.index(best)
        ties = [i for i, v in enumerate(row) if v == best]
        return ties[int(self._rng.random() * len(ties))]

    def _behaviour(self, q: np.ndarray, states: np.ndarray, eps: float) -> np.ndarray:
        """Epsilon-greedy action indices ``(n,)`` for state indices ``(n,)``, random greedy tie-breaking."""
        if states.shape[0] == 1:
            return np.array([self._act_one(q[states[0]].tolist(), eps)])
        n_actions = q.shape[1]
        draws = self._rng.random((states.shape[0], n_actions + 1))
        values = q[states]
        # tied maxima get +1, so argmax picks one of them uniformly at random
        actions = (draws[:, :n_actions] + (values == values.max(axis=1, keepdims=True))).argmax(axis=1)
        if eps > 0.0:
            u = draws[:, n_actions]
            explore = u < eps
            if explore.any():
                actions[explore] = np.minimum(u[explore] / eps * n_actions, n_actions - 1).astype(np.int64)
        return actions

    def _learn_step(self, q: np.ndarray, states: np.ndarray, actions: np.ndarray, rewards: np.ndarray,
                    next_states: np.ndarray, bootstrap: np.ndarray, alpha: float, eps: float
                    ) -> np.ndarray | None:
        """TD update of the table ``q`` in place for one vec step (all arrays ``(n,)``; ``bootstrap`` is 0.0
        on termination, else 1.0). Returns SARSA's next action indices ``a'`` ``(n,)``, None for Q-learning.
        """
        if states.shape[0] == 1:  # scalar fast path, about 3x cheaper than the vectorised one
            s, a, row = int(states[0]), int(actions[0]), q[int(next_states[0])].tolist()
            a_next = self._act_one(row, eps) if self.on_policy_target else -1
            value = row[a_next] if self.on_policy_target else max(row)
            q[s, a] += alpha * (float(rewards[0]) + self.gamma * float(bootstrap[0]) * value - q[s, a])
            return np.array([a_next]) if self.on_policy_target else None
        next_actions = None
        if self.on_policy_target:
            next_actions = self._behaviour(q, next_states, eps)
            values = q[next_states, next_actions]
        else:
            values = q[next_states].max(axis=1)
        q_flat, flat = q.reshape(-1), states * q.shape[1] + actions
        td = rewards + self.gamma * bootstrap * values - q_flat[flat]
        ordered = np.sort(flat)
        if (ordered[1:] == ordered[:-1]).any():  # duplicates: k sequential updates towards the mean target
            uniq, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
            mean_td = np.bincount(inverse, weights=td, minlength=uniq.size) / counts
            q_flat[uniq] += (1.0 - (1.0 - alpha) ** counts) * mean_td
        else:
            q_flat[flat] += alpha * td
        return next_actions

    def learn(self: SelfTabular, total_timesteps: int, callback: MaybeCallback = None,
              log_interval: int | None = 4, tb_log_name: str = "Tabular", reset_num_timesteps: bool = True,
              progress_bar: bool = False) -> SelfTabular:
        """Train for ``total_timesteps`` env steps, one TD update per env step.

        :param total_timesteps: env steps to train on (a vec step counts ``n_envs``).
        :param callback: SB3 callback(s); ``on_step`` returning False stops training.
        :param log_interval: dump the logs every this many episodes (None: never).
        :param tb_log_name: name of the tensorboard run.
        :param reset_num_timesteps: restart the step counter (and the env) instead of continuing.
        :param progress_bar: show a tqdm/rich progress bar.
        :return: this model, trained.
        """
        self._next_actions = None if reset_num_timesteps or self._last_obs is None else self._next_actions
        total_timesteps, callback = self._setup_learn(total_timesteps, callback, reset_num_timesteps,
                                                      tb_log_name, progress_bar)
        callback.on_training_start(locals(), globals())
        assert self.env is not None, "You must set the environment before calling learn()"
        env: VecEnv = self.env
        n_envs, q, all_bootstrap = env.num_envs, self.policy.table(), np.ones(env.num_envs)
        obs_start, action_start = self.policy.obs_start, self.policy.action_start
        states = np.asarray(self._last_obs, dtype=np.int64).reshape(n_envs) - obs_start
        self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
        self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
        next_actions = self._next_actions

        while self.num_timesteps < total_timesteps:
            callback.on_rollout_start()
            eps = self.exploration_rate
            action_idx = self._behaviour(q, states, eps) if next_actions is None else next_actions
            actions = action_idx + action_start
            new_obs, rewards, dones, infos = env.step(actions)
            assert isinstance(new_obs, np.ndarray)
            self.num_timesteps += n_envs
            callback.update_locals(locals())
            if not callback.on_step():  # like SB3: this last transition is not learned
                self._last_obs, self._last_episode_starts, self._next_actions = new_obs, dones, None
                break

            self._update_info_buffer(infos, dones)
            next_states = new_obs.astype(np.int64).reshape(n_envs) - obs_start
            target_states, bootstrap = next_states, all_bootstrap
            done_idx = np.flatnonzero(dones) if dones.any() else ()
            if len(done_idx):  # SB3 auto-reset: new_obs already starts the next episode
                target_states, bootstrap = next_states.copy(), all_bootstrap.copy()
                for i in done_idx:
                    target_states[i] = int(infos[i]["terminal_observation"]) - obs_start
                    bootstrap[i] = float(infos[i].get("TimeLimit.truncated", False))
            alpha = self.lr_schedule(self._current_progress_remaining)
            next_actions = self._learn_step(q, states, action_idx, rewards, target_states, bootstrap, alpha,
                                            eps)
            self._n_updates += n_envs
            if next_actions is not None and len(done_idx):  # SARSA: a new episode starts with a new action
                next_actions[done_idx] = self._behaviour(q, next_states[done_idx], eps)
            states = next_states
            self._last_obs, self._last_episode_starts, self._next_actions = new_obs, dones, next_actions

            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)
            self.exploration_rate = self.exploration_schedule(self._current_progress_remaining)
            for _ in done_idx:
                self._episode_num += 1
                if log_interval is not None and self._episode_num % log_interval == 0:
                    self.dump_logs()
            callback.on_rollout_end()

        callback.on_training_end()
        return self

    def dump_logs(self) -> None:
        """Write the logs: episodes, mean episode return/length, success rate, epsilon, alpha, fps."""
        assert self.ep_info_buffer is not None and self.ep_success_buffer is not None
        elapsed = max((time.time_ns() - self.start_time) / 1e9, 1e-9)
        record = self.logger.record
        record("time/episodes", self._episode_num, exclude="tensorboard")
        if self.ep_info_buffer:
            record("rollout/ep_rew_mean", safe_mean([info["r"] for info in self.ep_info_buffer]))
            record("rollout/ep_len_mean", safe_mean([info["l"] for info in self.ep_info_buffer]))
        if self.ep_success_buffer:
            record("rollout/success_rate", safe_mean(self.ep_success_buffer))
        record("rollout/exploration_rate", self.exploration_rate)
        record("train/learning_rate", self.lr_schedule(self._current_progress_remaining))
        record("train/n_updates", self._n_updates, exclude="tensorboard")
        record("time/fps", int((self.num_timesteps - self._num_timesteps_at_start) / elapsed))
        record("time/time_elapsed", int(elapsed), exclude="tensorboard")
        record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)

    def predict(self, observation: Observation, state: RecurrentState = None,
                episode_start: np.ndarray | None = None, deterministic: bool = False
                ) -> tuple[np.ndarray, RecurrentState]:
        """Epsilon-greedy action(s) with ``exploration_rate``, like ``DQN.predict`` (but per observation).

        :param observation: one observation (shape ``()``) or a batch (shape ``(n,)``).
        :param state: unused (no recurrent state); returned unchanged.
        :param episode_start: unused.
        :param deterministic: greedy actions (lowest index on ties) instead of epsilon-greedy.
        :return: actions (shape ``()`` or ``(n,)``) and ``state``.
        """
        if isinstance(observation, (tuple, dict)):
            raise ValueError("predict() takes an observation array, not a tuple or dict (with the Gymnasium "
                             "API use `obs, info = env.reset()` and pass `obs`)")
        obs = np.asarray(observation)
        vectorized = is_vectorized_observation(obs, self.observation_space)
        states, q = self.policy.state_index(obs), self.policy.table()
        if deterministic or self.exploration_rate <= 0.0:
            actions = q[states].argmax(axis=1)
        else:
            actions = self._behaviour(q, states, self.exploration_rate)
        actions = actions + self.policy.action_start
        return (actions if vectorized else actions.squeeze(axis=0)), state


class QLearning(TabularAlgorithm):
    """Tabular Q-learning (off-policy TD control), target ``r + gamma * max_a Q(s', a)``. The book's agent is
    ``QLearning(env=gym.make("sbagents/GridWorld-v0"))`` with its defaults (alpha 0.1, gamma 0.9, eps 0.1).
    Parameters: see :class:`TabularAlgorithm`."""

    on_policy_target = False

    def learn(self: SelfTabular, total_timesteps: int, callback: MaybeCallback = None,
              log_interval: int | None = 4, tb_log_name: str = "QLearning", reset_num_timesteps: bool = True,
              progress_bar: bool = False) -> SelfTabular:
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps,
                             progress_bar)


class SARSA(TabularAlgorithm):
    """Tabular SARSA (on-policy TD control), target ``r + gamma * Q(s', a')``, ``a'`` the next action taken.
    Parameters: see :class:`TabularAlgorithm`."""

    on_policy_target = True

    def learn(self: SelfTabular, total_timesteps: int, callback: MaybeCallback = None,
              log_interval: int | None = 4, tb_log_name: str = "SARSA", reset_num_timesteps: bool = True,
              progress_bar: bool = False) -> SelfTabular:
        return super().learn(total_timesteps, callback, log_interval, tb_log_name, reset_num_timesteps,
                             progress_bar)


__all__ = ["SARSA", "QLearning", "TabularAlgorithm", "TabularPolicy", "check_tabular_spaces"]
