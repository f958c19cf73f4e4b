"""The server's aggregation, from Flower's strategies: FedAvg, FedProx and DP-FedAvg, and DP-FedAvg's accounting.

- ``fedavg``: the mean of the homes' parameters (equal weights: every home trains the same ``local_steps``).
- ``fedprox``: the same mean; each home adds ``mu/2 ||w - w_global||^2`` to its losses (Flower's ``FedProx`` sends
  ``proximal-mu``, :func:`sbagents.federated.local.add_proximal_term` applies it).
- ``dp-fedavg``: user-level DP (McMahan et al. 2018): each home clips its update to L2 norm ``dp_clip`` before it
  leaves (Flower's ``fixedclipping_mod``), the server adds N(0, (dp_noise dp_clip / homes)^2) to the mean update
  (``DifferentialPrivacyClientSideFixedClipping``). Every home takes part in every round, so each round is one
  Gaussian mechanism of noise multiplier ``dp_noise`` on a home's data, with no amplification by sampling; the
  epsilon after ``r`` rounds is their RDP composition (:func:`dp_epsilon`). The unit of privacy is a whole home.
  The server adds the noise: the homes trust it to (central DP).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from sbagents.federated.settings import FederatedSettings


def build_strategy(settings: FederatedSettings) -> Any:
    """The Flower strategy of ``settings.strategy``; all homes train every round, none evaluates (the server
    evaluates on held-out homes)."""
    from flwr.serverapp.strategy import DifferentialPrivacyClientSideFixedClipping, FedAvg, FedProx

    common: dict[str, Any] = dict(fraction_train=1.0, fraction_evaluate=0.0, min_train_nodes=settings.homes,
                                  min_available_nodes=settings.homes)
    if settings.strategy == "fedprox":
        return FedProx(proximal_mu=settings.proximal_mu, **common)
    if settings.strategy == "dp-fedavg":
        return DifferentialPrivacyClientSideFixedClipping(FedAvg(**common), noise_multiplier=settings.dp_noise,
                                                          clipping_norm=settings.dp_clip,
                                                          num_sampled_clients=settings.homes)
    return FedAvg(**common)


def dp_epsilon(settings: FederatedSettings, rounds: int) -> float | None:
    """User-level epsilon of DP-FedAvg after ``rounds`` rounds at ``settings.dp_delta`` (None for other strategies):
    ``rounds`` Gaussian mechanisms of noise multiplier ``dp_noise`` at sample rate 1, composed in RDP."""
    if settings.strategy != "dp-fedavg":
        return None
    if rounds <= 0:
        return 0.0
    from sbagents.private.accounting import epsilon_of

    return epsilon_of(Counter({(1.0, 1): rounds}), settings.dp_noise, settings.dp_delta)
