"""DP-SGD for SB3's actor-critics: per-transition gradients clipped and noised by Opacus. Off-policy (DDPG, TD3,
SAC) here; on-policy (PPO, A2C) in :mod:`sbagents.private.on_policy`, through the same :func:`make_private`.

:func:`make_private` turns an SB3 model built with ``replay_buffer_class=PoissonReplayBuffer`` into a private
learner, in place: Opacus's per-sample gradient hooks on the actor and critic networks, their optimizers wrapped
in Opacus ``DPOptimizer`` (clip each transition's gradient to ``max_grad_norm``, add Gaussian noise of std
``noise_multiplier * max_grad_norm`` to the sum, divide by the expected batch size), and a
:class:`~sbagents.private.accounting.PrivacyLedger` fed by the buffer's draws and the optimizers' steps.

The model's ``learn`` and saved files stay plain SB3: target networks are copies of the private ones (post-processing),
and a saved model loads without Opacus. What must not see the data outside the noisy steps is refused: SAC's
automatic entropy coefficient (its loss reads the batch; use a fixed ``ent_coef``), and layers Opacus cannot
compute per-sample gradients for.

For PPO and A2C, ``make_private`` needs ``rollout_buffer_class=PoissonRolloutBuffer`` and ``normalize_advantage=False``
instead, and the ledger is a :class:`~sbagents.private.accounting.RolloutLedger` (epsilon per rollout).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

from sbagents.algos import ALGOS
from sbagents.private.accounting import PrivacyLedger, RolloutLedger, epsilon_of, noise_for_epsilon, planned_draws
from sbagents.private.options import DP_ALGOS
from sbagents.private.replay import PoissonReplayBuffer

#: Off-policy algorithms DP-SGD is wired for (of :data:`~sbagents.private.options.DP_ALGOS`, the algorithms whose
#: class names :func:`make_private` accepts).
OFF_POLICY_DP_ALGOS = tuple(name for name in DP_ALGOS if ALGOS[name].off_policy)


@dataclass
class PrivateTraining:
    """The DP state of a model made private by :func:`make_private`.

    :param ledger: draws and noisy steps so far; ``ledger.epsilon()`` is the privacy spent.
    :param max_grad_norm: the per-transition clipping norm ``C``.
    :param target_epsilon: the budget the noise was calibrated to (None: noise given directly).
    :param unit: what one record of the guarantee is (see docs/private.md).
    """

    ledger: PrivacyLedger
    max_grad_norm: float
    target_epsilon: float | None = None
    unit: str = "transition"

    @property
    def noise_multiplier(self) -> float:
        return self.ledger.noise_multiplier

    def summary(self) -> dict[str, Any]:
        """What ``summary.json`` keeps under ``dp``."""
        out = {"epsilon": _rounded(self.ledger.epsilon()), "delta": self.ledger.delta,
               "noise_multiplier": self.noise_multiplier, "max_grad_norm": self.max_grad_norm,
               "target_epsilon": self.target_epsilon, "accountant": "rdp", "sampling": "poisson",
               "unit": self.unit, "draws": self.ledger.n_draws, "noisy_steps": self.ledger.n_steps}
        if isinstance(self.ledger, RolloutLedger):
            out.update(composition="per rollout (parallel)", rollouts=self.ledger.n_rollouts,
                       epsilon_all_steps=_rounded(self.ledger.epsilon_all_steps()))
        return out


def _rounded(eps: float) -> float | None:
    """Epsilon for JSON: 4 decimals, None for infinity."""
    return round(eps, 4) if math.isfinite(eps) else None


def steps_per_draw(model: OffPolicyAlgorithm) -> tuple[int, ...]:
    """The cycle of noisy steps per draw: critic always, actor every ``policy_delay``-th update (TD3)."""
    delay = int(getattr(model, "policy_delay", 1)) if isinstance(model, TD3) else 1
    return tuple(2 if (i + 1) % delay == 0 else 1 for i in range(delay))


def check_private_model(model: Any) -> None:
    """Raise :class:`ValueError` (one line, saying what fits) for a model DP-SGD cannot be wired into."""
    from opacus.validators import ModuleValidator

    if isinstance(model, OnPolicyAlgorithm):
        from sbagents.private.on_policy import check_on_policy_model

        check_on_policy_model(model)
        return
    if not isinstance(model, DDPG | TD3 | SAC):
        raise ValueError(f"DP training is wired for {', '.join(DP_ALGOS)} (their actor and critic), not "
                         f"{type(model).__name__}")
    if not isinstance(model.replay_buffer, PoissonReplayBuffer):
        raise ValueError("DP training needs replay_buffer_class=PoissonReplayBuffer (the sampling its accounting "
                         "assumes)")
    if isinstance(model, SAC) and model.ent_coef_optimizer is not None:
        raise ValueError("DP training with SAC needs a fixed ent_coef (e.g. ent_coef: 0.05): the automatic one is "
                         "tuned on the batch without noise")
    for name in ("actor", "critic"):
        errors = ModuleValidator.validate(getattr(model, name), strict=False)
        if errors:
            raise ValueError(f"the {name} has layers Opacus cannot privatize ({errors[0]}); use Linear layers and "
                             "element-wise activations (MlpPolicy)")


def make_private(model: BaseAlgorithm, max_grad_norm: float = 1.0, noise_multiplier: float | None = None,
                 target_epsilon: float | None = None, delta: float = 1e-5,
                 total_timesteps: int | None = None) -> PrivateTraining:
    """Make ``model`` train with DP-SGD (in place); give ``noise_multiplier``, or ``target_epsilon`` and
    ``total_timesteps`` to calibrate the noise to the draws ``learn(total_timesteps)`` will make (on-policy: to the
    draws of one rollout, which is what one transition is exposed to).

    :raises ValueError: a model that cannot be made private, or bad privacy parameters.
    """
    from opacus.grad_sample import GradSampleModule
    from opacus.optimizers import DPOptimizer

    check_private_model(model)
    # Opacus's hooks on the first layer fire with no input requiring grad (observations): expected, not a problem
    warnings.filterwarnings("ignore", message="Full backward hook is firing when gradients are computed with "
                            "respect to module outputs", category=UserWarning)
    if max_grad_norm <= 0:
        raise ValueError(f"the clipping norm must be > 0, got {max_grad_norm}")
    if not 0 < delta < 1:
        raise ValueError(f"delta must be in (0, 1), got {delta}")
    if noise_multiplier is None:
        if target_epsilon is None or total_timesteps is None:
            raise ValueError("give noise_multiplier, or target_epsilon with total_timesteps")
        noise_multiplier = noise_for_epsilon(exposure_draws(model, total_timesteps), target_epsilon, delta)
    elif noise_multiplier < 0:
        raise ValueError(f"the noise multiplier must be >= 0, got {noise_multiplier}")
    if isinstance(model, OnPolicyAlgorithm):
        from sbagents.private.on_policy import wire_on_policy

        rollout_ledger = RolloutLedger(noise_multiplier, delta)
        wire_on_policy(model, rollout_ledger, max_grad_norm)
        unit = "transition" if float(getattr(model, "gae_lambda", 0.0)) == 0.0 else "rollout sample"
        return PrivateTraining(rollout_ledger, max_grad_norm, target_epsilon, unit)
    assert isinstance(model, OffPolicyAlgorithm)
    ledger = PrivacyLedger(noise_multiplier, delta)
    buffer = model.replay_buffer
    assert isinstance(buffer, PoissonReplayBuffer)
    buffer.on_draw = ledger.on_draw
    for name in ("actor", "critic"):
        net = getattr(model, name)
        # hooks on its layers, kept alive with it (in __dict__: not a submodule, no cycle in state_dict)
        net.__dict__["_dp_grad_sample_module"] = GradSampleModule(net, loss_reduction="mean")
        optimizer = DPOptimizer(net.optimizer, noise_multiplier=noise_multiplier, max_grad_norm=max_grad_norm,
                                expected_batch_size=model.batch_size, loss_reduction="mean")
        optimizer.attach_step_hook(lambda _opt: ledger.on_step())
        net.optimizer = optimizer
    return PrivateTraining(ledger, max_grad_norm, target_epsilon)


def planned_model_draws(model: BaseAlgorithm, total_timesteps: int) -> Any:
    """The draws ``learn(total_timesteps)`` will make, as ``{(q, k): count}``: off-policy,
    :func:`~sbagents.private.accounting.planned_draws` with ``model``'s own settings; on-policy, every rollout's."""
    if isinstance(model, OnPolicyAlgorithm):
        from sbagents.private.on_policy import planned_on_policy_draws

        return planned_on_policy_draws(model, total_timesteps)
    assert isinstance(model, OffPolicyAlgorithm)
    freq: Any = model.train_freq  # a TrainFreq once the model is set up
    if getattr(freq.unit, "value", freq.unit) != "step":
        raise ValueError("DP calibration to a target epsilon needs train_freq in steps (not episodes)")
    return planned_draws(total_timesteps, model.n_envs, model.batch_size, model.learning_starts, int(freq.frequency),
                         model.gradient_steps, model.buffer_size, steps_per_draw(model))


def exposure_draws(model: BaseAlgorithm, total_timesteps: int) -> Any:
    """The draws one transition is exposed to in ``learn(total_timesteps)``: off-policy, all of them; on-policy, its
    own rollout's (none if no rollout is trained on)."""
    if isinstance(model, OnPolicyAlgorithm):
        from sbagents.private.on_policy import model_rollout_schedule

        return model_rollout_schedule(model) if total_timesteps > 0 else type(model_rollout_schedule(model))()
    return planned_model_draws(model, total_timesteps)


def planned_epsilon(model: BaseAlgorithm, total_timesteps: int, noise_multiplier: float, delta: float) -> float:
    """The epsilon ``learn(total_timesteps)`` will report (for calibration and stopping before a budget)."""
    return epsilon_of(exposure_draws(model, total_timesteps), noise_multiplier, delta)
