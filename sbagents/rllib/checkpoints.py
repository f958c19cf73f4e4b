"""RLlib checkpoints of a run dir: written atomically, read back without unpickling anything.

RLlib's own checkpoint (``Algorithm.save_to_path``) is a tree of pickles (``class_and_ctor_args.pkl``,
``module_state.pkl``, ...): ``RLModule.from_checkpoint`` unpickles them, which runs whatever code a run dir from
elsewhere put there. So next to RLlib's files every checkpoint sbagents writes holds two plain-data files:

- :data:`~sbagents.rllib.MODULES_FILE` (JSON): the algorithm, the RLModule class (by name, from
  :data:`ALLOWED_MODULES`), the module ids with the agents each acts for, the run's ``model`` settings and how
  its continuous actions reach the env (``actions``: RLlib's ``normalize_actions`` and ``clip_actions``), and the
  algorithm settings that shape its module (``module_settings``: e.g. DQN's ``dueling``, SAC's ``twin_q``);
- :data:`~sbagents.rllib.WEIGHTS_FILE` (``.npz``, read with ``allow_pickle=False``): every module's weights,
  ``<module id>/<parameter name>``.

:func:`load_modules` rebuilds the RLModules from those (the class from the allow-list, the spaces from the env
the run names, the model settings through the same ``PPOConfig`` as training) and loads only the weights. A
checkpoint without them (made by an older sbagents, or by RLlib itself) is loaded through RLlib's unpickling only
with ``--trust-run``.

A checkpoint is written into a new hidden folder (:func:`sbagents.atomic.staging_dir`) and renamed into place
(:func:`sbagents.atomic.replace_dir`): a run killed mid-save keeps its previous checkpoint.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import logging
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from ray.rllib.algorithms.appo import APPOConfig
from ray.rllib.algorithms.dqn import DQNConfig
from ray.rllib.algorithms.impala import IMPALAConfig
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.algorithms.sac import SACConfig
from ray.rllib.core.rl_module.apis import TargetNetworkAPI
from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModule
from ray.rllib.core.rl_module.rl_module import RLModule

from sbagents.atomic import raise_disk_error, replace_dir, staging_dir, write_json, write_npz
from sbagents.core.env_kinds import EnvKind, SingleAgentKind, TeamKind
from sbagents.core.env_names import EnvRef
from sbagents.errors import UsageError
from sbagents.plain_data import TRUST_FLAG
from sbagents.rllib import MODULE_SUBDIR, MODULES_FILE, WEIGHTS_FILE
from sbagents.rllib.single_agent import DEFAULT_ACTIONS, SINGLE_MODULE, env_spaces

#: The RLModule classes rebuilt from a checkpoint's plain data, by algorithm: RLlib's own default modules only
#: (the algorithm's config class, and the module class its default spec builds; IMPALA's is PPO's).
ALLOWED_MODULES: dict[str, tuple[type[Any], str]] = {
    "ppo": (PPOConfig, "DefaultPPOTorchRLModule"), "appo": (APPOConfig, "DefaultAPPOTorchRLModule"),
    "impala": (IMPALAConfig, "DefaultPPOTorchRLModule"), "dqn": (DQNConfig, "DefaultDQNTorchRLModule"),
    "sac": (SACConfig, "DefaultSACTorchRLModule"),
}
#: Version of :data:`~sbagents.rllib.MODULES_FILE`'s layout.
FORMAT = 1


def save_checkpoint(algo: Any, path: Path, algo_name: str, model: Mapping[str, Any],
                    groups: Mapping[str, list[str]], learner_only: bool = False) -> Path:
    """Save ``algo`` to the checkpoint folder ``path`` atomically, with the plain-data module files; returns ``path``.

    :param algo: the RLlib ``Algorithm``.
    :param algo_name: ``--algo`` (a key of :data:`ALLOWED_MODULES`).
    :param model: the run's ``model`` settings (``DefaultModelConfig`` fields).
    :param groups: module id -> the agents it acts for.
    :param learner_only: save only the learner group (``<path>/learner_group``, the layout of a full checkpoint):
        the periodic module checkpoints, which leave the env runners' state out.
    """
    if algo_name not in ALLOWED_MODULES:
        raise UsageError(f"RLlib checkpoints of --algo {algo_name} are not supported (supported: "
                         f"{', '.join(ALLOWED_MODULES)})")
    staged = staging_dir(path)
    try:
        if learner_only:
            algo.learner_group.save_to_path(str((staged / "learner_group").resolve()))
        else:
            algo.save_to_path(str(staged.resolve()))
        weights = algo.learner_group.get_weights()
        arrays = {f"{module_id}/{name}": np.asarray(value) for module_id, state in weights.items()
                  for name, value in state.items()}
        write_npz(staged / WEIGHTS_FILE, **arrays)
        write_json(staged / MODULES_FILE, {
            "format": FORMAT, "algo": algo_name, "module_class": ALLOWED_MODULES[algo_name][1],
            "modules": {str(m): [str(a) for a in agents] for m, agents in groups.items() if m in weights},
            "model": dict(model),
            "actions": {"normalize": bool(algo.config.normalize_actions), "clip": bool(algo.config.clip_actions)},
            "module_settings": json.loads(json.dumps(algo.config._model_config_auto_includes)),  # tuples -> lists
        })
        return replace_dir(staged, path)
    except BaseException as exc:
        shutil.rmtree(staged, ignore_errors=True)
        raise_disk_error(exc, path)
        raise


def load_modules(checkpoint: str | Path, ref: EnvRef, env_kwargs: Mapping[str, Any] | None = None,
                 trust: bool = False) -> dict[str, RLModule]:
    """The learner's RLModules of an RLlib checkpoint written by sbagents, by module id, in inference mode.

    Reads :data:`~sbagents.rllib.MODULES_FILE` and :data:`~sbagents.rllib.WEIGHTS_FILE` only: nothing is
    unpickled and no Ray instance is started. A checkpoint without them is loaded with RLlib's
    ``RLModule.from_checkpoint`` (which unpickles its files) when ``trust``, else refused in one line.

    :param ref: the env the run names (the modules' spaces are its agents' spaces).
    :param env_kwargs: the run's env constructor arguments.
    :param trust: ``--trust-run``: the checkpoint comes from a trusted source.
    :raises UsageError: a missing, malformed or mismatched file, or an older checkpoint without ``trust``.
    """
    folder = Path(checkpoint)
    if (folder / MODULES_FILE).is_file():
        modules = _rebuild(folder, ref, dict(env_kwargs or {}))
    elif trust:
        modules = _unpickle(folder)
    else:
        if not folder.joinpath(*MODULE_SUBDIR).is_dir():
            raise UsageError(f"{folder} is not an RLlib checkpoint written by sbagents ({MODULES_FILE} is missing)")
        raise UsageError(f"{folder} has no {MODULES_FILE} (an RLlib checkpoint of an older sbagents): loading it "
                         f"would unpickle its files, which sbagents does not do by default: pass {TRUST_FLAG} if "
                         "you trust where the run came from")
    for module in modules.values():
        if isinstance(module, torch.nn.Module):  # TorchRLModule: inference mode for dropout/batch-norm layers
            module.eval()
    return modules


@contextlib.contextmanager
def _quiet_deprecations() -> Iterator[None]:
    """Silence RLlib's notice about its own RLModule constructor (RLlib builds its default modules that way)."""
    logger = logging.getLogger("ray._common.deprecation")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _unpickle(folder: Path) -> dict[str, RLModule]:
    """RLlib's own loader (``--trust-run``): unpickles the module classes, their arguments and their state."""
    path = folder.joinpath(*MODULE_SUBDIR)
    if not path.is_dir():
        raise UsageError(f"{folder} is not an RLlib checkpoint with a learner module ({path} is missing)")
    with _quiet_deprecations():
        multi = RLModule.from_checkpoint(str(path.resolve()))
    if not isinstance(multi, MultiRLModule):
        raise UsageError(f"{path} holds a single-agent RLModule; sbagents RLlib runs save a MultiRLModule")
    return dict(multi.items())


def _read_spec(path: Path) -> tuple[str, dict[str, list[str]], dict[str, Any]]:
    """Algorithm, module id -> agents and the module's model config (the ``model`` settings with the algorithm's
    ``module_settings``) of :data:`~sbagents.rllib.MODULES_FILE`, validated."""
    algo, groups, model, data = _read_fields(path)
    settings = data.get("module_settings", {})
    known = ALLOWED_MODULES[algo][0]()._model_config_auto_includes
    if not isinstance(settings, dict) or set(settings) - set(known) or not all(
            isinstance(v, (bool, int, float, str, list)) for v in settings.values()):
        raise UsageError(f"{path}: module_settings takes {', '.join(known) or 'nothing'} for {algo}, with plain "
                         "values")
    return algo, groups, {**settings, **dataclasses.asdict(DefaultModelConfig(**model))}  # as RLlib merges them


def _read_fields(path: Path) -> tuple[str, dict[str, list[str]], dict[str, Any], dict[str, Any]]:
    """Algorithm, module id -> agents and model settings of :data:`~sbagents.rllib.MODULES_FILE`, validated."""
    data = _read_json(path)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise UsageError(f"{path}: expected a JSON object with format {FORMAT}")
    algo = data.get("algo")
    if algo not in ALLOWED_MODULES:
        raise UsageError(f"{path}: algo {algo!r:.40} is not one sbagents rebuilds (accepted: "
                         f"{', '.join(ALLOWED_MODULES)})")
    expected = ALLOWED_MODULES[algo][1]
    if data.get("module_class") != expected:
        raise UsageError(f"{path}: module_class {data.get('module_class')!r:.60} is not RLlib's default module of "
                         f"{algo} (accepted: {expected})")
    modules = data.get("modules")
    if (not isinstance(modules, dict) or not modules
            or not all(isinstance(a, list) and a and all(isinstance(x, str) for x in a) for a in modules.values())):
        raise UsageError(f"{path}: modules must map module ids to non-empty lists of agent names")
    model = data.get("model")
    fields = {f.name for f in dataclasses.fields(DefaultModelConfig)}
    if not isinstance(model, dict) or set(model) - fields:
        bad = ", ".join(sorted(set(model) - fields)) if isinstance(model, dict) else repr(model)[:40]
        raise UsageError(f"{path}: model has unknown key(s) {bad}; accepted: {', '.join(sorted(fields))}")
    return str(algo), {str(m): list(a) for m, a in modules.items()}, model, data


def _rebuild(folder: Path, ref: EnvRef, env_kwargs: dict[str, Any]) -> dict[str, RLModule]:
    """Build the modules of :data:`~sbagents.rllib.MODULES_FILE` and load :data:`~sbagents.rllib.WEIGHTS_FILE`."""
    spec_path, weights_path = folder / MODULES_FILE, folder / WEIGHTS_FILE
    algo, groups, model = _read_spec(spec_path)
    spaces = _module_spaces(ref.kind, spec_path, groups, ref, env_kwargs)
    config_cls, class_name = ALLOWED_MODULES[algo]
    with _quiet_deprecations():
        try:
            config = config_cls().rl_module(model_config=model).multi_agent(
                policies=set(groups))
            multi = config.get_multi_rl_module_spec(spaces=spaces, inference_only=False).build()
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            raise UsageError(f"{spec_path}: cannot build the RLModules: {exc}".splitlines()[0]) from None
    modules = dict(multi.items())
    wrong = [m for m, module in modules.items() if type(module).__name__ != class_name]
    if wrong:
        raise UsageError(f"{spec_path}: RLlib built {type(modules[wrong[0]]).__name__}, not {class_name}")
    if not weights_path.is_file():
        raise UsageError(f"{folder} has {MODULES_FILE} but no {WEIGHTS_FILE}")
    states: dict[str, dict[str, torch.Tensor]] = {m: {} for m in modules}
    try:
        with np.load(weights_path, allow_pickle=False) as arrays:
            for key in arrays.files:
                module_id, _, name = key.rpartition("/")
                if module_id not in states:
                    raise UsageError(f"{weights_path}: {key!r:.80} is not a weight of modules "
                                     f"{', '.join(states)}")
                states[module_id][name] = torch.as_tensor(np.array(arrays[key]))
    except (OSError, ValueError, EOFError) as exc:  # not an npz, or object arrays (refused without pickle)
        raise UsageError(f"{weights_path} is not a plain-array .npz: {exc}".splitlines()[0]) from None
    for module_id, module in modules.items():
        if not isinstance(module, torch.nn.Module):
            raise UsageError(f"{spec_path}: module {module_id} is not a torch module")
        if isinstance(module, TargetNetworkAPI):  # DQN, SAC, APPO: the learner's copy holds target networks too
            module.make_target_networks()
        try:
            module.load_state_dict(states[module_id], strict=True)
        except RuntimeError as exc:
            raise UsageError(f"{weights_path}: the weights of module {module_id} do not fit the module the run "
                             f"describes: {exc}".splitlines()[0]) from None
    return modules


@functools.singledispatch
def _module_spaces(kind: EnvKind, spec_path: Path, groups: Mapping[str, list[str]], ref: EnvRef,
                   env_kwargs: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """Module id -> (observation, action space) of the modules a run on an env of ``kind`` trained."""
    raise UsageError(f"{spec_path}: --backend rllib does not train {kind.name} envs ({ref.env_id})")


@_module_spaces.register
def _team_spaces(kind: TeamKind, spec_path: Path, groups: Mapping[str, list[str]], ref: EnvRef,
                 env_kwargs: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """Module id -> (observation, action space) of a PettingZoo team's modules: their agents' spaces."""
    try:
        probe = ref.parallel_env(**env_kwargs)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"invalid env_kwargs for {ref.env_id}: {exc}") from None
    try:
        known = {str(a) for a in probe.possible_agents}
        spaces = {}
        for module_id, agents in groups.items():
            unknown = [a for a in agents if a not in known]
            if unknown:
                raise UsageError(f"{spec_path}: module {module_id} acts for {', '.join(unknown)}, not agents of "
                                 f"{ref.env_id}")
            obs, act = probe.observation_space(agents[0]), probe.action_space(agents[0])
            if any(probe.observation_space(a) != obs or probe.action_space(a) != act for a in agents):
                raise UsageError(f"{spec_path}: the agents of module {module_id} have different spaces in "
                                 f"{ref.env_id}")
            spaces[module_id] = (obs, act)
    finally:
        probe.close()
    return spaces


@_module_spaces.register
def _single_spaces(kind: SingleAgentKind, spec_path: Path, groups: Mapping[str, list[str]], ref: EnvRef,
                   env_kwargs: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """The one module of a run on a Gymnasium env, with the spaces the env runners gave it."""
    if list(groups) != [SINGLE_MODULE]:
        raise UsageError(f"{spec_path}: a run on the Gymnasium env {ref.env_id} has one module, {SINGLE_MODULE}; "
                         f"got {', '.join(groups)}")
    return {SINGLE_MODULE: env_spaces(ref, env_kwargs)}


def action_settings(checkpoint: str | Path) -> dict[str, bool]:
    """How the run's continuous actions reach the env (``normalize``, ``clip``: RLlib's ``normalize_actions`` and
    ``clip_actions``), from :data:`~sbagents.rllib.MODULES_FILE` (RLlib's defaults,
    :data:`~sbagents.rllib.single_agent.DEFAULT_ACTIONS`, where it says nothing)."""
    path = Path(checkpoint) / MODULES_FILE
    data = _read_json(path) if path.is_file() else {}
    given = data.get("actions", {}) if isinstance(data, dict) else {}
    if not isinstance(given, dict) or set(given) - {"normalize", "clip"} or \
            not all(isinstance(v, bool) for v in given.values()):
        raise UsageError(f"{path}: actions maps normalize and clip to true or false")
    return {**DEFAULT_ACTIONS, **given}


def _read_json(path: Path) -> Any:
    """The JSON of ``path`` (one line for a file that is not valid JSON)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UsageError(f"{path} is not valid JSON: {exc}") from None
