"""Observation attacks on SB3 policies (SA-MDP, Zhang et al. 2020): random noise, MAD (FGSM/PGD), critic.

Conventions (docs/robust.md):

- What is attacked: the policy's input. Under ``VecNormalize`` (with ``norm_obs``) that is the normalized
  observation and the per-dimension scale is 1 (so ``eps`` is in units of the running std, as in SA-PPO);
  otherwise the raw observation with scale ``high - low`` for dimensions with finite Box bounds (``eps`` is
  a fraction of the declared range) and 1 for unbounded ones. Perturbed observations are clipped to the
  Box bounds (or VecNormalize's ``clip_obs``).
- Discrete / MultiDiscrete / MultiBinary observations are attacked in SB3's one-hot (float) encoding, a
  continuous relaxation: every attack perturbs the one-hot vector (scale 1, clipped to [0, 1]) and the
  policy is evaluated on that vector directly (its observation space is swapped for a Box while it runs).
- ``gaussian``: add N(0, (eps * scale)^2) noise (the book's noise tests; not bounded by the ball).
  ``uniform``: a uniform random point of the L-inf ball of radius ``eps * scale``.
  ``fgsm`` / ``pgd``: the MAD attack (maximise the policy's action deviation) with one signed step / ``steps``
  projected signed steps (PGD starts at a random point of the ball, step size ``2.5 eps / steps``; FGSM
  starts at the clean point except for Box actions, whose MAD gradient vanishes there: R+FGSM, a random
  signed half step then a signed half step). Box actions: ``sum(((a(s~) - a(s)) / sigma)^2)`` with ``a`` the
  deterministic action and ``sigma`` the Gaussian policy's std (1 for squashed / deterministic actors).
  Discrete actions: cross-entropy of the clean greedy action under ``pi(.|s~)`` (Q-values as logits for DQN).
  ``critic`` (DQN, QR-DQN, DDPG, TD3, SAC): PGD that minimises the critic's value of the action taken:
  ``Q(s, a(s~))`` for actor-critics, and for Q-learners pushes ``argmax Q(s~, .)`` towards
  ``argmin Q(s, .)`` (cross-entropy).
- Dict observations are not supported (``ValueError``).
- Recurrent policies (sb3-contrib's ``RecurrentPPO``): every objective is the policy's at the step's hidden state
  (the state before this observation); the attacked observation is what the policy then remembers (the state it
  returns is the one computed from the attacked input), and the state resets where an episode starts.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F  # noqa: N812
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel, BasePolicy
from stable_baselines3.common.vec_env import VecEnv

from sbagents.callbacks.common import find_vec_normalize

ATTACKS: tuple[str, ...] = ("none", "gaussian", "uniform", "fgsm", "pgd", "critic")
_GRADIENT = ("fgsm", "pgd", "critic")


@dataclass(frozen=True)
class AttackSpec:
    """One attack at one strength.

    :param name: one of :data:`ATTACKS` (``none`` = clean evaluation).
    :param eps: L-inf radius (std for ``gaussian``), relative to each dimension's scale (module docstring).
    :param steps: gradient steps (default 1 for ``fgsm``, 10 for ``pgd``/``critic``).
    :param step_size: relative step size (default ``eps`` for FGSM, ``2.5 eps / steps`` otherwise).
    """

    name: str
    eps: float
    steps: int | None = None
    step_size: float | None = None

    def __post_init__(self) -> None:
        if self.name not in ATTACKS:
            raise ValueError(f"unknown attack {self.name!r}; expected one of {', '.join(ATTACKS)}")
        if not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"attack {self.name}: eps must be a finite number >= 0, got {self.eps}")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"attack {self.name}: steps must be >= 1, got {self.steps}")

    @property
    def n_steps(self) -> int:
        """Gradient steps actually used."""
        return self.steps if self.steps is not None else (1 if self.name == "fgsm" else 10)

    @property
    def alpha(self) -> float:
        """Relative step size actually used."""
        if self.step_size is not None:
            return self.step_size
        return self.eps if self.name == "fgsm" else 2.5 * self.eps / self.n_steps

    @property
    def label(self) -> str:
        """``<name>_<eps>``, e.g. ``pgd_0.05`` (TensorBoard tag / CSV key)."""
        return f"{self.name}_{self.eps:g}"


def parse_attack_spec(spec: str | Sequence[str]) -> list[AttackSpec]:
    """Parse ``"gaussian:0.05,0.1 fgsm:0.01"`` (the CLI's ``--attack``/``--adversarial-eval`` value).

    Space-separated items ``name:eps[,eps...][:key=value,...]`` with keys ``steps`` and ``step_size``,
    e.g. ``pgd:0.05,0.1:steps=20``; ``none`` alone is the clean evaluation. A sequence of strings is
    joined with spaces first.

    :raises ValueError: one line naming the bad item.
    """
    text = spec if isinstance(spec, str) else " ".join(spec)
    items = text.split()
    if not items:
        raise ValueError("empty attack spec; expected e.g. 'gaussian:0.05,0.1 fgsm:0.01'")
    out: list[AttackSpec] = []
    for item in items:
        parts = item.split(":")
        name = parts[0].lower()
        try:
            if name == "none" and len(parts) == 1:
                out.append(AttackSpec("none", 0.0))
                continue
            if len(parts) not in (2, 3) or not parts[1]:
                raise ValueError("expected name:eps[,eps...][:steps=N,step_size=X]")
            options: dict[str, float] = {}
            for opt in parts[2].split(",") if len(parts) == 3 else []:
                key, sep, value = opt.partition("=")
                if not sep or key not in ("steps", "step_size"):
                    raise ValueError(f"unknown option {opt!r} (allowed: steps=N, step_size=X)")
                options[key] = float(value)
            steps = int(options["steps"]) if "steps" in options else None
            for eps in parts[1].split(","):
                out.append(AttackSpec(name, float(eps), steps, options.get("step_size")))
        except ValueError as exc:
            raise ValueError(f"invalid attack spec {item!r}: {exc}") from None
    return out


def _encode(obs: np.ndarray, space: spaces.Space) -> th.Tensor:
    """SB3's float encoding of a batch of observations (one-hot for discrete spaces)."""
    x = th.as_tensor(np.asarray(obs))
    if isinstance(space, spaces.Discrete):
        return F.one_hot((x.long() - int(space.start)).reshape(-1), int(space.n)).float()
    if isinstance(space, spaces.MultiDiscrete):
        x = x.long().reshape(-1, len(space.nvec))
        return th.cat([F.one_hot(x[:, i], int(n)).float() for i, n in enumerate(space.nvec)], dim=1)
    if isinstance(space, (spaces.Box, spaces.MultiBinary)):
        return x.float().reshape(-1, *space.shape)
    raise ValueError(f"observation attacks support Box and discrete observations, not {type(space).__name__}")


def observation_scale(space: spaces.Space, env: VecEnv | None = None) -> np.ndarray:
    """Per-component scale of a Box policy input, the unit of every attack's ``eps`` (module docstring).

    :param space: the (Box) observation space.
    :param env: the VecEnv the policy acts in; its ``VecNormalize`` (with ``norm_obs``), if any, makes the scale 1.
    :return: ``obs_shape`` float32 array: ones under ``VecNormalize(norm_obs=True)``, else ``high - low`` where both
        bounds are finite and 1 elsewhere.
    :raises ValueError: for a non-Box ``space``.
    """
    if not isinstance(space, spaces.Box):
        raise ValueError(f"observation_scale needs a Box observation space, not {type(space).__name__}")
    vn = find_vec_normalize(env) if env is not None else None
    if vn is not None and vn.norm_obs:
        return np.ones(space.shape, dtype=np.float32)
    finite = np.isfinite(space.low) & np.isfinite(space.high)
    with np.errstate(invalid="ignore", over="ignore"):
        return np.where(finite, space.high - space.low, 1.0).astype(np.float32)


@contextlib.contextmanager
def relaxed_observation_space(policy: BasePolicy, dim: int) -> Iterator[None]:
    """Swap the observation space of every sub-model of ``policy`` for ``Box(0, 1, (dim,))`` while active,
    so SB3's preprocessing accepts an already one-hot encoded (and perturbed) float tensor."""
    if isinstance(policy.observation_space, spaces.Box):
        yield
        return
    box = spaces.Box(0.0, 1.0, (dim,), dtype=np.float32)
    models = [m for m in policy.modules() if isinstance(m, BaseModel)]
    saved = [m.observation_space for m in models]
    try:
        for m in models:
            m.observation_space = box
        yield
    finally:
        for m, space in zip(models, saved, strict=True):
            m.observation_space = space


class ObservationAttacker:
    """Perturb the policy's input with an :class:`AttackSpec` and return the policy's env actions.

    :param policy: an SB3 policy (``model.policy``).
    :param env: the evaluation VecEnv (its ``VecNormalize``, if any, decides the attacked space).
    :param attack: the attack.
    :param seed: seed of the attack's own random numbers (noise, random starts).
    """

    def __init__(self, policy: BasePolicy, env: VecEnv, attack: AttackSpec, seed: int | None = None) -> None:
        self.policy, self.attack = policy, attack
        space = policy.observation_space
        self.obs_space = space
        if isinstance(space, spaces.Dict):
            raise ValueError("observation attacks do not support Dict observations")
        if attack.name != "none" and not any(p.requires_grad for p in policy.parameters()):
            raise ValueError(
                f"observation attacks need a neural-network policy; {type(policy).__name__} has no trainable "
                "network (a tabular policy indexes a table by the exact observation)"
            )
        if attack.name == "critic" and not (hasattr(policy, "critic") or hasattr(policy, "q_net")):
            raise ValueError(
                "the critic attack needs a Q-function (DQN, QR-DQN, DDPG, TD3, SAC), "
                f"not {type(policy).__name__}"
            )
        self.gen = th.Generator().manual_seed(seed if seed is not None else int(np.random.randint(2**31 - 1)))
        vn = find_vec_normalize(env)
        dim_shape = _encode(space.sample()[None], space).shape[1:]
        if isinstance(space, spaces.Box):
            self.scale = th.as_tensor(observation_scale(space, env))
            if vn is not None and vn.norm_obs:
                self.low, self.high = th.full(dim_shape, -vn.clip_obs), th.full(dim_shape, vn.clip_obs)
            else:
                self.low = th.as_tensor(space.low, dtype=th.float32)
                self.high = th.as_tensor(space.high, dtype=th.float32)
        else:
            self.scale, self.low, self.high = th.ones(dim_shape), th.zeros(dim_shape), th.ones(dim_shape)
        self.dim = int(np.prod(dim_shape))
        self.device = policy.device
        self.scale, self.low, self.high = (t.to(self.device) for t in (self.scale, self.low, self.high))
        self.max_perturbation = 0.0
        self.recurrent = hasattr(policy, "lstm_hidden_state_shape")
        #: the hidden state and episode starts of the step being attacked (recurrent policies only)
        self._memory: tuple[tuple[th.Tensor, th.Tensor], th.Tensor] | None = None

    # ------------------------------------------------------------------ the policy at this step
    def _distribution(self, x: th.Tensor) -> Any:
        """The policy's action distribution at ``x`` (at this step's hidden state for a recurrent policy)."""
        if self._memory is not None:
            states, starts = self._memory
            recurrent: Any = self.policy
            return recurrent.get_distribution(x, states, starts)[0]
        return self.policy.get_distribution(x)  # type: ignore[operator]

    def _actions(self, x: th.Tensor, deterministic: bool = True) -> th.Tensor:
        """The policy's actions at ``x`` (in the policy's own space, before rescaling)."""
        if self._memory is not None:
            states, starts = self._memory
            recurrent: Any = self.policy
            return recurrent._predict(x, states, starts, deterministic)[0]  # type: ignore[no-any-return]
        return self.policy._predict(x, deterministic=deterministic)

    # ------------------------------------------------------------------ objectives
    def _logits(self, x: th.Tensor) -> th.Tensor:
        policy = self.policy
        if hasattr(policy, "get_distribution"):
            return self._distribution(x).distribution.logits  # type: ignore[no-any-return]
        q = policy.q_net(x)  # type: ignore[operator]
        return q.mean(dim=1) if q.dim() == 3 else q  # QR-DQN: (batch, quantiles, actions)

    def _objective(self, x: th.Tensor) -> Callable[[th.Tensor], th.Tensor]:
        """The function of ``x_adv`` (per-sample losses) that the attack maximises."""
        policy = self.policy
        discrete = isinstance(policy.action_space, spaces.Discrete)
        with th.no_grad():
            if self.attack.name == "critic" and hasattr(policy, "q_net") and discrete:
                worst = self._logits(x).argmin(dim=1)
                return lambda xa: -F.cross_entropy(self._logits(xa), worst, reduction="none")
            if self.attack.name == "critic":
                return lambda xa: -policy.critic(x, self._actions(xa))[0].sum(dim=1)  # type: ignore[operator]
            if discrete:
                clean = self._logits(x).argmax(dim=1)
                return lambda xa: F.cross_entropy(self._logits(xa), clean, reduction="none")
            ref = self._actions(x).reshape(len(x), -1)
            sigma = th.ones_like(ref)
            if isinstance(policy, ActorCriticPolicy):
                dist = self._distribution(x).distribution
                if isinstance(dist, th.distributions.Normal):
                    sigma = dist.stddev.reshape(len(x), -1).clamp_min(1e-6)

        def mad(xa: th.Tensor) -> th.Tensor:
            action = self._actions(xa).reshape(len(x), -1)
            return (((action - ref) / sigma) ** 2).sum(dim=1)

        return mad

    # ------------------------------------------------------------------ perturbation
    def _project(self, xa: th.Tensor, x: th.Tensor, radius: th.Tensor) -> th.Tensor:
        xa = th.max(th.min(xa, x + radius), x - radius)
        return th.max(th.min(xa, self.high), self.low)

    def _rand_like(self, x: th.Tensor) -> th.Tensor:
        return (th.rand(x.shape, generator=self.gen) * 2.0 - 1.0).to(x.device)

    def _randn_like(self, x: th.Tensor) -> th.Tensor:
        return th.randn(x.shape, generator=self.gen).to(x.device)

    def perturb(self, x: th.Tensor) -> th.Tensor:
        """The attacked version of the encoded observation batch ``x`` (same shape)."""
        attack, name = self.attack, self.attack.name
        if name == "none" or attack.eps == 0:
            return x
        radius = attack.eps * self.scale
        if name == "gaussian":
            noise = self._randn_like(x) * radius
            return th.max(th.min(x + noise, self.high), self.low)
        if name == "uniform":
            return self._project(x + self._rand_like(x) * radius, x, radius)
        with relaxed_observation_space(self.policy, self.dim):
            return self._gradient_attack(x, radius)

    def _gradient_attack(self, x: th.Tensor, radius: th.Tensor) -> th.Tensor:
        attack, name = self.attack, self.attack.name
        objective = self._objective(x)
        alpha = attack.alpha * self.scale
        box_mad = name == "fgsm" and isinstance(self.policy.action_space, spaces.Box)
        if name == "fgsm" and not box_mad:
            xa = x.clone()
        elif box_mad:  # R+FGSM: the MAD gradient vanishes at the clean point
            xa = self._project(x + 0.5 * radius * th.sign(self._randn_like(x)), x, radius)
            alpha = 0.5 * alpha
        else:
            xa = self._project(x + self._rand_like(x) * radius, x, radius)
        for _ in range(attack.n_steps):
            xa = xa.detach().requires_grad_(True)
            (grad,) = th.autograd.grad(objective(xa).sum(), xa)
            xa = self._project(xa.detach() + alpha * th.sign(grad), x, radius)
        return xa.detach()

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Env actions of a stateless policy on the attacked observations ``obs`` (a VecEnv batch)."""
        if self.recurrent:
            raise ValueError("a recurrent policy acts with step(obs, state, episode_start)")
        return self.step(obs, None, np.zeros(len(obs), dtype=bool), deterministic)[0]

    def step(self, obs: np.ndarray, state: Any, episode_start: np.ndarray, deterministic: bool = True
             ) -> tuple[np.ndarray, Any]:
        """The :class:`~sbagents.callbacks.episodes.Policy` step on the attacked observations: env actions of the
        policy for the VecEnv batch ``obs``, and its next hidden state (None for a stateless policy).

        :param state: the previous step's state (None at the first step: zeros).
        :param episode_start: ``(n_envs,)`` bools, True where an episode starts (the state is reset there).
        """
        policy: Any = self.policy
        x = _encode(obs, self.obs_space).to(self.device)
        new_state = None
        if self.recurrent:
            if state is None:
                zeros = np.zeros((*policy.lstm_hidden_state_shape[:1], len(x),
                                  *policy.lstm_hidden_state_shape[2:]), dtype=np.float32)
                state = (zeros, zeros)
            states = (th.as_tensor(state[0], dtype=th.float32, device=self.device),
                      th.as_tensor(state[1], dtype=th.float32, device=self.device))
            self._memory = (states, th.as_tensor(np.asarray(episode_start), dtype=th.float32, device=self.device))
        try:
            with relaxed_observation_space(policy, self.dim):
                xa = self.perturb(x)
                with th.no_grad():
                    if self._memory is not None:
                        chosen, next_states = policy._predict(xa, *self._memory, deterministic)
                        new_state = tuple(t.cpu().numpy() for t in next_states)
                    else:
                        chosen = policy._predict(xa, deterministic=deterministic)
                    actions = chosen.cpu().numpy()
        finally:
            self._memory = None
        if self.attack.name != "none" and self.attack.eps > 0:
            rel = ((xa - x).abs() / self.scale).max().item()
            self.max_perturbation = max(self.max_perturbation, float(rel))
        space = policy.action_space
        if isinstance(space, spaces.Box):
            actions = actions.reshape((-1, *space.shape))
            if policy.squash_output:
                actions = policy.unscale_action(actions)
            else:
                actions = np.clip(actions, space.low, space.high)
        return actions, new_state
