"""SB3 callbacks for trustworthy agents (book chapter 6): a per-decision audit log, counted safety
violations, robustness under observation attacks and success per group of episode attributes.

All work with ``model.learn(..., callback=[...])`` on DummyVecEnv, SubprocVecEnv and the multi-agent
``ParameterSharingVecEnv``; the evaluation functions back the ``evaluate`` CLI.
"""

from sbagents.callbacks.adversarial import AdversarialEvalCallback, adversarial_report, evaluate_under_attack
from sbagents.callbacks.attacks import ATTACKS, AttackSpec, ObservationAttacker, parse_attack_spec
from sbagents.callbacks.fairness import FairnessEvalCallback, fairness_report, wilson_interval
from sbagents.callbacks.safety import SafetyViolationCallback, step_violation
from sbagents.callbacks.transparency import TransparencyCSVCallback

__all__: list[str] = [
    "ATTACKS",
    "AdversarialEvalCallback",
    "AttackSpec",
    "FairnessEvalCallback",
    "ObservationAttacker",
    "SafetyViolationCallback",
    "TransparencyCSVCallback",
    "adversarial_report",
    "evaluate_under_attack",
    "fairness_report",
    "parse_attack_spec",
    "step_violation",
    "wilson_interval",
]
