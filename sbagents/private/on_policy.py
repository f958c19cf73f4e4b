"""DP-SGD for SB3's on-policy actor-critics (PPO, A2C): per-transition gradients of the whole loss, clipped and noised.

:func:`make_private_on_policy` (through :func:`~sbagents.private.dp_sgd.make_private`) wires, in place:

- Opacus's per-sample gradient hooks on every layer of ``model.policy`` (features extractor, MLP extractor,
  action and value heads) and ``model.policy.optimizer`` wrapped in an Opacus ``DPOptimizer``. One noisy step clips
  each transition's gradient of the *whole* loss (policy loss + ``vf_coef`` * value loss - ``ent_coef`` * entropy;
  A2C's the same without the ratio clipping), over *all* the policy's parameters, to ``max_grad_norm``.
- Gaussian policies' ``log_std``: a bare ``nn.Parameter`` of the policy that Opacus's layer hooks never see. It stays
  trainable: :class:`PerSampleLogStd` hands the distribution one copy of it per sample (the same parameter,
  expanded), whose per-sample gradient Opacus then has exactly (the gradient of a broadcast parameter is the
  per-sample gradient of its copy), so it is clipped with the rest. The saved model keeps SB3's plain ``log_std``.
- Batches: ``rollout_buffer_class=PoissonRolloutBuffer`` (:mod:`sbagents.private.rollout`); the ledger is a
  :class:`~sbagents.private.accounting.RolloutLedger`.

Refused, because they read the batch outside the noisy steps or mix samples in one sample's loss: PPO's
``normalize_advantage`` (mean and std over the minibatch: one transition's loss would depend on the others),
``target_kl`` (early stopping on the batch's KL, without noise), gSDE (``use_sde``: its noise weights are not
per-sample), and dict observations. SB3's own ``max_grad_norm`` (``clip_grad_norm_`` on the whole batch's
gradient before ``optimizer.step()``) acts on the ordinary gradient, which ``DPOptimizer`` then replaces by the noisy
sum of the clipped per-sample gradients: it changes nothing and is harmless; ``--dp-clip`` is the clipping that counts.
"""

from __future__ import annotations

import warnings
from typing import Any

import torch
from gymnasium import spaces
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.distributions import DiagGaussianDistribution, Distribution
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from sbagents.private.accounting import RolloutLedger, planned_rollouts, rollout_schedule
from sbagents.private.rollout import PoissonRolloutBuffer


class PerSampleLogStd(nn.Module):
    """Holds a Gaussian policy's ``log_std`` (the same parameter, not a copy) and returns it once per sample, so
    that Opacus computes its per-sample gradient (:func:`_log_std_grad_sample`)."""

    def __init__(self, log_std: nn.Parameter) -> None:
        super().__init__()
        self.log_std = log_std

    def forward(self, mean_actions: torch.Tensor) -> torch.Tensor:
        """``log_std`` repeated for each row of ``mean_actions``: shape ``(n, action_dim)``."""
        return self.log_std.unsqueeze(0).expand(mean_actions.shape[0], -1)


def _log_std_grad_sample(layer: PerSampleLogStd, activations: list[torch.Tensor],
                         backprops: torch.Tensor) -> dict[nn.Parameter, torch.Tensor]:
    """Opacus grad sampler of :class:`PerSampleLogStd`: sample ``i``'s gradient is the gradient of its row."""
    return {layer.log_std: backprops} if layer.log_std.requires_grad else {}


def register_log_std_sampler() -> None:
    """Register :func:`_log_std_grad_sample` with Opacus (idempotent)."""
    from opacus.grad_sample import register_grad_sampler

    register_grad_sampler(PerSampleLogStd)(_log_std_grad_sample)


def check_on_policy_model(model: Any) -> None:
    """Raise :class:`ValueError` (one line, saying what fits) for an on-policy model DP-SGD cannot be wired into."""
    from opacus.validators import ModuleValidator

    if not isinstance(model, PPO | A2C):
        raise ValueError(f"DP training is wired for PPO and A2C among on-policy algorithms, not {type(model).__name__}")
    if not isinstance(model.rollout_buffer, PoissonRolloutBuffer):
        raise ValueError("DP training needs rollout_buffer_class=PoissonRolloutBuffer (the sampling its accounting "
                         "assumes)")
    if model.normalize_advantage:
        raise ValueError("DP training needs normalize_advantage=False: normalizing over the minibatch makes one "
                         "transition's loss depend on the others")
    if getattr(model, "target_kl", None) is not None:
        raise ValueError("DP training cannot use target_kl: its early stopping reads the batch without noise")
    if model.use_sde:
        raise ValueError("DP training does not support use_sde (gSDE's exploration weights are not per-sample)")
    policy = model.policy
    if not isinstance(policy, ActorCriticPolicy) or isinstance(model.observation_space, spaces.Dict):
        raise ValueError("DP training with PPO/A2C needs MlpPolicy or CnnPolicy (no dict observations)")
    for name, child in policy.named_children():
        errors = ModuleValidator.validate(child, strict=False)
        if errors:
            raise ValueError(f"the policy's {name} has layers Opacus cannot privatize ({errors[0]}); use Linear "
                             "layers and element-wise activations (MlpPolicy)")


def per_sample_log_std(policy: ActorCriticPolicy) -> PerSampleLogStd | None:
    """For a Gaussian policy, route ``log_std`` through a :class:`PerSampleLogStd` (kept with the policy, not a
    submodule: its ``state_dict`` is unchanged); None for other action distributions."""
    if not isinstance(policy.action_dist, DiagGaussianDistribution):
        return None
    module = PerSampleLogStd(policy.log_std)
    policy.__dict__["_dp_log_std"] = module

    def dist_from_latent(latent_pi: torch.Tensor) -> Distribution:
        mean_actions = policy.action_net(latent_pi)
        # detached input: the module's output depends on log_std only, so Opacus's backward hook must fire on the
        # output's gradient (it would wait for an input gradient that never comes)
        log_std = module(mean_actions.detach())
        return policy.action_dist.proba_distribution(mean_actions, log_std)  # type: ignore[call-arg]

    policy.__dict__["_get_action_dist_from_latent"] = dist_from_latent  # instance attribute: this policy only
    return module


def wire_on_policy(model: OnPolicyAlgorithm, ledger: RolloutLedger, max_grad_norm: float) -> None:
    """Hooks, ``DPOptimizer`` and the ledger's listeners on ``model`` (checked by :func:`check_on_policy_model`)."""
    from opacus.grad_sample import GradSampleModule
    from opacus.optimizers import DPOptimizer

    register_log_std_sampler()
    warnings.filterwarnings("ignore", message="Full backward hook is firing when gradients are computed with "
                            "respect to module outputs", category=UserWarning)
    policy = model.policy
    wrapped: list[nn.Module] = [child for _, child in policy.named_children()
                                if any(p.requires_grad for p in child.parameters())]
    log_std = per_sample_log_std(policy)
    if log_std is not None:
        wrapped.append(log_std)
    # hooks on the layers, kept alive with the policy (in __dict__: no submodule, no change to state_dict)
    policy.__dict__["_dp_grad_sample_modules"] = [GradSampleModule(m, loss_reduction="mean") for m in wrapped]
    buffer = model.rollout_buffer
    assert isinstance(buffer, PoissonRolloutBuffer)
    buffer.on_draw, buffer.on_rollout = ledger.on_draw, ledger.on_rollout
    optimizer = DPOptimizer(policy.optimizer, noise_multiplier=ledger.noise_multiplier, max_grad_norm=max_grad_norm,
                            expected_batch_size=expected_batch_size(model), loss_reduction="mean")
    optimizer.attach_step_hook(lambda _opt: ledger.on_step())
    policy.optimizer = optimizer


def expected_batch_size(model: OnPolicyAlgorithm) -> int:
    """The mean size of a Poisson minibatch: PPO's ``batch_size`` (at most the rollout), A2C's whole rollout."""
    n = model.n_steps * model.n_envs
    batch_size = getattr(model, "batch_size", None) if isinstance(model, PPO) else None
    return n if batch_size is None else min(int(batch_size), n)


def model_rollout_schedule(model: OnPolicyAlgorithm) -> Any:
    """:func:`~sbagents.private.accounting.rollout_schedule` with ``model``'s settings."""
    batch_size = model.batch_size if isinstance(model, PPO) else None
    n_epochs = model.n_epochs if isinstance(model, PPO) else 1
    return rollout_schedule(model.n_steps * model.n_envs, batch_size, n_epochs)


def planned_on_policy_draws(model: OnPolicyAlgorithm, total_timesteps: int) -> Any:
    """Every draw ``learn(total_timesteps)`` will make (all rollouts), as ``{(q, k): count}``."""
    schedule = model_rollout_schedule(model)
    rollouts = planned_rollouts(total_timesteps, model.n_steps * model.n_envs)
    return type(schedule)({key: n * rollouts for key, n in schedule.items()})
