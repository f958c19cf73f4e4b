"""A whole federated run into a normal run dir: Flower's simulation (one process, Ray actors as homes) or a real
deployment on this machine (:mod:`sbagents.federated.deployment`), then the final evaluation, ``summary.json`` and
the rounds plot.

The run dir is the one ``train`` writes (``<log-folder>/<algo>/<env>_<k>/``: ``config.yml``, ``args.yml``,
``command.txt``, the model, ``vecnormalize.pkl``, ``summary.json``), so ``evaluate``, ``export`` and ``serve`` take
it; ``rounds.csv``, ``rounds.png`` and ``federated.json`` add the federation's own record.
"""

from __future__ import annotations

import json
import logging
import os
import shlex
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sbagents.core.lifecycle import LearningClock, base_summary, finish_run, new_run_dir
from sbagents.errors import UsageError
from sbagents.federated.settings import FederatedSettings

#: Flower's telemetry stays off unless the user turned it on.
os.environ.setdefault("FLWR_TELEMETRY_ENABLED", "0")


@dataclass
class FederatedResult:
    """What a federated run produced: its run dir, ``summary.json``'s content and ``federated.json``'s."""

    run_dir: Path
    summary: dict[str, Any]
    record: dict[str, Any] = field(default_factory=dict)
    interrupted: bool = False


def require_flower() -> None:
    """:class:`UsageError` (one line) when Flower or Opacus is missing."""
    import sys

    try:
        import flwr  # noqa: F401

        from sbagents.private import require_opacus

        require_opacus()
    except ImportError as exc:
        needs = " (Flower needs Python >= 3.11)" if sys.version_info < (3, 11) else ""
        raise UsageError(f"federated homes need Flower and Opacus: pip install 'sbagents[federated]'{needs} "
                         f"({exc})") from None


def federate(settings: FederatedSettings, log_folder: str | Path = "logs", deploy: bool = False, port: int = 8000,
             final_eval_episodes: int = 10, command: str | None = None, quiet: bool = False,
             verbose: int = 1) -> FederatedResult:
    """Train one global policy across ``settings.homes`` homes and write a run dir.

    :param deploy: run a real deployment on localhost (a SuperLink here; homes started with
        ``python -m sbagents.federated.home``) instead of Flower's simulation.
    :param port: the SuperLink's port (deployment).
    :param quiet: no line per round.
    :param verbose: 2 shows Flower's own logs.
    """
    from sbagents.federated.local import home_experiment

    settings.validate()
    require_flower()
    exp = home_experiment(settings)  # checks the config before a run dir exists
    if deploy:
        from sbagents.federated.deployment import check_port_free

        check_port_free("127.0.0.1", port, "--port")
    args = {"algo": settings.algo, "env": settings.env, "seed": settings.seed,
            "n_timesteps": settings.homes * settings.total_local_steps, "federated": settings.to_run_config(),
            "mode": "deployment" if deploy else "simulation", "log_folder": str(log_folder)}
    command = command or "python -m sbagents.federated " + shlex.join(["--homes", str(settings.homes)])
    with new_run_dir(log_folder, settings.algo, settings.env, exp.hyperparams, args, command) as run_dir:
        pass
    clock = LearningClock(graceful=False)
    report = (lambda _line: None) if quiet else print
    with clock, tempfile.TemporaryDirectory(prefix="sbagents-homes-") as state_root:  # Ctrl-C: clock.interrupted
        if deploy:
            from sbagents.federated.deployment import run_deployment

            run_deployment(settings, run_dir, port, report)
        else:
            simulate(settings, run_dir, Path(state_root), quiet, verbose)
    return finish(settings, run_dir, clock, final_eval_episodes)


def simulate(settings: FederatedSettings, run_dir: Path, state_root: Path, quiet: bool = False,
             verbose: int = 1) -> None:
    """Flower's simulation in a child process (Ray takes over its signals), stopped on Ctrl-C / SIGTERM here: the
    run dir keeps the last round's global model and rows.

    :raises UsageError: the simulation failed (rerun with ``-v 2`` for Flower's logs).
    """
    import multiprocessing

    child = multiprocessing.get_context("spawn").Process(
        target=_simulate, args=(settings, run_dir, state_root, quiet, verbose), name="flower-simulation")
    child.start()
    try:
        child.join()
    except KeyboardInterrupt:
        child.kill()  # SIGTERM would make Ray print a stack dump; Ray's own processes share the child's fate
        child.join()
        raise
    if child.exitcode != 0:
        raise UsageError(f"Flower's simulation failed (exit {child.exitcode}); see the lines above, and -v 2 for "
                         "Flower's own logs")


def _simulate(settings: FederatedSettings, run_dir: Path, state_root: Path, quiet: bool, verbose: int) -> None:
    """The simulation's process: ``settings.homes`` virtual SuperNodes on Ray, one CPU each."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides (a terminal's Ctrl-C reaches both)
    quiet_flower(verbose)
    from flwr.simulation import run_simulation

    from sbagents.federated.apps import make_client_app, make_server_app

    init_args: dict[str, Any] = {"num_cpus": max(os.cpu_count() or 1, 1), "include_dashboard": False}
    if verbose < 2:
        init_args.update(log_to_driver=False, logging_level=logging.ERROR)
    report = (lambda _line: None) if quiet else _print_flush
    run_simulation(make_server_app(settings, run_dir, report), make_client_app(settings, state_root),
                   num_supernodes=settings.homes,
                   backend_config={"client_resources": {"num_cpus": 1}, "init_args": init_args})


def _print_flush(line: str) -> None:
    print(line, flush=True)


def quiet_flower(verbose: int) -> None:
    """Flower logs errors only unless ``verbose >= 2`` (its per-round INFO tables repeat our round lines, and its
    warnings are about choices made here: no client-side evaluation, ``run_simulation``)."""
    if verbose >= 2:
        return
    os.environ.setdefault("FLWR_LOG_LEVEL", "ERROR")
    os.environ.setdefault("RAY_ACCEL_ENV_VAR_OVERRIDE_ON_ZERO", "0")  # Ray's FutureWarning about GPUs we never use
    from flwr.common.logger import update_console_handler

    update_console_handler(level=logging.ERROR)
    logging.getLogger("flwr").propagate = False


def finish(settings: FederatedSettings, run_dir: Path, clock: LearningClock, final_eval_episodes: int
           ) -> FederatedResult:
    """``summary.json`` (with the final evaluation on SmartHome's random users), the rounds plot, the result."""
    from sbagents.core.run_dir import RunRef, env_stem, load_run
    from sbagents.federated.plots import plot_rounds
    from sbagents.federated.server import FEDERATED_FILE, ROUNDS_FILE

    record_path = run_dir / FEDERATED_FILE
    record = json.loads(record_path.read_text()) if record_path.exists() else {}  # written after every round
    steps = settings.homes * settings.local_steps * max(len(record.get("rounds", [])) - 1, 0)
    summary = base_summary(settings.algo, settings.env, settings.seed, steps, steps, clock)
    rounds = record.get("rounds", [])
    summary["federated"] = {
        "strategy": settings.strategy, "homes": settings.homes, "rounds": len(rounds) - 1 if rounds else 0,
        "local_steps": settings.local_steps, "bytes_per_round_per_home": record.get("bytes_per_round_per_home"),
        "held_out": {k: rounds[-1][k] for k in rounds[-1] if k.startswith("heldout_")} if rounds else None,
        "dp_epsilon": rounds[-1].get("dp_epsilon") if rounds else None,
        "dp_delta": settings.dp_delta if settings.strategy == "dp-fedavg" else None}
    if (run_dir / ROUNDS_FILE).exists():
        plot_rounds(run_dir / ROUNDS_FILE, run_dir / "rounds.png", f"{settings.strategy}, {settings.homes} homes")
    model_file = run_dir / f"{env_stem(settings.env)}.zip"
    if not model_file.exists():
        clock.interrupted = True
        summary["interrupted"] = True

    def final_eval() -> dict[str, Any]:
        from sbagents.core.options import EvaluateOptions
        from sbagents.pipeline.evaluation import evaluate_sb3_run

        exp_id = int(run_dir.name.rsplit("_", 1)[1])
        run = load_run(RunRef(settings.algo, settings.env, str(run_dir.parent.parent), exp_id))
        return evaluate_sb3_run(run, EvaluateOptions(n_episodes=final_eval_episodes, seed=settings.seed))

    finish_run(run_dir, summary, final_eval if final_eval_episodes > 0 and model_file.exists() else None)
    return FederatedResult(run_dir, summary, record, bool(summary["interrupted"]))
