"""``--constraint lagrangian|pid`` with ``--cost-limit X`` on ``train``: the checks, the table of constrained
algorithms, the zoo key ``constraint_kwargs``, and the constraint's record in ``safety.json`` and ``summary.json``.

A zoo entry sets the constrained class's own keyword arguments under ``constraint_kwargs``; only ``--constraint``
runs use them (the same entry trains the unconstrained agent)::

    sbagents/HazardGridWorld-v0:
      n_steps: 64
      constraint_kwargs:
        cost_vf_learning_rate: 1.0e-3
        multiplier_kwargs:                  # one mapping for both methods, or one per method
          lagrangian: {lr: 0.1}
          pid: {kp: 0.5, ki: 0.1, kd: 0.1, d_delay: 5}

``-params constraint_kwargs:{...}`` replaces the entry's mapping as a whole (as for ``policy_kwargs``). Nothing here
imports torch until a constrained class is asked for.
"""

from __future__ import annotations

import importlib
import inspect
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sbagents.atomic import write_json
from sbagents.constrained.lagrangian import MULTIPLIERS
from sbagents.errors import UsageError

#: Methods of ``--constraint``.
CONSTRAINTS = tuple(MULTIPLIERS)
#: Algorithm -> its constrained class in :mod:`sbagents.constrained`, by name: imported when a run needs it, so the
#: table holds algorithms whose class this install may not have yet.
CONSTRAINED_CLASSES: dict[str, str] = {"ppo": "PPOLagrangian", "sac": "SACLagrangian"}
#: Algorithms ``--constraint`` trains: the declaration of :class:`~sbagents.constrained.extension.ConstraintExtension`
#: (the capability table's ``constrained`` column); tests check that :data:`CONSTRAINED_CLASSES` covers it.
CONSTRAINED_ALGOS: tuple[str, ...] = ("ppo", "sac")
#: The zoo key holding the constrained class's keyword arguments.
CONFIG_KEY = "constraint_kwargs"
_CLI_KWARGS = frozenset({"cost_limit", "constraint"})  # --cost-limit and --constraint set these, never a config


def check_constraint(constraint: str, algo: str, cost_limit: float | None) -> float:
    """Raise :class:`UsageError` (one line) unless ``constraint`` can train ``algo``; return the cost limit."""
    if constraint not in CONSTRAINTS:
        raise UsageError(f"--constraint must be one of {', '.join(CONSTRAINTS)}, got {constraint!r}")
    if algo not in CONSTRAINED_CLASSES:
        raise UsageError(f"--constraint trains {', '.join(CONSTRAINED_ALGOS)}, not {algo}")
    if cost_limit is None:
        raise UsageError("--constraint needs --cost-limit X (the mean episode cost to stay under)")
    if not cost_limit >= 0:
        raise UsageError(f"--cost-limit must be >= 0 with --constraint, got {cost_limit}")
    return float(cost_limit)


def constrained_class(algo: str) -> type[Any]:
    """The constrained class of ``algo`` (:data:`CONSTRAINED_CLASSES`), imported now.

    :raises UsageError: ``algo`` has no constrained version, or this install lacks its class.
    """
    name = CONSTRAINED_CLASSES.get(algo)
    if name is None:
        raise UsageError(f"--constraint trains {', '.join(CONSTRAINED_ALGOS)}, not {algo}")
    cls = getattr(importlib.import_module("sbagents.constrained"), name, None)
    if cls is None:
        raise UsageError(f"--constraint with {algo} needs sbagents.constrained.{name}, which this install lacks")
    return cls  # type: ignore[no-any-return]


def own_keywords(cls: type[Any], base: type[Any]) -> list[str]:
    """Keyword arguments of ``cls`` that its base algorithm ``base`` lacks, but for the CLI's ``cost_limit`` and
    ``constraint``: what ``constraint_kwargs`` may set (e.g. ``multiplier_kwargs``, ``cost_vf_learning_rate``)."""
    inherited = set(inspect.signature(base.__init__).parameters)
    return sorted(
        name for name, p in inspect.signature(cls.__init__).parameters.items()
        if name not in inherited and name not in _CLI_KWARGS and not name.startswith("_")
        and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
    )


def multiplier_kwargs(method: str, cost_limit: float, value: Any, source: str = "") -> dict[str, Any]:
    """The multiplier's keyword arguments for ``method`` from ``value``: one mapping, or one per method
    (``{lagrangian: {...}, pid: {...}}``; a method without one gets the defaults). Checked by building it.

    :raises UsageError: not a mapping, a keyword the method's multiplier lacks, or a value it rejects.
    """
    where = f" ({source})" if source else ""
    if value is not None and not isinstance(value, dict):
        raise UsageError(f"{CONFIG_KEY}: multiplier_kwargs must be a mapping such as {{lr: 0.1}}, got {value!r}{where}")
    kwargs = dict(value or {})
    if kwargs and set(kwargs) <= set(CONSTRAINTS):
        return multiplier_kwargs(method, cost_limit, kwargs.get(method), source)
    cls = MULTIPLIERS[method]
    accepted = [k for k in inspect.signature(cls.__init__).parameters if k not in ("self", "cost_limit")]
    unknown = sorted(str(k) for k in kwargs if k not in accepted)
    if unknown:
        raise UsageError(f"{CONFIG_KEY}: multiplier_kwargs {', '.join(unknown)} do not apply to --constraint "
                         f"{method}{where}; accepted: {', '.join(accepted)}")
    try:
        cls(cost_limit, **kwargs)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{CONFIG_KEY}: multiplier_kwargs of --constraint {method}: {exc}{where}") from None
    return kwargs


@dataclass(frozen=True)
class ConstraintSpec:
    """A checked ``--constraint``: what :func:`sbagents.pipeline.models.make_model` builds.

    :param method: ``lagrangian`` or ``pid``.
    :param cost_limit: the mean episode cost to stay under (``--cost-limit``; None only before the spec is checked by
        :func:`constraint_spec`, which refuses it).
    :param kwargs: the constrained class's other keyword arguments (the config's ``constraint_kwargs``, with
        ``multiplier_kwargs`` resolved for ``method``).
    """

    method: str
    cost_limit: float | None = None
    kwargs: dict[str, Any] = field(default_factory=dict)

    def model_class(self, algo: str) -> type[Any]:
        """The constrained class of ``algo``."""
        return constrained_class(algo)

    def model_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the constrained class."""
        return {"constraint": self.method, "cost_limit": self.cost_limit, **self.kwargs}

    def load_model(self, cls: type[Any], path: Path, trust: bool = False, **kwargs: Any) -> Any:
        """``cls.load(path, **kwargs)`` to continue training (``-i``; without running code from the file unless
        ``trust``, :mod:`sbagents.safe_load`): the saved multiplier keeps its state and settings under this spec's
        cost limit.

        :raises UsageError: the file holds no constrained model, or one trained with another method.
        """
        from sbagents.safe_load import load_model, read_model_data

        saved = read_model_data(path)  # the plain JSON: nothing decoded yet
        if "multiplier" not in saved:
            raise UsageError(f"-i/--trained-agent {path} holds no {cls.__name__} model: --constraint continues a "
                             "--constraint run's model")
        if saved.get("constraint") != self.method:
            raise UsageError(f"-i/--trained-agent was trained with --constraint {saved.get('constraint')}: continue "
                             "it with the same method")
        model = load_model(cls, path, trust=trust, **kwargs)
        model.cost_limit = model.multiplier.cost_limit = self.cost_limit
        return model

    def record(self) -> dict[str, Any]:
        """The run's ``args.yml`` items (with the resolved ``constraint_kwargs``: the run can be repeated)."""
        return {"constraint": self.method, "cost_limit": self.cost_limit, CONFIG_KEY: self.kwargs}


def constraint_spec(method: str, algo: str, cost_limit: float | None, config: Any = None,
                    source: str = "") -> ConstraintSpec:
    """Check ``--constraint method --cost-limit X`` for ``algo`` with the entry's ``constraint_kwargs`` ``config``.

    :param source: where the entry came from, for messages.
    :raises UsageError: (one line) see :func:`check_constraint`, :func:`multiplier_kwargs`; unknown keys.
    """
    from sbagents.algos import ALGOS

    limit = check_constraint(method, algo, cost_limit)
    cls = constrained_class(algo)
    where = f" ({source})" if source else ""
    if config is not None and not isinstance(config, dict):
        raise UsageError(f"{CONFIG_KEY} must be a mapping such as {{multiplier_kwargs: {{lr: 0.1}}}}, got "
                         f"{config!r}{where}")
    kwargs = dict(config or {})
    accepted = own_keywords(cls, ALGOS[algo].cls)
    unknown = sorted(str(k) for k in kwargs if k not in accepted)
    if unknown:
        raise UsageError(f"unknown {CONFIG_KEY} key(s) {', '.join(unknown)} for {cls.__name__}{where}; "
                         f"accepted: {', '.join(accepted)}")
    if "multiplier_kwargs" in kwargs:
        kwargs["multiplier_kwargs"] = multiplier_kwargs(method, limit, kwargs["multiplier_kwargs"], source)
    return ConstraintSpec(method, limit, kwargs)


def check_unconstrained(algo: str, hyperparams: dict[str, Any], overrides: dict[str, Any]) -> None:
    """A run without ``--constraint``: the entry's ``constraint_kwargs`` is left unused (the entry trains both
    runs), but refused where it could never apply: given by ``-params``, or for an algorithm with no constrained
    class."""
    if CONFIG_KEY not in hyperparams:
        return
    if CONFIG_KEY in overrides:
        raise UsageError(f"-params {CONFIG_KEY} configures --constraint runs; add --constraint lagrangian|pid "
                         "--cost-limit X")
    if algo not in CONSTRAINED_CLASSES:
        raise UsageError(f"{CONFIG_KEY} applies to {', '.join(CONSTRAINED_ALGOS)} (with --constraint), not {algo}")


#: Multiplier updates whose measured episode costs make "recent training episodes" (whether the limit held).
RECENT_UPDATES = 10


def record_constraint(run_dir: Path, model: Any) -> dict[str, Any]:
    """Add the constraint's history (timesteps, episode cost, multiplier per rollout) to ``safety.json`` and return
    the summary items: ``constraint`` (method, cost limit, final multiplier, last episode cost, and whether the limit
    held in training: ``train_ep_cost``, the mean of the last :data:`RECENT_UPDATES` updates' episode costs, and
    ``held_in_training``; :func:`judge_evaluation` adds the final evaluation's)."""
    multiplier = model.multiplier  # LagrangeMultiplier or PIDLagrangeMultiplier
    history = list(multiplier.history)
    recent = [float(h["ep_cost"]) for h in history[-RECENT_UPDATES:]]
    train_cost = sum(recent) / len(recent) if recent else None
    item = {
        "method": model.constraint,
        "cost_limit": float(model.cost_limit),
        "multiplier": float(multiplier.value),
        "last_ep_cost": history[-1]["ep_cost"] if history else None,
        "train_ep_cost": train_cost,
        "held_in_training": None if train_cost is None else bool(train_cost <= model.cost_limit),
    }
    path = run_dir / "safety.json"
    data = json.loads(path.read_text()) if path.exists() else {}
    data["constraint"] = {**item, "history": history}
    write_json(path, data)
    return {"constraint": item}


def judge_evaluation(constraint: dict[str, Any], evaluation: Mapping[str, Any]) -> None:
    """Add to a summary's ``constraint`` item whether the limit held in the final evaluation: ``eval_ep_cost`` (its
    mean episode cost) and ``held_in_evaluation`` (None when the evaluation reported no cost)."""
    cost = evaluation.get("mean_cost")
    constraint["eval_ep_cost"] = cost
    constraint["held_in_evaluation"] = None if cost is None else bool(cost <= constraint["cost_limit"])
