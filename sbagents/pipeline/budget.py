"""Budgets that learn (next to) nothing: a run whose steps end before ``learning_starts`` (off-policy) or within its
first rollout (on-policy) is told so in one warning line before it trains."""

from __future__ import annotations

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm


def budget_warnings(model: BaseAlgorithm, algo: str, n_timesteps: int, steps_before: int = 0) -> list[str]:
    """One line per way in which ``n_timesteps`` more steps of ``model`` will barely train it.

    :param algo: the algorithm's name, for the message.
    :param steps_before: the model's steps before this run (``-i``); SB3 counts ``learning_starts`` from the first.
    """
    warnings: list[str] = []
    end = steps_before + n_timesteps
    if isinstance(model, OffPolicyAlgorithm) and end <= model.learning_starts:
        warnings.append(
            f"the budget ends at {end:,} steps, before learning_starts ({model.learning_starts:,}): {algo} will not "
            "update its networks; raise -n or lower learning_starts (-params learning_starts:N)")
    if isinstance(model, OnPolicyAlgorithm):
        rollout = model.n_steps * model.n_envs
        if n_timesteps < rollout:
            warnings.append(
                f"the budget ({n_timesteps:,} steps) is below one rollout (n_steps {model.n_steps:,} x "
                f"{model.n_envs:,} envs = {rollout:,} steps): {algo} takes {rollout:,} steps and updates once; raise "
                "-n or lower n_steps / n_envs (-params n_steps:N)")
    return warnings
