"""Federated homes: one policy learned across homes whose users differ, with Flower; only parameters leave a home.

``python -m sbagents.federated`` (docs/federated.md). :mod:`~sbagents.federated.homes` draws the homes' users,
:mod:`~sbagents.federated.local` is one home's learner, :mod:`~sbagents.federated.strategies` the server's
aggregation (FedAvg, FedProx, DP-FedAvg), :mod:`~sbagents.federated.apps` the Flower ServerApp and ClientApp,
:mod:`~sbagents.federated.runner` a whole run (simulation or a real deployment) into a normal run dir.
Needs the ``private`` extra (Flower and Opacus).
"""
