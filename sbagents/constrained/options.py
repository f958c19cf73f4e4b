"""``--constraint lagrangian|pid`` with ``--cost-limit X`` on ``train``: checks (without importing torch) and the
constraint's record in ``safety.json`` and ``summary.json``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError

#: Methods of ``--constraint`` and the algorithms they train.
CONSTRAINTS = ("lagrangian", "pid")
CONSTRAINED_ALGOS = ("ppo",)


def check_constraint(constraint: str, algo: str, cost_limit: float | None) -> float:
    """Raise :class:`UsageError` (one line) unless ``constraint`` can train ``algo``; return the cost limit."""
    if constraint not in CONSTRAINTS:
        raise UsageError(f"--constraint must be one of {', '.join(CONSTRAINTS)}, got {constraint!r}")
    if algo not in CONSTRAINED_ALGOS:
        raise UsageError(f"--constraint trains {', '.join(CONSTRAINED_ALGOS)} (PPO-Lagrangian), not {algo}")
    if cost_limit is None:
        raise UsageError("--constraint needs --cost-limit X (the mean episode cost to stay under)")
    if not cost_limit >= 0:
        raise UsageError(f"--cost-limit must be >= 0 with --constraint, got {cost_limit}")
    return float(cost_limit)


def record_constraint(run_dir: Path, model: Any) -> dict[str, Any]:
    """Add the constraint's history (timesteps, episode cost, multiplier per rollout) to ``safety.json`` and return
    the summary items: ``constraint`` (method, cost limit, final multiplier, last episode cost)."""
    multiplier = model.multiplier  # LagrangeMultiplier or PIDLagrangeMultiplier
    history = list(multiplier.history)
    item = {
        "method": model.constraint,
        "cost_limit": float(model.cost_limit),
        "multiplier": float(multiplier.value),
        "last_ep_cost": history[-1]["ep_cost"] if history else None,
    }
    path = run_dir / "safety.json"
    data = json.loads(path.read_text()) if path.exists() else {}
    data["constraint"] = {**item, "history": history}
    path.write_text(json.dumps(data, indent=2) + "\n")
    return {"constraint": item}
