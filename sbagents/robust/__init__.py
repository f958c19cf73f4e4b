"""Robust training for off-policy actor-critics: the state-adversarial (SA) regularizer (Zhang et al., 2020) and
adversarial rollouts (a share of the training steps act on attacked observations)."""

from sbagents.robust.adversarial_rollouts import (
    AdvDDPG,
    AdversarialRollouts,
    AdvSAC,
    AdvTD3,
    SAAdvDDPG,
    SAAdvTD3,
)
from sbagents.robust.sa_regularizer import SADDPG, SATD3, SARegularizer, ramped_eps

__all__ = ["SADDPG", "SATD3", "AdvDDPG", "AdvSAC", "AdvTD3", "AdversarialRollouts", "SAAdvDDPG", "SAAdvTD3",
           "SARegularizer", "ramped_eps"]
