"""Training one SB3 model per group of agents side by side on one team: :func:`learn_in_lockstep`.

Each model runs its own, unchanged SB3 ``learn`` (rollouts or replay, gradient steps, callbacks, logging) on its
group's VecEnv, in a thread of its own; the threads take turns at every env step
(:class:`~sbagents.multiagent.joint.Turns`), so only one runs at a time and the run is as reproducible as a
single-model one. Every model takes the same number of env steps: the budget is rounded up to a whole number of
rollouts (on-policy ``n_steps``) or training intervals (off-policy ``train_freq``), which must then be equal for all
groups.

Ctrl-C or SIGTERM in the main thread (and a failure, or a callback that stops one model early) stops every model
at its next env step; the models keep what they learned and can be saved.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.type_aliases import TrainFrequencyUnit

from sbagents.errors import UsageError
from sbagents.multiagent.joint import JointStepper, LockstepAborted, Turns


def step_granularity(model: BaseAlgorithm) -> int:
    """The env steps a model takes between two of its checks of the budget (``n_steps`` or ``train_freq``)."""
    if isinstance(model, OnPolicyAlgorithm):
        return int(model.n_steps)
    if isinstance(model, OffPolicyAlgorithm):
        freq = model.train_freq
        if freq.unit != TrainFrequencyUnit.STEP:  # type: ignore[union-attr]
            raise UsageError("per-group training needs train_freq counted in steps, not episodes")
        return int(freq.frequency)  # type: ignore[union-attr]
    return 1


def lockstep_budget(models: dict[str, BaseAlgorithm], env_steps: int) -> dict[str, int]:
    """Each model's ``total_timesteps`` so that all take the same whole number of env (vec) steps >= ``env_steps``.

    :raises UsageError: models whose rollout lengths (or training intervals) differ.
    """
    sizes = {g: step_granularity(m) for g, m in models.items()}
    if len(set(sizes.values())) > 1:
        raise UsageError(f"per-group models step in lockstep and need equal n_steps/train_freq, got {sizes}")
    unit = next(iter(sizes.values()))
    steps = math.ceil(env_steps / unit) * unit
    return {g: steps * m.get_env().num_envs for g, m in models.items()}  # type: ignore[union-attr]


def learn_in_lockstep(
    joint: JointStepper, models: dict[str, BaseAlgorithm], env_steps: int,
    callbacks: Mapping[str, Sequence[BaseCallback]] | None = None, log_interval: int = 1,
    reset_num_timesteps: bool = True,
) -> None:
    """``learn`` every group's model for ``env_steps`` team steps (rounded up, see :func:`lockstep_budget`).

    :param joint: the team coordinator of the models' VecEnvs (one per group, in ``joint.order``).
    :param models: group -> model; each model's env is its group's VecEnv (possibly wrapped, e.g. VecNormalize).
    :param callbacks: group -> its callbacks.
    :raises KeyboardInterrupt: after Ctrl-C or SIGTERM, once every model has stopped.
    """
    order = joint.order
    budget = lockstep_budget(models, env_steps)
    turns = Turns(len(order))
    joint.turns = turns
    errors: list[BaseException] = []

    def body(index: int, group: str) -> None:
        try:
            turns.wait(index)
            models[group].learn(budget[group], callback=list((callbacks or {}).get(group, [])),
                                log_interval=log_interval, reset_num_timesteps=reset_num_timesteps)
        except LockstepAborted:
            pass  # another group stopped: this one stops too, keeping what it learned
        except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
            errors.append(exc)
            turns.stop(f"{group} failed: {exc!r}")
        finally:
            turns.finish(index)

    threads = [threading.Thread(target=body, args=(i, g), name=f"sbagents-{g}", daemon=True)
               for i, g in enumerate(order)]
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            while thread.is_alive():
                thread.join(timeout=0.2)  # a short join keeps Ctrl-C / SIGTERM responsive
    except KeyboardInterrupt:
        turns.stop("interrupted")
        for thread in threads:
            thread.join()
        raise
    finally:
        joint.turns = None
    if errors:
        raise errors[0]


def first_group_callbacks(order: list[str], first: Sequence[BaseCallback], each: dict[str, list[BaseCallback]]
                          ) -> dict[str, list[BaseCallback]]:
    """Callbacks per group: ``first`` (progress, team evaluation) on the first group's model only, then each
    group's own."""
    return {g: [*(first if i == 0 else []), *each.get(g, [])] for i, g in enumerate(order)}
