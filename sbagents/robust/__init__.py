"""Robust training: state-adversarial (SA) regularization for off-policy actor-critics (Zhang et al., 2020)."""

from sbagents.robust.sa_regularizer import SADDPG, SATD3, SARegularizer, sa_scale

__all__ = ["SADDPG", "SATD3", "SARegularizer", "sa_scale"]
