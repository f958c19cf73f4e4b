"""The ``--dp-*`` flags of ``python -m sbagents.train`` as an option group (no Opacus or torch import here)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from sbagents.capabilities import Capability
from sbagents.core.env_kinds import SINGLE_AGENT
from sbagents.errors import UsageError

#: Algorithms DP-SGD is wired for (off-policy first; :func:`sbagents.private.dp_sgd.make_private` takes their classes):
#: the declaration of :class:`~sbagents.private.extension.PrivacyExtension`.
DP_ALGOS: tuple[str, ...] = ("ddpg", "td3", "sac", "a2c", "ppo")
#: DP-SGD training: single-agent envs (one model's data) and :data:`DP_ALGOS`; the capability table's ``dp`` column.
DP_TRAINING = Capability("dp", "DP-SGD training (--dp-*)", DP_ALGOS, (SINGLE_AGENT.name,), label="DP training (--dp-*)",
                         refusal="{label} is for {algos}, whose networks Opacus privatizes; not {algo}")


@dataclass(frozen=True, kw_only=True)
class PrivacyOptions:
    """What the ``--dp-*`` flags asked for (all None / default: no DP).

    :param epsilon: the privacy budget: calibrate the noise to it (or, with ``noise``, stop before passing it).
    :param delta: the delta of (epsilon, delta)-DP; must be below 1 / the number of transitions trained on.
    :param clip: per-transition gradient clipping norm ``C``.
    :param noise: noise multiplier ``sigma`` (noise std / C) instead of a calibrated one.
    """

    epsilon: float | None = None
    delta: float = 1e-5
    clip: float = 1.0
    noise: float | None = None

    @property
    def enabled(self) -> bool:
        """Whether DP training is asked for (an epsilon or a noise multiplier)."""
        return self.epsilon is not None or self.noise is not None

    def validate(self) -> None:
        """One-line :class:`UsageError` for values out of range."""
        if self.epsilon is not None and not (self.epsilon > 0 and math.isfinite(self.epsilon)):
            raise UsageError(f"--dp-epsilon must be a finite number > 0, got {self.epsilon}")
        if self.noise is not None and not (self.noise > 0 and math.isfinite(self.noise)):
            raise UsageError(f"--dp-noise must be a finite number > 0, got {self.noise}")
        if not 0 < self.delta < 1:
            raise UsageError(f"--dp-delta must be in (0, 1), got {self.delta}")
        if not (self.clip > 0 and math.isfinite(self.clip)):
            raise UsageError(f"--dp-clip must be a finite number > 0, got {self.clip}")
