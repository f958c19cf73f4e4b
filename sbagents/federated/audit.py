"""What left the homes: every reply a home sent, described where the server receives it (``federated.json``:
``replies``). A reply should hold the home's parameters (``arrays``: the global model's names and shapes) and
``num-examples`` (``metrics``), nothing else; DP-FedAvg's replies also have an update norm within the clip."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def describe_reply(server_round: int, reply: Any, sent: Any) -> dict[str, Any]:
    """One reply (a Flower ``Message``) against the global arrays ``sent`` that round (an ``ArrayRecord``)."""
    if reply.has_error():
        return {"round": server_round, "node": int(reply.metadata.src_node_id), "error": str(reply.error.reason)}
    content = reply.content
    arrays = list(content.array_records.values())
    described: dict[str, Any] = {
        "round": server_round, "node": int(reply.metadata.src_node_id),
        "records": {name: type(record).__name__ for name, record in content.items()},
        "metric_keys": sorted(k for m in content.metric_records.values() for k in m),
        "config_keys": sorted(k for c in content.config_records.values() for k in c),
        "same_names_and_shapes": False, "update_norm": None}
    if len(arrays) == 1:
        got, base = arrays[0], sent
        same = list(got.keys()) == list(base.keys()) and all(
            tuple(got[k].shape) == tuple(base[k].shape) for k in base)
        described["same_names_and_shapes"] = same
        if same:
            squares = sum(float(np.sum((got[k].numpy().astype(np.float64) - base[k].numpy()) ** 2))
                          for k in base)
            described["update_norm"] = round(math.sqrt(squares), 6)
    return described


def audit_replies(strategy: Any, sent_arrays: Any, log: list[dict[str, Any]]) -> Any:
    """Make ``strategy`` (a Flower strategy) describe each round's replies into ``log`` before aggregating them;
    ``sent_arrays()`` gives the global arrays the round started from."""
    aggregate = strategy.aggregate_train

    def aggregate_train(server_round: int, replies: Any) -> Any:
        replies = list(replies)
        sent = sent_arrays()
        log.extend(describe_reply(server_round, r, sent) for r in replies)
        return aggregate(server_round, replies)

    strategy.aggregate_train = aggregate_train
    return strategy
