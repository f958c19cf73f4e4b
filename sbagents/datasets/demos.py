"""Demonstrations in the replay buffer (``train --demos DATASET``): an off-policy model's batches mix a set share of
recorded transitions with its own (Nair et al. 2018, "Overcoming Exploration in Reinforcement Learning with
Demonstrations"; Hester et al. 2018, DQfD's demonstration replay).

The model's buffer class is the demonstration-mixing twin of the class it would use (:func:`demo_buffer_class`):
:class:`DemoReplayBuffer` (which is a :class:`DemoDictReplayBuffer` on ``Dict`` observations, as SB3 picks
``DictReplayBuffer``) or :class:`DemoHerReplayBuffer`. Until :meth:`DemoMixin.attach_demos` gives it the
demonstrations it is its base class; afterwards ``sample(batch_size)`` draws ``round(ratio * batch_size)`` samples
from a second buffer of the base class that holds only the demonstrations (relabelled by HER like the model's own
transitions in goal envs: its own episodes, its own future goals) and the rest from the model's transitions. The
demonstrations are never overwritten and never saved with the run's replay buffer: a continued run (``-i``) reads them
from the dataset again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sbagents.datasets.reading import Episode
from sbagents.errors import UsageError


class DemoMixin:
    """Sampling that mixes demonstrations into a replay buffer's batches (see the module docstring)."""

    #: the buffer class the demonstrations are kept in (the model's own, without the mixing)
    base_class: type[BaseBuffer]
    demos: BaseBuffer | None = None
    demo_ratio: float = 0.0

    @property
    def saved_as(self) -> str:
        """The buffer class whose file this buffer writes and reads (:func:`sbagents.state_files.save_replay_buffer`):
        :attr:`base_class`'s, since the demonstrations are not saved; so ``-i`` may add or drop ``--demos``."""
        return self.base_class.__name__

    def attach_demos(self, demos: BaseBuffer, ratio: float) -> None:
        """Mix ``demos`` (a filled buffer of :attr:`base_class`) into every batch at ``ratio`` (in [0, 1])."""
        if not 0 <= ratio <= 1:
            raise ValueError(f"the demonstration ratio must be in [0, 1], got {ratio}")
        self.demos, self.demo_ratio = demos, ratio

    def demo_count(self, batch_size: int) -> int:
        """How many of a batch of ``batch_size`` come from the demonstrations."""
        return 0 if self.demos is None else int(round(self.demo_ratio * batch_size))

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> Any:
        """``batch_size`` samples: :meth:`demo_count` of them from the demonstrations, then the model's own."""
        n_demo = self.demo_count(batch_size)
        own = super().sample  # type: ignore[misc]
        if n_demo == 0:
            return own(batch_size, env=env)
        assert self.demos is not None
        demo = self.demos.sample(n_demo, env=env)
        if n_demo == batch_size:
            return demo
        return concatenate([own(batch_size - n_demo, env=env), demo])


class DemoReplayBuffer(DemoMixin, ReplayBuffer):
    """SB3's :class:`~stable_baselines3.common.buffers.ReplayBuffer` with demonstrations mixed in; built for a
    ``Dict`` observation space it is a :class:`DemoDictReplayBuffer` (as SB3 picks ``DictReplayBuffer``)."""

    base_class = ReplayBuffer

    def __new__(cls, buffer_size: int = 0, observation_space: spaces.Space[Any] | None = None, *args: Any,
                **kwargs: Any) -> Any:  # defaults: copy and pickle call __new__ without arguments
        if cls is DemoReplayBuffer and isinstance(observation_space, spaces.Dict):
            return DemoDictReplayBuffer(buffer_size, observation_space, *args, **kwargs)
        return super().__new__(cls)


class DemoDictReplayBuffer(DemoMixin, DictReplayBuffer):
    """SB3's ``DictReplayBuffer`` with demonstrations mixed in."""

    base_class = DictReplayBuffer


class DemoHerReplayBuffer(DemoMixin, HerReplayBuffer):
    """SB3's ``HerReplayBuffer`` with demonstrations mixed in; the demonstrations are relabelled with goals of their own
    episodes (HER's strategy and ratio)."""

    base_class = HerReplayBuffer


_DEMO_CLASSES: dict[type, type[DemoMixin]] = {
    ReplayBuffer: DemoReplayBuffer, DictReplayBuffer: DemoDictReplayBuffer, HerReplayBuffer: DemoHerReplayBuffer}


def demo_buffer_class(base: type | None) -> type[DemoMixin]:
    """The demonstration-mixing class of the buffer class ``base`` (None: SB3's default, ``ReplayBuffer`` or
    ``DictReplayBuffer`` by the observation space).

    :raises UsageError: a buffer class of another kind (e.g. a private or a constrained run's own buffer).
    """
    if base is None:
        return DemoReplayBuffer
    if issubclass(base, DemoMixin):  # already the twin (a resolved experiment given again)
        return base
    try:
        return _DEMO_CLASSES[base]
    except KeyError:
        raise UsageError(f"--demos mixes demonstrations into ReplayBuffer, DictReplayBuffer or HerReplayBuffer, not "
                         f"{getattr(base, '__name__', base)}") from None


def concatenate(batches: Sequence[Any]) -> Any:
    """One batch of SB3 samples (``ReplayBufferSamples``, ``DictReplayBufferSamples``) from several, field by field
    along the batch dimension (dict observations key by key; a field that is None in every batch stays None)."""
    fields: dict[str, Any] = {}
    for name in batches[0]._fields:
        values = [getattr(batch, name) for batch in batches]
        if all(value is None for value in values):
            fields[name] = None
        elif isinstance(values[0], dict):
            fields[name] = {key: torch.cat([value[key] for value in values]) for key in values[0]}
        else:
            fields[name] = torch.cat(values)
    return type(batches[0])(**fields)


def demo_buffer(model: OffPolicyAlgorithm, episodes: Sequence[Episode]) -> BaseBuffer:
    """A buffer of the model's base buffer class holding ``episodes`` (one env; actions in the buffer's scale, as the
    model stores its own: ``[-1, 1]`` for a ``Box``); an episode that neither terminated nor was truncated is taken as
    truncated at its last step (it bootstraps there).

    :raises UsageError: the model's buffer does not mix demonstrations.
    """
    buffer = model.replay_buffer
    if not isinstance(buffer, DemoMixin):
        raise UsageError(f"--demos needs the model's replay buffer to mix demonstrations, it is a "
                         f"{type(buffer).__name__}")
    kwargs = dict(model.replay_buffer_kwargs)
    if issubclass(buffer.base_class, HerReplayBuffer):
        kwargs["env"] = model.get_env()
    size = sum(len(episode) for episode in episodes) + 1  # never full: HER drops episodes a full buffer overwrites
    demos = buffer.base_class(size, model.observation_space, model.action_space, device=model.device, n_envs=1,
                              **kwargs)
    box = isinstance(model.action_space, spaces.Box)
    for episode in episodes:
        actions = np.asarray(model.policy.scale_action(episode.actions)) if box else episode.actions
        last = len(episode) - 1
        for t in range(len(episode)):
            terminated = bool(episode.terminations[t])
            done = terminated or bool(episode.truncations[t]) or t == last
            demos.add(_one(episode.observation(t)), _one(episode.observation(t + 1)),  # type: ignore[call-arg]
                      np.asarray(actions[t])[None], np.asarray([episode.rewards[t]], dtype=np.float32),
                      np.asarray([done]), [{"TimeLimit.truncated": done and not terminated}])
    return demos


def _one(obs: Any) -> Any:
    """An observation as one env's batch (a leading axis of 1)."""
    return {k: np.asarray(v)[None] for k, v in obs.items()} if isinstance(obs, dict) else np.asarray(obs)[None]
