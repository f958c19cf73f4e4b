"""Flower's ServerApp and ClientApp of the federated homes.

A home's reply to a train message holds exactly two records: ``arrays`` (the home's new parameters, the same names
and shapes as the global ones) and ``metrics`` (``num-examples``: the steps it trained, which the run config already
fixes). Nothing else leaves a home: no rewards, no preferences, no transitions.

:func:`make_client_app` / :func:`make_server_app` build the apps for the simulation (settings passed directly);
:data:`client_app` / :data:`server_app` are the deployment's (``flwr run``), which read the settings from the run
config and the home from the SuperNode's node config (``home=I`` and optionally ``preferred-temp``,
``preferred-light``, ``state-dir``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from flwr.app import ArrayRecord, Context, Message, MetricRecord, RecordDict
from flwr.clientapp import ClientApp
from flwr.clientapp.mod import fixedclipping_mod
from flwr.serverapp import Grid, ServerApp

from sbagents.federated.homes import Home, client_homes
from sbagents.federated.local import HomeLearner
from sbagents.federated.settings import FederatedSettings

#: The config key Flower's DP strategies send the clipping norm under.
CLIPPING_KEY = "clipping_norm"


def home_of(settings: FederatedSettings, node_config: dict[str, Any]) -> Home:
    """The home a node is: ``partition-id`` (simulation) or ``home`` (deployment); a deployment's home may set its
    own user (``preferred-temp``, ``preferred-light``), which then never leaves it."""
    index = int(node_config.get("home", node_config.get("partition-id", 0)))
    home = client_homes(max(settings.homes, index + 1), settings.seed)[index]
    if "preferred-temp" in node_config or "preferred-light" in node_config:
        home = Home(index, "own", float(node_config.get("preferred-temp", home.preferred_temp)),
                    float(node_config.get("preferred-light", home.preferred_light)))
    return home


def _clip_when_asked(msg: Message, context: Context, call_next: Any) -> Message:
    """Flower's ``fixedclipping_mod`` for DP-FedAvg's train messages (the ones carrying a clipping norm).

    Flower 1.42 divides by the update's norm: a home whose update is exactly zero (no gradient step yet, e.g. before
    ``learning_starts``) raises ZeroDivisionError there. Such an update needs no clipping and is sent as it is.
    """
    config = msg.content.config_records.get("config")
    if config is None or CLIPPING_KEY not in config:
        return call_next(msg, context)  # type: ignore[no-any-return]
    replies: list[Message] = []

    def train_once(message: Message, ctx: Context) -> Message:
        replies.append(call_next(message, ctx))
        return replies[-1]

    try:
        return fixedclipping_mod(msg, context, train_once)  # type: ignore[no-any-return]
    except ZeroDivisionError:
        return replies[-1]


def make_client_app(settings: FederatedSettings | None = None, state_root: Path | None = None) -> ClientApp:
    """The homes' ClientApp; without ``settings`` it reads them from the run config (deployment), without
    ``state_root`` a home keeps its state under ``state-dir`` of its node config (else a temporary folder)."""
    app = ClientApp(mods=[_clip_when_asked])

    @app.train()
    def train(msg: Message, context: Context) -> Message:
        run_settings = settings or FederatedSettings.from_run_config(dict(context.run_config))
        home = home_of(run_settings, dict(context.node_config))
        root = state_root or Path(str(context.node_config.get("state-dir", "")) or _default_state_root())
        config = msg.content.config_records["config"]
        learner = HomeLearner(run_settings, home, root / f"home-{home.index}")
        state = learner.train_round(msg.content.array_records["arrays"].to_torch_state_dict(),
                                    int(str(config["server-round"])), float(str(config.get("proximal-mu", 0.0))))
        metrics = MetricRecord({"num-examples": run_settings.local_steps})
        reply = RecordDict({"arrays": ArrayRecord(state), "metrics": metrics})
        return Message(content=reply, reply_to=msg)

    return app


_STATE_ROOT: list[Path] = []


def _default_state_root() -> Path:
    """A home without a ``state-dir``: one temporary folder per process (gone with the machine's temp files)."""
    if not _STATE_ROOT:
        _STATE_ROOT.append(Path(tempfile.mkdtemp(prefix="sbagents-home-")))
    return _STATE_ROOT[0]


def make_server_app(settings: FederatedSettings | None = None, run_dir: Path | None = None,
                    report: Any = print) -> ServerApp:
    """The server's ServerApp (:func:`sbagents.federated.server.run_federation`); without arguments it reads
    the settings and ``run-dir`` from the run config (deployment). ``report`` takes the per-round lines."""
    app = ServerApp()

    @app.main()
    def main(grid: Grid, context: Context) -> None:
        from sbagents.federated.server import run_federation

        run_settings = settings or FederatedSettings.from_run_config(dict(context.run_config))
        run_federation(grid, run_settings, run_dir or Path(str(context.run_config["run-dir"])), report)

    return app


client_app = make_client_app()
server_app = make_server_app()
