"""Ray RLlib backend for Gymnasium envs and PettingZoo teams (``python -m sbagents.train --backend rllib``).

This module never imports Ray: it holds what the CLIs need to decide whether a run or a command belongs to the
RLlib backend. Training lives in :mod:`sbagents.rllib.training`, evaluation in :mod:`sbagents.rllib.evaluation`
(both import Ray, an optional extra: ``pip install 'sbagents[distributed]'``).

An RLlib run dir has the same layout as an SB3 one (``<log>/<algo>/<env>_<k>/`` with ``<env>/config.yml``,
``args.yml``, ``command.txt``, ``summary.json``) plus ``rllib_checkpoint/`` (``Algorithm.save_to_path``) and
``progress.csv`` (one row per training iteration), instead of the SB3 model zip; ``--save-freq N`` adds
``checkpoint_<env steps>/`` module checkpoints. Every checkpoint also holds its modules and weights as plain data
(:data:`MODULES_FILE`, :data:`WEIGHTS_FILE`), which is what evaluation reads: RLlib's own files are pickles.
"""

from __future__ import annotations

import functools
import importlib.util
import socket
from pathlib import Path
from typing import Any

from sbagents.core.env_kinds import EnvKind, SingleAgentKind, TeamKind
from sbagents.errors import UsageError

#: Algorithms the RLlib backend trains (names as in ``--algo``): its declaration
#: (:attr:`sbagents.rllib.backend.RllibBackend.algos`, the capability table's ``rllib`` column). ``appo`` and
#: ``impala`` exist only in RLlib; all five train Gymnasium envs.
RLLIB_ALGOS: tuple[str, ...] = ("ppo", "appo", "impala", "dqn", "sac")
#: Those that train PettingZoo teams here (one RLModule per module id, on-policy).
TEAM_ALGOS: tuple[str, ...] = ("ppo", "appo", "impala")


def rllib_algos() -> tuple[str, ...]:
    """Algorithms the RLlib backend trains (:data:`RLLIB_ALGOS`)."""
    return RLLIB_ALGOS


@functools.singledispatch
def kind_algos(kind: EnvKind) -> tuple[str, ...]:
    """The algorithms the RLlib backend trains on envs of ``kind`` (none for a kind it does not train)."""
    return ()


@kind_algos.register
def _single_agent_algos(kind: SingleAgentKind) -> tuple[str, ...]:
    return RLLIB_ALGOS


@kind_algos.register
def _team_algos(kind: TeamKind) -> tuple[str, ...]:
    return TEAM_ALGOS


def check_kind_algo(kind: EnvKind, algo: str) -> None:
    """Raise :class:`UsageError` (one line) when the RLlib backend does not train ``algo`` on envs of ``kind``."""
    accepted = kind_algos(kind)
    if algo not in accepted:
        raise UsageError(f"--backend rllib trains {kind.name} envs with --algo {', '.join(accepted)}; got {algo}")


#: The RLlib checkpoint inside a run dir; its presence marks an RLlib run.
CHECKPOINT_DIR = "rllib_checkpoint"
#: Periodic module checkpoints (``--save-freq``) are ``<run dir>/checkpoint_<env steps>/``.
CHECKPOINT_PREFIX = "checkpoint"
#: Per-iteration metrics of an RLlib run.
PROGRESS_FILE = "progress.csv"
#: In every checkpoint sbagents writes: its RLModules as plain data (JSON: algorithm, module class, module id ->
#: agents, model settings) and their weights (``.npz``), read without unpickling (:mod:`sbagents.rllib.checkpoints`).
MODULES_FILE = "sbagents_modules.json"
WEIGHTS_FILE = "sbagents_modules.npz"
#: Where the learner's (multi-agent) RLModule sits inside an RLlib checkpoint.
MODULE_SUBDIR = ("learner_group", "learner", "rl_module")
#: Module id of the parameter-shared policy (``policies: shared``); per-agent modules are named like the agents.
SHARED_MODULE = "shared"
NEEDS_RAY = "--backend rllib needs Ray: pip install 'sbagents[distributed]'"

#: Options (group, field) the RLlib backend does not implement -> their ``train`` flag.
UNSUPPORTED_OPTIONS: dict[tuple[str, str], str] = {
    ("spec", "trained_agent"): "-i/--trained-agent",
    ("output", "tensorboard_log"): "-tb/--tensorboard-log",
    ("evaluation", "n_eval_envs"): "--n-eval-envs",
    ("sb3", "vec_env"): "--vec-env",
    ("sb3", "log_interval"): "--log-interval",
}


def ray_available() -> bool:
    """Whether ``ray.rllib`` can be imported (without importing it)."""
    try:
        return importlib.util.find_spec("ray") is not None and importlib.util.find_spec("ray.rllib") is not None
    except (ImportError, ValueError):  # a broken or stubbed-out ray package
        return False


def require_ray(what: str = "--backend rllib") -> None:
    """Raise :class:`UsageError` (``<what> needs Ray: pip install ...``) unless Ray RLlib is importable."""
    if not ray_available():
        raise UsageError(NEEDS_RAY.replace("--backend rllib", what, 1))


def is_rllib_run(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` was written by the RLlib backend (it holds :data:`CHECKPOINT_DIR`)."""
    return (Path(run_dir) / CHECKPOINT_DIR).is_dir()


def check_address(address: str | None, timeout: float = 5.0) -> None:
    """Raise :class:`UsageError` unless the Ray cluster at ``address`` accepts a TCP connection.

    Ray itself retries an unreachable address for minutes; this fails in seconds. ``None``, ``auto`` and ``local``
    are not checked (Ray resolves them).
    """
    if address is None or address in ("auto", "local"):
        return
    host, _, port = address.split("://", 1)[-1].rpartition(":")
    if not host or not port.isdigit():
        raise UsageError(f"--address {address!r}: expected host:port, ray://host:port or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        raise UsageError(f"cannot reach the Ray cluster at {address}: {exc.strerror or exc}") from None


def check_options(groups: dict[str, Any], refused: list[str] | None = None) -> None:
    """Reject options the RLlib backend cannot honour (one-line :class:`UsageError` naming their flags).

    :param groups: the option groups of a run by name (``spec``, ``output``, ``evaluation``, ``execution``, ``sb3``,
        ``rllib``); a field that differs from its dataclass default counts as given.
    :param refused: flags of training extensions that refuse this backend
        (:func:`sbagents.extensions.refused_flags`), named in the same line.
    """
    given = []
    for (group, name), flag in UNSUPPORTED_OPTIONS.items():
        options = groups.get(group)
        if options is not None and getattr(options, name) != getattr(type(options)(), name):
            given.append(flag)
    given += refused or []
    if given:
        raise UsageError(f"{', '.join(given)} not supported with --backend rllib")
    execution, spec, rllib = groups["execution"], groups["spec"], groups.get("rllib")
    if spec.algo not in rllib_algos():
        raise UsageError(f"--backend rllib supports --algo {', '.join(rllib_algos())}; got {spec.algo!r}")
    if execution.device not in ("auto", "cpu"):
        raise UsageError(f"--backend rllib trains on the CPU here; got --device {execution.device}")
    check_address(None if rllib is None else rllib.address)


__all__ = [
    "CHECKPOINT_DIR",
    "CHECKPOINT_PREFIX",
    "MODULE_SUBDIR",
    "MODULES_FILE",
    "WEIGHTS_FILE",
    "NEEDS_RAY",
    "PROGRESS_FILE",
    "RLLIB_ALGOS",
    "TEAM_ALGOS",
    "rllib_algos",
    "SHARED_MODULE",
    "check_address",
    "check_kind_algo",
    "kind_algos",
    "check_options",
    "is_rllib_run",
    "ray_available",
    "require_ray",
]
