"""The options of a run, in a few typed groups: what to train, where to write, how to evaluate, how to run.

The CLIs build these from their flags; Python users build them directly (every field has the CLI's default)::

    train(TrainSpec("ppo", "sbagents/GridWorld-v0", n_timesteps=20_000), execution=ExecOptions(seed=0))
    train(TrainSpec("ppo", "sbagents/GridWorld-v0"), sb3=Sb3Options(vec_env="subproc"))

The groups are frozen; beyond their first field(s) they take keywords only, so a new field never shifts the others.
Execution is split by library: :class:`ExecOptions` (both), :class:`Sb3Options` and :class:`RllibOptions`; each
field's ``:param:`` names its ``train`` flag (tests/test_option_flags.py checks that every flag reaches its field).
Each group checks its own values (:meth:`validate`) before any run dir exists; messages name the CLI flag. A
training feature's options (``--robust``, ``--dp-*``, the trust flags, ...) belong to its extension
(:mod:`sbagents.extensions`), not to these groups.
"""

from __future__ import annotations

from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path
from typing import Any

from sbagents.errors import UsageError

VEC_ENV_TYPES = ("auto", "dummy", "subproc", "batched", "envpool")


def check_at_least(flag: str, value: int | None, low: int, also: str = "") -> None:
    """Raise :class:`UsageError` (``--flag must be >= low``) when ``value`` is set and below ``low``."""
    if value is not None and value < low:
        raise UsageError(f"{flag} must be >= {low}{also}, got {value}")


@dataclass(frozen=True)
class TrainSpec:
    """What to train.

    :param algo: algorithm name (``--algo``; see ``python -m sbagents.train --list``).
    :param env: env name (``--env``): a Gymnasium id, ``module:EnvId`` or a PettingZoo name.
    :param n_timesteps: budget overriding the config's ``n_timesteps`` (``-n``).
    :param hyperparams: config overrides (``-params key:value``).
    :param conf_file: zoo config file (``-conf/--conf-file``; default: ``zoo_configs/<algo>.yml``).
    :param env_kwargs: env constructor arguments merged into the config's (``--env-kwargs``).
    :param gym_packages: packages to import that register the env (``--gym-packages``).
    :param trained_agent: a model ``.zip`` to continue training (``-i``).
    :param trust_run: the ``-i`` model and the files beside it come from a trusted source: load pickles in them
        as they are (``--trust-run``; by default loading runs no code from a file, see docs/security.md).
    """

    algo: str = "qlearning"
    env: str = "sbagents/GridWorld-v0"
    n_timesteps: int | None = None
    hyperparams: dict[str, Any] = field(default_factory=dict)
    _: KW_ONLY
    conf_file: str | Path | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    gym_packages: tuple[str, ...] = ()
    trained_agent: str | Path | None = None
    trust_run: bool = False

    def validate(self) -> None:
        """Check the budget (the rest is checked against the config and the env)."""
        if self.n_timesteps is not None and self.n_timesteps < 1:
            raise UsageError(f"-n/--n-timesteps must be a positive integer, got {self.n_timesteps}")


@dataclass(frozen=True)
class OutputOptions:
    """Where a run writes.

    :param log_folder: root of the run dirs (``-f``).
    :param tensorboard_log: TensorBoard folder (``-tb``; None: none).
    :param save_freq: checkpoint every N env steps (``--save-freq``; <= 0: never).
    :param command: the command line recorded in ``command.txt`` (default: one rebuilt from the spec).
    """

    log_folder: str | Path = "logs"
    _: KW_ONLY
    tensorboard_log: str | None = None
    save_freq: int = -1
    command: str = ""


@dataclass(frozen=True, kw_only=True)
class EvalOptions:
    """How a run is evaluated while and after it trains.

    :param eval_freq: env steps between evaluations (``--eval-freq``; None: a tenth of the budget, at most 25,000;
        <= 0: none). On-policy runs evaluate at most once per rollout, whatever the period.
    :param eval_episodes: episodes per periodic evaluation (``--eval-episodes``).
    :param n_eval_envs: envs of the periodic evaluation (``--n-eval-envs``).
    :param final_eval_episodes: episodes of the final evaluation in ``summary.json`` (``--final-eval-episodes``;
        0: none).
    """

    eval_freq: int | None = None
    eval_episodes: int = 5
    n_eval_envs: int = 1
    final_eval_episodes: int = 10

    def validate(self) -> None:
        """Check the episode counts."""
        check_at_least("--eval-episodes", self.eval_episodes, 1)
        check_at_least("--n-eval-envs", self.n_eval_envs, 1)
        check_at_least("--final-eval-episodes", self.final_eval_episodes, 0)

    def frequency(self, n_timesteps: int) -> int:
        """The evaluation period in env steps: :attr:`eval_freq`, or a tenth of the budget, at most 25,000."""
        if self.eval_freq is not None:
            return self.eval_freq
        return min(25_000, max(n_timesteps // 10, 1))


@dataclass(frozen=True, kw_only=True)
class ExecOptions:
    """How a run executes, whichever library trains it (:class:`Sb3Options` and :class:`RllibOptions` hold what only
    one of them uses).

    :param seed: random seed (``--seed``; -1: draw one; it is recorded in ``summary.json``).
    :param backend: the training library (``--backend``): ``sb3`` or ``rllib`` (Ray RLlib, PettingZoo envs).
    :param device: torch device (``--device``: ``auto``, ``cpu``, ``cuda``, ``cuda:N``).
    :param num_threads: torch threads (``--num-threads``; 1 is far faster for small networks on few cores; <= 0
        keeps torch's).
    :param progress: show a progress bar (``-P/--progress``; None: when stderr is a terminal).
    :param verbose: ``--verbose``: 0 prints nothing, 1 a progress bar and one line per evaluation, 2 also the
        library's log tables.
    """

    seed: int = -1
    backend: str = "sb3"
    device: str = "auto"
    num_threads: int = 1
    progress: bool | None = None
    verbose: int = 1

    def validate(self) -> None:
        """Check the backend and the device name (through torch, if torch is asked to parse one)."""
        from sbagents.core.backends import backend_names

        if self.backend not in backend_names():
            raise UsageError(f"--backend must be one of {', '.join(backend_names())}, got {self.backend!r}")
        if self.device != "auto":
            import torch

            try:
                torch.device(self.device)
            except (RuntimeError, TypeError):
                raise UsageError(
                    f"--device {self.device!r} is not a torch device; use auto, cpu, cuda or cuda:N"
                ) from None


@dataclass(frozen=True, kw_only=True)
class Sb3Options:
    """How an SB3 run (``--backend sb3``) executes; RLlib refuses any of these that differs from its default.

    :param vec_env: the vector env (``--vec-env``): ``auto`` (batched numpy envs where they exist; EnvPool for Atari
        ids when installed), ``dummy``, ``subproc``, ``batched`` or ``envpool``.
    :param log_interval: episodes (off-policy) or rollouts (on-policy) between SB3 log dumps (``--log-interval``;
        -1: automatic).
    """

    vec_env: str = "auto"
    log_interval: int = -1

    def validate(self) -> None:
        """Check the vec env kind and the log interval."""
        if self.vec_env not in VEC_ENV_TYPES:
            raise UsageError(f"--vec-env must be one of {', '.join(VEC_ENV_TYPES)}, got {self.vec_env!r}")
        if self.log_interval != -1:
            check_at_least("--log-interval", self.log_interval, 1, " or -1 (automatic)")


@dataclass(frozen=True, kw_only=True)
class RllibOptions:
    """How an RLlib run (``--backend rllib``) executes; an SB3 run refuses any of these that differs from its default.

    :param num_env_runners: RLlib env runner actors (``--num-env-runners``; None: the config's; 0 samples in the
        driver).
    :param address: Ray cluster to join (``--address``: ``auto``, ``host:6379`` or ``ray://host:10001``; None: a
        local Ray).
    """

    num_env_runners: int | None = None
    address: str | None = None

    def validate(self) -> None:
        """Check the runner count (the address is checked by connecting to it)."""
        check_at_least("--num-env-runners", self.num_env_runners, 0)


@dataclass(frozen=True, kw_only=True)
class EvaluateOptions:
    """How ``evaluate`` plays a finished run.

    :param n_episodes: episodes to play (``-n``).
    :param deterministic: greedy actions (``--deterministic``), or sampled ones (``--stochastic``); None: as the
        run's config says (its ``deterministic_eval``, greedy unless set to false).
    :param seed: seed of the evaluation env (``--seed``; same episodes every time).
    :param render: print each state (text envs) or let the env render itself (``human``) (``--render``).
    :param attacks: observation attacks to evaluate as well (``--attack``, e.g. ``"gaussian:0.05 pgd:0.1"``).
    :param fairness: info keys to bucket episodes by (``--fairness``).
    :param bins: buckets per fairness key (``--bins``).
    :param opponent: turn-based games: the opponent of every other seat (``--opponent``: ``random``, ``heuristic``,
        ``minimax``, a run dir, a model zip or ``module:function``; None: the run's ``self_play.eval_opponent``).
    """

    n_episodes: int = 10
    deterministic: bool | None = None
    seed: int | None = 0
    render: bool = False
    attacks: str | None = None
    fairness: str | None = None
    bins: int = 3
    opponent: str | None = None

    def validate(self) -> None:
        """Check the counts."""
        if self.n_episodes < 1:
            raise UsageError(f"the number of evaluation episodes must be >= 1, got {self.n_episodes}")
        if self.fairness:
            check_at_least("--bins", self.bins, 1)

    def greedy(self, default: bool = True) -> bool:
        """Whether to act greedily: :attr:`deterministic`, or ``default`` (the run's ``deterministic_eval``) when
        it is None."""
        return default if self.deterministic is None else self.deterministic


@dataclass(frozen=True, kw_only=True)
class StudyOptions:
    """An Optuna study of ``tune``.

    :param n_trials: finished trials the study should hold (``--n-trials``; a resumed study runs only the missing
        ones).
    :param storage: RDB URL (``--storage``; None: an SQLite file in the log folder).
    :param study_name: study name (``--study-name``; None: ``<algo>-<EnvId>``).
    :param n_jobs: parallel trials in this process (``--n-jobs``).
    :param sampler: the Optuna sampler (``--sampler``): ``tpe`` or ``random``.
    :param pruner: the Optuna pruner (``--pruner``): ``median``, ``halving`` or ``none``.
    :param n_seeds: seeds per trial (``--n-seeds``; the objective is the mean of their best evaluations).
    :param n_evaluations: evaluations per training run (``--n-evaluations``).
    :param eval_episodes: episodes per evaluation (``--eval-episodes``).
    """

    n_trials: int = 20
    storage: str | None = None
    study_name: str | None = None
    n_jobs: int = 1
    sampler: str = "tpe"
    pruner: str = "median"
    n_seeds: int = 1
    n_evaluations: int = 5
    eval_episodes: int = 5

    def validate(self) -> None:
        """Check the counts (samplers and pruners are checked against Optuna's tables by ``tune``)."""
        for flag, value in (("--n-trials", self.n_trials), ("--n-seeds", self.n_seeds), ("--n-jobs", self.n_jobs),
                            ("--n-evaluations", self.n_evaluations), ("--eval-episodes", self.eval_episodes)):
            check_at_least(flag, value, 1)
