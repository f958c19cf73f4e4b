"""DP-SGD for SB3's off-policy actor-critics (DDPG, TD3, SAC): per-transition gradients clipped and noised by Opacus.

:func:`make_private` turns an SB3 model built with ``replay_buffer_class=PoissonReplayBuffer`` into a private
learner, in place: Opacus's per-sample gradient hooks on the actor and critic networks, their optimizers wrapped
in Opacus ``DPOptimizer`` (clip each transition's gradient to ``max_grad_norm``, add Gaussian noise of std
``noise_multiplier * max_grad_norm`` to the sum, divide by the expected batch size), and a
:class:`~sbagents.private.accounting.PrivacyLedger` fed by the buffer's draws and the optimizers' steps.

The model's ``learn`` and saved files stay plain SB3: target networks are copies of the private ones (post-processing),
and a saved model loads without Opacus. What must not see the data outside the noisy steps is refused: SAC's
automatic entropy coefficient (its loss reads the batch; use a fixed ``ent_coef``), and layers Opacus cannot
compute per-sample gradients for.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

from stable_baselines3 import DDPG, SAC, TD3
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sbagents.private.accounting import PrivacyLedger, noise_for_epsilon, planned_draws
from sbagents.private.replay import PoissonReplayBuffer

#: Algorithms DP-SGD is wired for (the class names accepted by :func:`make_private`).
DP_ALGOS = ("ddpg", "td3", "sac")


@dataclass
class PrivateTraining:
    """The DP state of a model made private by :func:`make_private`.

    :param ledger: draws and noisy steps so far; ``ledger.epsilon()`` is the privacy spent.
    :param max_grad_norm: the per-transition clipping norm ``C``.
    :param target_epsilon: the budget the noise was calibrated to (None: noise given directly).
    """

    ledger: PrivacyLedger
    max_grad_norm: float
    target_epsilon: float | None = None

    @property
    def noise_multiplier(self) -> float:
        return self.ledger.noise_multiplier

    def summary(self) -> dict[str, Any]:
        """What ``summary.json`` keeps under ``dp``."""
        eps = self.ledger.epsilon()
        return {"epsilon": round(eps, 4) if math.isfinite(eps) else None, "delta": self.ledger.delta,
                "noise_multiplier": self.noise_multiplier, "max_grad_norm": self.max_grad_norm,
                "target_epsilon": self.target_epsilon, "accountant": "rdp", "sampling": "poisson",
                "unit": "transition", "draws": self.ledger.n_draws, "noisy_steps": self.ledger.n_steps}


def steps_per_draw(model: OffPolicyAlgorithm) -> tuple[int, ...]:
    """The cycle of noisy steps per draw: critic always, actor every ``policy_delay``-th update (TD3)."""
    delay = int(getattr(model, "policy_delay", 1)) if isinstance(model, TD3) else 1
    return tuple(2 if (i + 1) % delay == 0 else 1 for i in range(delay))


def check_private_model(model: Any) -> None:
    """Raise :class:`ValueError` (one line, saying what fits) for a model DP-SGD cannot be wired into."""
    from opacus.validators import ModuleValidator

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


def make_private(model: OffPolicyAlgorithm, max_grad_norm: float = 1.0, noise_multiplier: float | None = None,
                 target_epsilon: float | None = None, delta: float = 1e-5,
                 total_timesteps: int | None = None) -> PrivateTraining:
    """Make ``model`` train with DP-SGD (in place); give ``noise_multiplier``, or ``target_epsilon`` and
    ``total_timesteps`` to calibrate the noise to the draws ``learn(total_timesteps)`` will make.

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
        noise_multiplier = noise_for_epsilon(planned_model_draws(model, total_timesteps), target_epsilon, delta)
    elif noise_multiplier < 0:
        raise ValueError(f"the noise multiplier must be >= 0, got {noise_multiplier}")
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


def planned_model_draws(model: OffPolicyAlgorithm, total_timesteps: int) -> Any:
    """:func:`~sbagents.private.accounting.planned_draws` with ``model``'s own settings."""
    freq: Any = model.train_freq  # a TrainFreq once the model is set up
    if getattr(freq.unit, "value", freq.unit) != "step":
        raise ValueError("DP calibration to a target epsilon needs train_freq in steps (not episodes)")
    return planned_draws(total_timesteps, model.n_envs, model.batch_size, model.learning_starts, int(freq.frequency),
                         model.gradient_steps, model.buffer_size, steps_per_draw(model))
