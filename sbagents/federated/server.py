"""The server's side of a federated run: the global model, the rounds, the held-out evaluation, and the files.

:func:`run_federation` runs inside Flower's ServerApp (simulation or deployment) and writes into the run dir:
the global model after every round (``<env>.zip``, with ``vecnormalize.npz`` when the config normalizes), ``rounds.csv``
(one row per round: held-out homes' comfort, success, return, energy; bytes per home; DP epsilon; seconds) and
``federated.json`` (the homes, the settings, the rounds, and what every home's reply carried:
:mod:`sbagents.federated.audit`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch
from stable_baselines3.common.vec_env import VecNormalize

from sbagents.atomic import save_model, write_csv, write_json
from sbagents.core.run_dir import env_stem
from sbagents.federated.audit import audit_replies
from sbagents.federated.evaluation import evaluate_homes
from sbagents.federated.homes import client_homes, held_out_homes
from sbagents.federated.local import home_experiment, load_shared_state, make_env, new_model, shared_state
from sbagents.federated.settings import FederatedSettings
from sbagents.federated.strategies import build_strategy, dp_epsilon
from sbagents.state_files import VECNORMALIZE_FILE, save_vecnormalize

ROUNDS_FILE = "rounds.csv"
FEDERATED_FILE = "federated.json"
ROUND_FIELDS = ("round", "heldout_criterion_share", "heldout_success_rate", "heldout_mean_return",
                "heldout_mean_energy", "bytes_down_per_home", "bytes_up_per_home", "dp_epsilon", "seconds")
#: Seed offset of the server's held-out evaluation episodes.
EVAL_SEED = 50_000


def run_federation(grid: Any, settings: FederatedSettings, run_dir: Path, report: Any = print) -> dict[str, Any]:
    """Run ``settings.rounds`` rounds of ``settings.strategy`` over the homes on ``grid``; write the run dir's
    files; return what ``federated.json`` holds."""
    from flwr.app import ArrayRecord, ConfigRecord, MetricRecord

    torch.set_num_threads(1)
    exp = home_experiment(settings)
    env = make_env(exp, settings.seed)
    model = new_model(exp, env, settings.seed)
    initial = ArrayRecord(shared_state(model))
    size = initial.count_bytes()
    n_parameters = sum(int(v.numel()) for v in shared_state(model).values())
    held_out = held_out_homes(settings.held_out, settings.seed)
    rows: list[dict[str, Any]] = []
    replies: list[dict[str, Any]] = []
    current = [initial]  # the global arrays the next round starts from
    start = time.perf_counter()

    homes = client_homes(settings.homes, settings.seed)
    model_file = run_dir / f"{env_stem(settings.env)}.zip"
    if isinstance(env, VecNormalize):
        save_vecnormalize(env, run_dir / VECNORMALIZE_FILE)

    def record() -> dict[str, Any]:
        return {"settings": settings.to_run_config(), "homes": [vars(h) for h in homes],
                "held_out_homes": [vars(h) for h in held_out], "rounds": rows, "replies": replies,
                "bytes_per_round_per_home": 2 * size,
                "parameters": n_parameters,
                "seconds": round(time.perf_counter() - start, 2)}

    def evaluate(server_round: int, arrays: ArrayRecord) -> MetricRecord:
        """After each round: the held-out evaluation, the global model and the record (an interrupted run keeps
        the last round's)."""
        row: dict[str, Any] = {"round": server_round, "bytes_down_per_home": size if server_round else 0,
                               "bytes_up_per_home": size if server_round else 0,
                               "dp_epsilon": dp_epsilon(settings, server_round)}
        load_shared_state(model, arrays.to_torch_state_dict(), sync_targets=True)
        if held_out:
            result = evaluate_homes(model, exp, held_out, settings.eval_episodes, settings.seed + EVAL_SEED)
            row.update({f"heldout_{k}": round(v, 4) for k, v in result.items() if k != "per_home"})
        row["seconds"] = round(time.perf_counter() - start, 2)
        current[0] = arrays
        rows.append(row)
        _write_rows(run_dir / ROUNDS_FILE, rows)
        save_model(model, model_file)
        write_json(run_dir / FEDERATED_FILE, record())
        report(round_line(row, settings.rounds))
        return MetricRecord({k: float(v) for k, v in row.items() if isinstance(v, int | float)})

    strategy = audit_replies(build_strategy(settings), lambda: current[0], replies)
    strategy.start(grid=grid, initial_arrays=initial, num_rounds=settings.rounds, train_config=ConfigRecord(),
                   evaluate_fn=evaluate)
    env.close()
    return record()


def _write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    write_csv(path, ROUND_FIELDS, rows)


def round_line(row: dict[str, Any], rounds: int) -> str:
    share = row.get("heldout_criterion_share")
    parts = [f"round {row['round']}/{rounds}"]
    if share is not None:
        parts.append(f"held-out comfort {share:.1%}, success {row['heldout_success_rate']:.0%}")
    if row.get("dp_epsilon") is not None:
        parts.append(f"epsilon {row['dp_epsilon']:.2f}")
    parts.append(f"{row['seconds']:.0f} s")
    return ", ".join(parts)
