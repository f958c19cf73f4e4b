"""Run directories in RL Zoo's layout, ``<log-folder>/<algo>/<EnvId with / replaced by _>_<k>/``: making one,
finding one (:class:`RunRef`), the files every backend writes into it, and loading a finished SB3 run.

Importing this module needs neither torch nor SB3 (``serve`` finds exported policies through it); loading a
model imports them when asked.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from sbagents.atomic import write_text
from sbagents.errors import UsageError
from sbagents.state_files import BEST_VECNORMALIZE_FILE, VECNORMALIZE_FILE

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

    from sbagents.core.env_kinds import EnvKind
    from sbagents.core.experiment import Experiment

SUMMARY_FILE = "summary.json"
BEST_MODEL_FILE = "best_model.zip"
#: The group of a run whose agents share one model (its files carry no group name).
SHARED_GROUP = "shared"


def env_stem(env_id: str) -> str:
    """The file-name form of an env id: ``sbagents/GridWorld-v0`` -> ``sbagents_GridWorld-v0``."""
    return env_id.replace("/", "_").replace(":", "_")


def _existing_ids(algo_dir: Path, stem: str) -> list[int]:
    pattern = re.compile(rf"^{re.escape(stem)}_(\d+)$")
    if not algo_dir.is_dir():
        return []
    return sorted(int(m.group(1)) for p in algo_dir.iterdir() if (m := pattern.match(p.name)))


def create_run_dir(log_folder: str | Path, algo: str, env_id: str) -> Path:
    """Create and return a new run dir with k = highest existing + 1.

    ``os.mkdir`` is atomic, so two runs started at once into the same folder never share a directory:
    the loser of a race moves on to the next k.
    """
    algo_dir = Path(log_folder) / algo
    stem = env_stem(env_id)
    try:
        algo_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"log folder {log_folder} is not writable: {exc.strerror}") from None
    if not os.access(algo_dir, os.W_OK | os.X_OK):
        raise UsageError(f"log folder {log_folder} is not writable")
    k = max(_existing_ids(algo_dir, stem), default=0) + 1
    while True:
        run_dir = algo_dir / f"{stem}_{k}"
        try:
            run_dir.mkdir()
            return run_dir
        except FileExistsError:
            k += 1
        except OSError as exc:
            if exc.errno in (errno.EACCES, errno.EROFS, errno.EPERM):
                raise UsageError(f"log folder {log_folder} is not writable: {exc.strerror}") from None
            raise


def find_run_dir(log_folder: str | Path, algo: str, env_id: str, exp_id: int = 0) -> Path:
    """The run dir of experiment ``exp_id`` (0 = the latest), or :class:`UsageError` listing what exists."""
    if exp_id < 0:
        raise UsageError(f"--exp-id must be >= 0 (0: the latest run), got {exp_id}")
    algo_dir = Path(log_folder) / algo
    stem = env_stem(env_id)
    ids = _existing_ids(algo_dir, stem)
    if not ids:
        raise UsageError(f"no {algo} run for {env_id} in {log_folder} (looked for {algo_dir / stem}_<k>)")
    k = ids[-1] if exp_id == 0 else exp_id
    if k not in ids:
        raise UsageError(f"no run {stem}_{k} in {algo_dir}; existing exp ids: {', '.join(map(str, ids))}")
    return algo_dir / f"{stem}_{k}"


CHECKPOINT_PREFIX = "rl_model"


def saved_checkpoints(run_dir: Path) -> dict[int, Path]:
    """Timesteps -> model zip of the checkpoints ``--save-freq`` saved in a run dir (``rl_model_<steps>_steps.zip``,
    SB3's ``CheckpointCallback`` names), in step order."""
    found = {int(m.group(1)): p for p in run_dir.glob(f"{CHECKPOINT_PREFIX}_*_steps.zip")
             if (m := re.fullmatch(rf"{CHECKPOINT_PREFIX}_(\d+)_steps\.zip", p.name))}
    return dict(sorted(found.items()))


def checkpoint_path(run_dir: Path, steps: int) -> Path:
    """The checkpoint saved after ``steps`` timesteps, or :class:`UsageError` listing the run's checkpoints."""
    saved = saved_checkpoints(run_dir)
    if steps not in saved:
        listed = f"saved: {', '.join(map(str, saved))}" if saved else "it saved none (train with --save-freq N)"
        raise UsageError(f"no checkpoint after {steps} steps in {run_dir}; {listed}")
    return saved[steps]


def checkpoint_stats_path(run_dir: Path, steps: int) -> Path:
    """The ``VecNormalize`` statistics saved with the checkpoint of ``steps`` (the file may not exist)."""
    return run_dir / f"{CHECKPOINT_PREFIX}_vecnormalize_{steps}_steps.npz"


def best_stats_path(run_dir: Path, group: str = SHARED_GROUP) -> Path:
    """The ``VecNormalize`` statistics of ``best_model.zip`` (of a group's ``best_model.<group>.zip``): those saved
    with it (``vecnormalize_best.npz``, ``vecnormalize_best.<group>.npz``), else (a run from before they were kept)
    the final ones."""
    best = run_dir / best_stats_name(group)
    return best if best.is_file() else run_dir / group_stats_name(group)


def best_stats_name(group: str = SHARED_GROUP) -> str:
    """The file of the ``VecNormalize`` statistics saved with a best model: ``vecnormalize_best.npz`` (the run's one
    model, or ``shared``) or ``vecnormalize_best.<group>.npz``."""
    stem, _, ext = BEST_VECNORMALIZE_FILE.rpartition(".")
    return BEST_VECNORMALIZE_FILE if group == SHARED_GROUP else f"{stem}.{group}.{ext}"


def model_path(run_dir: Path, env_id: str, load_best: bool = False, checkpoint: int | None = None) -> Path:
    """The final (best, or ``checkpoint``-steps) model file of a run, or :class:`UsageError` if it is missing."""
    if checkpoint is not None:
        return checkpoint_path(run_dir, checkpoint)
    path = run_dir / (BEST_MODEL_FILE if load_best else f"{env_stem(env_id)}.zip")
    if not path.exists():
        hint = " (no evaluation ran during training; drop --load-best)" if load_best else ""
        raise UsageError(f"model file {path} does not exist{hint}")
    return path


def config_path(run_dir: Path, env_id: str) -> Path:
    """``<run dir>/<EnvId>/config.yml`` (RL Zoo layout)."""
    return run_dir / env_stem(env_id) / "config.yml"


def save_run_config(
    run_dir: Path, env_id: str, hyperparams: dict[str, Any], args: dict[str, Any], command: str
) -> None:
    """Write ``config.yml`` (the resolved hyperparameters), ``args.yml`` and ``command.txt`` (any backend),
    each atomically."""
    folder = config_path(run_dir, env_id).parent
    folder.mkdir(parents=True, exist_ok=True)
    write_text(folder / "config.yml", yaml.safe_dump(hyperparams, sort_keys=True))
    write_text(folder / "args.yml", yaml.safe_dump(args, sort_keys=True))
    write_text(run_dir / "command.txt", command + "\n")


def load_run_config(run_dir: Path, env_id: str) -> dict[str, Any]:
    """The hyperparameters saved in a run's ``config.yml``, or :class:`UsageError` if the file is missing or holds
    no settings (training always writes them: an empty file is a damaged run, not one without settings)."""
    path = config_path(run_dir, env_id)
    if not path.exists():
        raise UsageError(f"{run_dir} has no {path.relative_to(run_dir)}; is it a sbagents run dir?")
    entry = read_settings_file(path)
    if not entry:
        raise UsageError(f"{path} holds no settings (training writes the run's hyperparameters there); "
                         "is it a sbagents run dir?")
    return entry


def read_settings_file(path: Path) -> dict[str, Any]:
    """A run's YAML file that must hold a mapping (``config.yml``, ``args.yml``; safe YAML); one line for anything
    else (malformed, binary, a list)."""
    from sbagents.core.zoo_config import load_yaml

    try:
        data = load_yaml(path)
    except UnicodeDecodeError:
        raise UsageError(f"{path} is not a text file (binary content); is it a sbagents run dir?") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise UsageError(f"{path} must hold a YAML mapping of settings, not a {type(data).__name__}")
    return data


def run_args(run_dir: Path, env_id: str) -> dict[str, Any]:
    """A run's ``args.yml`` (the CLI settings it was trained with; ``{}`` when the file is missing)."""
    path = config_path(run_dir, env_id).with_name("args.yml")
    return read_settings_file(path) if path.exists() else {}


def load_experiment(run_dir: Path, algo: str, env_id: str, kind: EnvKind | None = None,
                    trusted_modules: tuple[str, ...] = ()) -> Experiment:
    """The :class:`~sbagents.core.experiment.Experiment` a run was trained with (so evaluation wraps the
    env identically).

    :param kind: the env's kind (default: a single-agent Gymnasium env).
    :param trusted_modules: modules the user named (``--env module:...``, ``--gym-packages``) whose classes the
        run's config may name besides the import allow-list (:data:`~sbagents.core.experiment.ALLOWED_IMPORTS`).
    """
    from sbagents.core.env_kinds import SINGLE_AGENT
    from sbagents.core.experiment import resolve

    entry = load_run_config(run_dir, env_id)
    source = str(config_path(run_dir, env_id))
    exp = resolve(algo, env_id, entry, source, kind or SINGLE_AGENT, trusted_modules)
    check_no_paths(entry, source)  # after resolve: an import path outside the allow-list is refused first
    return exp


#: Config keys whose arguments are handed to code that builds a finished run's envs (evaluate, export, record).
WRAPPER_KEYS = ("env_wrapper", "vec_env_wrapper")
#: Name components of an argument that names a file or folder (``video_folder``, ``filename``, ``log_dir``, ...).
PATH_WORDS = frozenset({"file", "filename", "filepath", "fname", "folder", "dir", "dirname", "directory", "path",
                        "video", "save", "prefix", "output", "out", "dest", "destination", "root", "log", "logdir",
                        "logs", "csv"})
_FILE_SUFFIX = re.compile(r"\.(csv|json|jsonl|txt|log|mp4|gif|png|jpg|npz|npy|pkl|zip|ya?ml|monitor|h5|pt|onnx)$",
                          re.IGNORECASE)


def names_path(key: str) -> bool:
    """Whether an argument called ``key`` names a file or folder (a component of :data:`PATH_WORDS`)."""
    lowered = key.lower()
    return lowered in PATH_WORDS or any(word in PATH_WORDS for word in re.split(r"[_\-.\s]+", lowered))


def looks_like_path(value: str) -> bool:
    """Whether a string reads as a file-system path: a separator, a leading ``~`` or ``.``, or a data file's
    suffix (``m.monitor.csv``)."""
    return ("/" in value or "\\" in value or value.startswith(("~", ".")) or bool(_FILE_SUFFIX.search(value)))


def _path_values(value: Any, path_key: bool) -> list[str]:
    """The strings in ``value`` (a scalar, or lists/mappings of them) that name paths: every non-empty string
    under a path-named key, and strings that :func:`looks_like_path` anywhere."""
    if isinstance(value, str):
        return [value] if (path_key and value.strip()) or looks_like_path(value) else []
    if isinstance(value, dict):
        return [v for key, item in value.items() for v in _path_values(item, path_key or names_path(str(key)))]
    if isinstance(value, list | tuple):
        return [v for item in value for v in _path_values(item, path_key)]
    return []


def check_no_paths(entry: dict[str, Any], source: str) -> None:
    """Refuse, in one line, a finished run's config whose wrapper arguments (``env_wrapper``, ``vec_env_wrapper``)
    or ``monitor_kwargs`` name a file or folder: evaluating, exporting or recording a run writes only into its run
    dir, and a wrapper given ``video_folder: /elsewhere`` or ``filename: /elsewhere/m`` would write (and truncate)
    files wherever the config says.

    :param source: the config file, for the message.
    :raises UsageError: naming the key, the wrapper, the argument and its value.
    """
    found: list[tuple[str, str, str]] = []
    for key in WRAPPER_KEYS:
        value = entry.get(key)
        for item in value if isinstance(value, list) else [value] if value else []:
            if isinstance(item, dict):
                for wrapper, kwargs in item.items():
                    for arg, arg_value in (kwargs or {}).items() if isinstance(kwargs, dict) else ():
                        found += [(f"{key} {wrapper}", str(arg), v) for v in _path_values(arg_value, names_path(
                            str(arg)))]
    monitor = entry.get("monitor_kwargs")
    if isinstance(monitor, dict):
        for arg, arg_value in monitor.items():
            found += [("monitor_kwargs", str(arg), v) for v in _path_values(arg_value, names_path(str(arg)))]
    if found:
        where, arg, value = found[0]
        raise UsageError(f"{source}: {where} argument {arg}={value!r:.80} names a file or folder; a run's config may "
                         "not write outside its run dir when it is evaluated, exported or recorded (remove the "
                         "argument from the config to use this run)")


def check_model_file(path: str | Path) -> Path:
    """Raise :class:`UsageError` unless ``path`` is an SB3 model zip (a complete zip holding a valid ``data``)."""
    from sbagents.safe_load import read_model_data

    path = Path(path)
    if not path.exists():
        raise UsageError(f"--trained-agent {path} does not exist")
    try:
        read_model_data(path)
    except UsageError as exc:
        raise UsageError(f"--trained-agent: {exc}") from None
    return path


@dataclass(frozen=True)
class RunRef:
    """Which finished run(s) a command means: the ``--algo --env -f --exp-id --load-best --gym-packages`` flags.

    :param algo: algorithm of the run (``--algo``; None: any, for commands that take several runs, such as ``plot``).
    :param env: env name as given on the command line (``--env``; resolved to its id by :meth:`env_ref`; None: any).
    :param log_folder: root of the run dirs (``-f/--log-folder``).
    :param exp_id: run number k (``--exp-id``; 0: the latest).
    :param load_best: the run's ``best_model.zip`` instead of its final model (``--load-best``).
    :param gym_packages: packages to import that register the env (``--gym-packages``).
    :param checkpoint: the checkpoint saved after this many timesteps (``train --save-freq``) instead of the final
        model (``--load-checkpoint``).
    :param env_kwargs: env constructor arguments on top of the run's (``--env-kwargs``) when its env is built again.
    :param trust: the run's files come from a trusted source: load pickles in them as they are (``--trust-run``;
        by default nothing in a run dir can run code, see docs/security.md).
    """

    algo: str | None
    env: str | None
    log_folder: str | Path = "logs"
    exp_id: int = 0
    load_best: bool = False
    gym_packages: tuple[str, ...] = ()
    checkpoint: int | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict, hash=False)
    trust: bool = False

    def __post_init__(self) -> None:
        if self.load_best and self.checkpoint is not None:
            raise UsageError("load_best and checkpoint each name a model of the run: give one of them")

    def env_ref(self) -> Any:
        """The resolved env (:class:`~sbagents.core.env_names.EnvRef`; imports gymnasium)."""
        from sbagents.core.env_names import resolve_env

        if self.env is None:
            raise UsageError("this command needs --env")
        return resolve_env(self.env, self.gym_packages)

    def run_dir(self) -> Path:
        """The run dir this reference names (:func:`find_run_dir`)."""
        if self.algo is None:
            raise UsageError("this command needs --algo")
        return find_run_dir(self.log_folder, self.algo, self.env_ref().env_id, self.exp_id)


@dataclass
class LoadedRun:
    """A finished SB3 run, ready to evaluate, export or record.

    :param models: group -> model for a run of one model per group of agents (``{"shared": model}`` otherwise).
    :param stats_paths: group -> where the ``VecNormalize`` statistics of its model are (the files may not exist).
    """

    run_dir: Path
    model_path: Path
    experiment: Experiment
    model: BaseAlgorithm
    env: Any  # EnvRef
    models: dict[str, BaseAlgorithm] = field(default_factory=dict)
    stats_paths: dict[str, Path | None] = field(default_factory=dict)
    trust: bool = False

    @property
    def stats_path(self) -> Path | None:
        """The ``VecNormalize`` statistics of the (first) model (None: the run has none)."""
        return next(iter(self.stats_paths.values()), None)


def run_groups(run_dir: Path, env_id: str) -> dict[str, list[str]] | None:
    """The groups of a PettingZoo run (``args.yml``; None for runs of other envs or made before groups)."""
    groups = run_args(run_dir, env_id).get("groups")
    if groups is None:
        return None
    if not isinstance(groups, dict) or not all(isinstance(a, list) for a in groups.values()):
        raise UsageError(f"{config_path(run_dir, env_id).with_name('args.yml')}: groups must map group names to "
                         f"lists of agents, got {groups!r:.80}")
    return {str(g): [str(x) for x in a] for g, a in groups.items()}


def group_model_name(stem: str, group: str) -> str:
    """The model file of a group in a run dir: ``<EnvStem>.<group>.zip`` (``shared``: ``<EnvStem>.zip``)."""
    return f"{stem}.zip" if group == SHARED_GROUP else f"{stem}.{group}.zip"


def group_resume_files(model: Path, env_id: str, groups: Sequence[str]) -> dict[str, tuple[Path, Path]]:
    """What ``-i`` continues in a run of one model per group: given one group's model file, every group's model file
    of the same moment beside it, with the ``VecNormalize`` statistics saved with each (that file may not exist).

    ``model`` may be a group's final model (``<EnvStem>.<group>.zip``, with ``vecnormalize.<group>.npz``), best
    model (``best_model.<group>.zip``, with ``vecnormalize_best.<group>.npz``) or checkpoint
    (``rl_model.<group>_<N>_steps.zip``, with ``rl_model.<group>_vecnormalize_<N>_steps.npz``; the groups' models
    count their own agents' steps, so the k-th checkpoint of each group is of the same moment).

    :raises UsageError: a file that is none of these for a group of ``groups``, or another group's model missing.
    """
    run_dir, stem, best = model.parent, env_stem(env_id), Path(BEST_MODEL_FILE).stem

    def checkpoint(group: str, name: str) -> int | None:
        found = re.fullmatch(rf"{re.escape(CHECKPOINT_PREFIX)}\.{re.escape(group)}_(\d+)_steps\.zip", name)
        return int(found.group(1)) if found else None

    def checkpoints(group: str) -> list[int]:
        return sorted(n for p in run_dir.iterdir() if (n := checkpoint(group, p.name)) is not None)

    def files(kind: str, group: str, index: int = 0) -> tuple[str, Path]:
        if kind == "final":
            return group_model_name(stem, group), run_dir / group_stats_name(group)
        if kind == "best":
            return f"{best}.{group}.zip", best_stats_path(run_dir, group)
        found = checkpoints(group)
        steps = found[index] if index < len(found) else "N"
        return (f"{CHECKPOINT_PREFIX}.{group}_{steps}_steps.zip",
                run_dir / f"{CHECKPOINT_PREFIX}.{group}_vecnormalize_{steps}_steps.npz")

    given: tuple[str, int] | None = None
    for group in groups:
        kind = next((k for k in ("final", "best") if files(k, group)[0] == model.name), None)
        if kind is not None:
            given = (kind, 0)
        elif (steps := checkpoint(group, model.name)) is not None and steps in (found := checkpoints(group)):
            given = ("checkpoint", found.index(steps))
        if given is not None:
            break
    if given is None:
        first = groups[0]
        raise UsageError(f"-i {model}: this run trains one model per group ({', '.join(groups)}); give one group's "
                         f"model ({files('final', first)[0]}, {files('best', first)[0]} or a checkpoint "
                         f"{CHECKPOINT_PREFIX}.{first}_<N>_steps.zip) and the others beside it continue too")
    resumed = {}
    for group in groups:
        name, stats = files(given[0], group, given[1])
        if not (run_dir / name).is_file():
            raise UsageError(f"-i {model}: group {group}'s model of the same moment is not beside it ({name})")
        resumed[group] = (run_dir / name, stats)
    return resumed


def group_stats_name(group: str) -> str:
    """The VecNormalize statistics file of a group: ``vecnormalize.npz`` (shared) or ``vecnormalize.<group>.npz``."""
    return "vecnormalize.npz" if group == SHARED_GROUP else f"vecnormalize.{group}.npz"


def group_model_path(run_dir: Path, env_id: str, group: str, load_best: bool = False) -> Path:
    """A group's model file (``<EnvId>.<group>.zip`` or ``best_model.<group>.zip``), or :class:`UsageError`."""
    name = f"best_model.{group}.zip" if load_best else f"{env_stem(env_id)}.{group}.zip"
    path = run_dir / name
    if not path.exists():
        hint = " (no evaluation ran during training; drop --load-best)" if load_best else ""
        raise UsageError(f"model file {path} does not exist{hint}")
    return path


def with_env_kwargs(exp: Experiment, env_kwargs: dict[str, Any]) -> Experiment:
    """``exp`` building its envs with ``env_kwargs`` on top of its own (its ``eval_env_kwargs`` no longer override
    those keys)."""
    if env_kwargs:
        return dataclasses.replace(exp, env_kwargs={**exp.env_kwargs, **env_kwargs},
                                   eval_env_kwargs={k: v for k, v in exp.eval_env_kwargs.items()
                                                    if k not in env_kwargs})
    return exp


def load_run(ref: RunRef) -> LoadedRun:
    """Find the run ``ref`` names and load its model(s) and experiment, without running code from its files: each
    model is rebuilt from the run's resolved hyperparameters, its plain data and its weights
    (:mod:`sbagents.safe_load`; ``ref.trust`` loads them as SB3 does)."""
    from sbagents.algos import ALGOS
    from sbagents.core.backends import DEFAULT_BACKEND, backend_of_run
    from sbagents.safe_load import load_model

    env = ref.env_ref()
    run_dir = find_run_dir(ref.log_folder, str(ref.algo), env.env_id, ref.exp_id)
    backend = backend_of_run(run_dir)
    if backend.name != DEFAULT_BACKEND:  # its policy is not an SB3 model (e.g. RLlib's modules)
        raise UsageError(f"{run_dir} is a --backend {backend.name} run: python -m sbagents.evaluate plays it; this "
                         f"command loads SB3 models only")
    if ref.algo not in ALGOS:
        raise UsageError(f"unknown algo {ref.algo!r}; available: {', '.join(ALGOS)}")
    trusted = env.trusted_modules()
    exp = with_env_kwargs(load_experiment(run_dir, ref.algo, env.env_id, env.kind, trusted),
                          ref.env_kwargs)
    from sbagents.core.extensions import registered_extensions  # (registered by load_experiment's import)

    cls: Any = ALGOS[ref.algo].cls
    args = run_args(run_dir, env.env_id)
    for extension in registered_extensions():  # e.g. a constrained run's zip holds a cost critic PPO.load refuses
        cls = extension.load_class(ref.algo, args) or cls

    def load(path: Path) -> Any:
        return load_model(cls, path, device="cpu", trust=ref.trust, trusted_modules=trusted,
                          hyperparams={"policy": exp.policy, **exp.algo_kwargs})

    groups = run_groups(run_dir, env.env_id)
    if groups is not None and len(groups) > 1:
        if ref.checkpoint is not None:
            raise UsageError("--load-checkpoint loads one model; this run has one model per group (its checkpoints "
                             "are rl_model.<group>_<steps>_steps.zip)")
        paths = {g: group_model_path(run_dir, env.env_id, g, ref.load_best) for g in groups}
        models = {g: load(path) for g, path in paths.items()}
        first = next(iter(models))
        stats = {g: _stats(best_stats_path(run_dir, g) if ref.load_best else run_dir / group_stats_name(g), ref.trust)
                 for g in groups}
        return LoadedRun(run_dir, paths[first], exp, models[first], env, models, stats, ref.trust)
    path = model_path(run_dir, env.env_id, ref.load_best, ref.checkpoint)
    model = load(path)
    stats_path = (checkpoint_stats_path(run_dir, ref.checkpoint) if ref.checkpoint is not None
                  else best_stats_path(run_dir) if ref.load_best else run_dir / VECNORMALIZE_FILE)
    return LoadedRun(run_dir, path, exp, model, env, {"shared": model}, {"shared": _stats(stats_path, ref.trust)},
                     ref.trust)


def _stats(path: Path, trust: bool) -> Path | None:
    """The statistics file to use for ``path``: itself, a legacy pickle beside it (refused in one line now, before
    anything else runs, unless ``trust``), or None when the run has none."""
    from sbagents.safe_load import untrusted_pickle
    from sbagents.state_files import existing

    found = existing(path)
    if found is not None and found.suffix == ".pkl" and not trust:
        raise untrusted_pickle(found, "VecNormalize statistics")
    return found
