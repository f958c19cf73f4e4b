"""``--robust SPEC``: which robust training a run uses (parsed without importing torch).

``sa:EPS`` is the state-adversarial regularizer (:class:`~sbagents.robust.sa_regularizer.SATD3` /
:class:`~sbagents.robust.sa_regularizer.SADDPG`): eps in the attacks' units (VecNormalize standard deviations, else
the observation Box range), reached by a linear ramp over the first half of training.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from sbagents.errors import UsageError

#: Algorithms each robust method trains, by name.
ROBUST_ALGOS: dict[str, tuple[str, ...]] = {"sa": ("ddpg", "td3")}


@dataclass(frozen=True)
class RobustSpec:
    """A parsed ``--robust`` value.

    :param method: ``"sa"`` (state-adversarial regularization).
    :param eps: the perturbation radius trained against.
    """

    method: str
    eps: float

    def model_class(self, algo: str) -> Any:
        """The SB3 class that trains ``algo`` with this method (imports torch)."""
        from sbagents.robust.sa_regularizer import SADDPG, SATD3

        return {"td3": SATD3, "ddpg": SADDPG}[algo]

    def model_kwargs(self) -> dict[str, Any]:
        """Constructor keywords of :meth:`model_class`."""
        return {"sa_eps": self.eps}


def parse_robust(text: str, algo: str | None = None) -> RobustSpec:
    """``"sa:0.2"`` -> :class:`RobustSpec`; :class:`UsageError` (one line) for anything else, or for an ``algo`` the
    method does not train."""
    method, sep, value = text.partition(":")
    if method not in ROBUST_ALGOS or not sep:
        raise UsageError(f"--robust {text!r}: expected sa:EPS (state-adversarial regularization, e.g. sa:0.2)")
    try:
        eps = float(value)
    except ValueError:
        eps = math.nan
    if not math.isfinite(eps) or eps <= 0:
        raise UsageError(f"--robust {text!r}: EPS must be a finite number > 0")
    if algo is not None and algo not in ROBUST_ALGOS[method]:
        raise UsageError(f"--robust {method} trains {', '.join(ROBUST_ALGOS[method])}, not {algo}")
    return RobustSpec(method, eps)
