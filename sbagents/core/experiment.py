"""Turning a zoo entry (plain YAML data) plus the CLI overrides into a validated SB3 experiment description.

Classes and functions are named by import path (``package.module.Name`` or ``package.module:Name``) or by a
short name from a fixed table; nothing is ``eval``'d.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch.nn as nn
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.utils import LinearSchedule

from sbagents.algos import ALGOS
from sbagents.core.env_kinds import SINGLE_AGENT, EnvKind
from sbagents.core.env_names import EnvRef
from sbagents.core.extensions import config_keys
from sbagents.core.options import TrainSpec
from sbagents.core.zoo_config import ZOO_KEYS, expression_values, spec_entry
from sbagents.errors import UsageError
from sbagents.import_paths import resolve_path

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "elu": nn.ELU,
    "leaky_relu": nn.LeakyReLU,
    "gelu": nn.GELU,
    "silu": nn.SiLU,
    "selu": nn.SELU,
    "sigmoid": nn.Sigmoid,
}

#: Short names usable in configs for classes RL Zoo configs mention by bare name.
KNOWN_CLASSES: dict[str, str] = {
    "HerReplayBuffer": "stable_baselines3.HerReplayBuffer",
    "AtariWrapper": "stable_baselines3.common.atari_wrappers.AtariWrapper",
    "TimeLimit": "gymnasium.wrappers.TimeLimit",
    "Adam": "torch.optim.Adam",
    "AdamW": "torch.optim.AdamW",
    "RMSprop": "torch.optim.RMSprop",
    "RMSpropTFLike": "stable_baselines3.common.sb2_compat.rmsprop_tf_like.RMSpropTFLike",
    "NatureCNN": "stable_baselines3.common.torch_layers.NatureCNN",
}


_SCHEDULABLE = ("learning_rate", "clip_range", "clip_range_vf")
_CLASS_KWARGS = ("replay_buffer_class", "features_extractor_class", "optimizer_class")
_RUNTIME_KWARGS = {"policy", "env", "verbose", "seed", "device", "tensorboard_log", "_init_setup_model"}


#: Packages whose classes a config may name (``env_wrapper``, ``callback``, ``policy_kwargs`` classes, ...) without
#: the user vouching for them; a module the user names (``--gym-packages``, ``--env module:...``) is trusted too.
ALLOWED_IMPORTS: tuple[str, ...] = ("sbagents", "stable_baselines3", "sb3_contrib", "gymnasium", "torch.nn",
                                    "torch.optim")


def _expected_bases(what: str) -> tuple[type, ...]:
    """The classes an import path of config key ``what`` must derive from, when it names an allowed package."""
    import gymnasium as gym
    import torch
    from pettingzoo.utils import BaseParallelWrapper, BaseWrapper
    from stable_baselines3.common.buffers import BaseBuffer
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnvWrapper

    return {
        "env_wrapper": (gym.Wrapper, BaseWrapper, BaseParallelWrapper),
        "vec_env_wrapper": (VecEnvWrapper,),
        "callback": (BaseCallback,),
        "optimizer_class": (torch.optim.Optimizer,),
        "replay_buffer_class": (BaseBuffer,),
    }.get(what, (nn.Module,))  # activation_fn, features_extractor_class


def import_object(path: str, what: str = "object", trusted_modules: tuple[str, ...] = ()) -> Any:
    """Resolve ``package.module.Name`` or ``package.module:Name`` (or a short name of :data:`KNOWN_CLASSES`).

    Only from the allow-list: a class of the kind ``what`` takes (a wrapper, a callback, a network module, ...) from
    :data:`ALLOWED_IMPORTS`, or anything from ``trusted_modules`` (the modules the user named on the command line).
    The path is checked before anything is imported, and an allowed package's object is found among the modules that
    package already loads (:func:`sbagents.import_paths.resolve_path`), so a config can neither run code on import
    nor call a function of its choosing.

    :raises UsageError: one line: a malformed path, a module outside the allow-list, or the wrong kind of object.
    """
    path = KNOWN_CLASSES.get(path, path)
    obj, trusted = resolve_path(path, what, ALLOWED_IMPORTS, trusted_modules)
    if not trusted and not (inspect.isclass(obj) and issubclass(obj, _expected_bases(what))):
        kinds = " or ".join(b.__name__ for b in _expected_bases(what))
        raise UsageError(f"{what} {path!r} is not a {kinds} class (a config names classes of that kind from the "
                         "allow-list; functions and other objects only from packages you name with --gym-packages)")
    return obj


@dataclass(frozen=True)
class Experiment:
    """A resolved experiment: what to build and how to train it.

    ``hyperparams`` keeps the plain-data entry (after overrides) as written to ``config.yml``.
    """

    algo: str
    env_id: str
    n_timesteps: int  # 0 when neither the config nor the CLI set it
    n_envs: int = 1
    policy: str = "MlpPolicy"
    normalize: bool | dict[str, Any] = False
    frame_stack: int | None = None
    env_wrapper: list[tuple[Any, dict[str, Any]]] = field(default_factory=list)
    vec_env_wrapper: list[tuple[Any, dict[str, Any]]] = field(default_factory=list)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    eval_env_kwargs: dict[str, Any] = field(default_factory=dict)  # on top of env_kwargs for evaluation envs only
    monitor_kwargs: dict[str, Any] = field(default_factory=dict)
    callbacks: list[tuple[Any, dict[str, Any]]] = field(default_factory=list)
    noise_type: str | None = None
    noise_std: float = 0.1
    algo_kwargs: dict[str, Any] = field(default_factory=dict)
    hyperparams: dict[str, Any] = field(default_factory=dict)
    deterministic_eval: bool = True  # greedy evaluations (False: sample, for policies that must stay stochastic)
    env_kind: EnvKind = SINGLE_AGENT  # the env's kind (its operations dispatch on it)
    #: the env kind's own settings, read from its zoo keys (:meth:`~sbagents.core.env_kinds.EnvKind.options`): a
    #: team's :class:`~sbagents.core.team_options.TeamOptions`, a game's
    #: :class:`~sbagents.core.selfplay_options.SelfPlayOptions`; None for one Gymnasium agent. Read them with the
    #: options type's ``of(exp)``.
    kind_options: Any = None

    def action_noise(self, n_actions: int) -> NormalActionNoise | OrnsteinUhlenbeckActionNoise | None:
        """The exploration noise object for ``noise_type`` (``normal`` or ``ornstein-uhlenbeck``)."""
        if self.noise_type is None:
            return None
        mean, sigma = np.zeros(n_actions), self.noise_std * np.ones(n_actions)
        if self.noise_type == "normal":
            return NormalActionNoise(mean, sigma)
        return OrnsteinUhlenbeckActionNoise(mean, sigma)


def accepted_algo_kwargs(algo: str) -> list[str]:
    """Constructor keywords of ``algo`` that a config may set."""
    params = inspect.signature(ALGOS[algo].cls.__init__).parameters
    return sorted(k for k in params if k not in _RUNTIME_KWARGS and k != "self" and not k.startswith("_"))


def _wrapper_list(value: Any, key: str, trusted: tuple[str, ...]) -> list[tuple[Any, dict[str, Any]]]:
    """``env_wrapper``/``callback`` values: a path, a list of paths, or ``{path: kwargs}`` items."""
    items = value if isinstance(value, list) else [value]
    result: list[tuple[Any, dict[str, Any]]] = []
    for item in items:
        if isinstance(item, str):
            result.append((import_object(item, key, trusted), {}))
        elif isinstance(item, dict) and len(item) == 1:
            (path, kwargs), = item.items()
            if kwargs is not None and not isinstance(kwargs, dict):
                raise UsageError(f"{key} {path!r}: its arguments must be a mapping, got {kwargs!r:.80}")
            result.append((import_object(str(path), key, trusted), dict(kwargs or {})))
        else:
            raise UsageError(f"{key} entries must be import paths or {{path: kwargs}} mappings, got {item!r}")
    return result


def _schedule(key: str, value: Any) -> Any:
    if isinstance(value, str) and value.startswith("lin_"):
        try:
            start = float(value[4:])
        except ValueError:
            raise UsageError(f"{key}: {value!r} is not a linear schedule like 'lin_3e-4'") from None
        return LinearSchedule(start, 0.0, 1.0)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise UsageError(f"{key} must be a number or a schedule 'lin_<start>', got {value!r}")
    return float(value)


def _policy_kwargs(value: Any, trusted: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise UsageError(f"policy_kwargs must be a mapping such as {{net_arch: [64, 64]}}, got {value!r}")
    kwargs = dict(value)
    act = kwargs.get("activation_fn")
    if isinstance(act, str):
        name = act.removeprefix("nn.").lower()
        if name in ACTIVATIONS:
            kwargs["activation_fn"] = ACTIVATIONS[name]
        else:
            kwargs["activation_fn"] = import_object(act, "activation_fn", trusted)
    for key in _CLASS_KWARGS:
        if isinstance(kwargs.get(key), str):
            kwargs[key] = import_object(kwargs[key], key, trusted)
    return kwargs


def _positive_int(entry: dict[str, Any], key: str, default: int | None) -> int | None:
    value = entry.get(key, default)
    if value is None:
        return None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise UsageError(f"{key} must be a positive integer, got {value!r}")
    return value


def resolve(algo: str, env_id: str, entry: dict[str, Any], source: str, kind: EnvKind = SINGLE_AGENT,
            trusted_modules: tuple[str, ...] = ()) -> Experiment:
    """Validate a zoo entry (after CLI overrides) and build the :class:`Experiment`.

    :param source: where the entry came from, for error messages (file and env id).
    :param kind: the env's kind, which owns its zoo keys (``policies``, ... for teams; ``self_play`` for games).
    :param trusted_modules: modules the user named, whose objects import paths may name (:func:`import_object`).
    """
    trusted = trusted_modules
    entry = expression_values(entry, source)  # RL Zoo's "dict(...)" strings, read as data
    kind.check_entry(entry, source)
    accepted = accepted_algo_kwargs(algo)
    zoo_keys = ZOO_KEYS | config_keys()  # RL Zoo's keys, sbagents' own and the training extensions'
    unknown = sorted(k for k in entry if k not in zoo_keys and k not in accepted)
    if unknown:
        raise UsageError(
            f"unknown hyperparameter(s) {', '.join(unknown)} for {algo} ({source}); "
            f"accepted: {', '.join(sorted(zoo_keys | set(accepted)))}"
        )
    n_timesteps = _positive_int(entry, "n_timesteps", None) or 0
    algo_kwargs: dict[str, Any] = {}
    for key, value in entry.items():
        if key in zoo_keys:
            continue
        if key in _SCHEDULABLE:
            value = _schedule(key, value)
        elif key == "policy_kwargs":
            value = _policy_kwargs(value, trusted)
        elif key in _CLASS_KWARGS and isinstance(value, str):
            value = import_object(value, key, trusted)
        elif key == "train_freq" and isinstance(value, list):
            value = tuple(value)
        algo_kwargs[key] = value
    noise_type = entry.get("noise_type")
    if noise_type not in (None, "normal", "ornstein-uhlenbeck"):
        raise UsageError(f"noise_type must be 'normal' or 'ornstein-uhlenbeck', got {noise_type!r}")
    for key in ("env_kwargs", "eval_env_kwargs", "monitor_kwargs"):
        if not isinstance(entry.get(key, {}), dict):
            raise UsageError(f"{key} must be a mapping, got {entry[key]!r} ({source})")
    deterministic_eval = entry.get("deterministic_eval", True)
    if not isinstance(deterministic_eval, bool):
        raise UsageError(f"deterministic_eval must be true or false, got {deterministic_eval!r} ({source})")
    normalize = entry.get("normalize", False)
    if not isinstance(normalize, bool | dict):
        raise UsageError(f"normalize must be true/false or a VecNormalize kwargs mapping, got {normalize!r}")
    return Experiment(
        algo=algo,
        env_id=env_id,
        n_timesteps=n_timesteps,
        n_envs=_positive_int(entry, "n_envs", 1) or 1,
        policy=str(entry.get("policy", "MlpPolicy")),
        normalize=normalize,
        frame_stack=_positive_int(entry, "frame_stack", None),
        env_wrapper=_wrapper_list(entry["env_wrapper"], "env_wrapper", trusted) if entry.get("env_wrapper") else [],
        vec_env_wrapper=(
            _wrapper_list(entry["vec_env_wrapper"], "vec_env_wrapper", trusted) if entry.get("vec_env_wrapper")
            else []
        ),
        env_kwargs=dict(entry.get("env_kwargs") or {}),
        eval_env_kwargs=dict(entry.get("eval_env_kwargs") or {}),
        monitor_kwargs=dict(entry.get("monitor_kwargs") or {}),
        callbacks=_wrapper_list(entry["callback"], "callback", trusted) if entry.get("callback") else [],
        noise_type=noise_type,
        noise_std=float(entry.get("noise_std", 0.1)),
        algo_kwargs=algo_kwargs,
        hyperparams=dict(entry),
        deterministic_eval=deterministic_eval,
        env_kind=kind,
        kind_options=kind.options(entry, source),
    )


def build_experiment(spec: TrainSpec, ref: EnvRef, overrides: tuple[str, ...] = ()) -> Experiment:
    """The :class:`Experiment` of ``spec`` on the env ``ref``: its zoo entry (``zoo_configs/<algo>.yml`` or
    ``spec.conf_file``, looked up by :attr:`~sbagents.core.env_names.EnvRef.config_keys`) with the overrides,
    validated.

    :param overrides: entry keys of hyperparameter overrides to apply (the run's extensions'
        :attr:`~sbagents.extensions.TrainingExtension.overrides_key`, e.g. ``robust_overrides``).
    """
    if spec.algo not in ALGOS:
        raise UsageError(f"unknown algo {spec.algo!r}; available: {', '.join(ALGOS)}")
    entry, where = spec_entry(spec, spec.algo, ref, overrides)
    from sbagents.core.image_obs import image_entry

    entry = image_entry(spec, ref, entry)
    return resolve(spec.algo, ref.env_id, entry, where, ref.kind, ref.trusted_modules())
