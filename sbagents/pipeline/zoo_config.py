"""Reading RL Zoo format hyperparameter files safely.

A zoo file maps env ids (then ``atari``, then ``default``) to hyperparameters. Unlike RL Zoo nothing is
``eval``'d: values are YAML data, classes are named by import path, and CLI overrides ``key:value`` are
parsed as YAML scalars, lists or mappings with a safe loader.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from sbagents.errors import UsageError
from sbagents.pipeline.env_names import EnvRef
from sbagents.pipeline.options import TrainSpec

#: Keys of a zoo entry that configure the experiment rather than the algorithm constructor.
ZOO_KEYS: frozenset[str] = frozenset(
    {
        "n_timesteps",
        "n_envs",
        "policy",
        "normalize",
        "frame_stack",
        "env_wrapper",
        "vec_env_wrapper",
        "env_kwargs",
        "eval_env_kwargs",
        "monitor_kwargs",
        "callback",
        "noise_type",
        "noise_std",
        "policies",
        "groups",
        "agent_id",
        "critic",
        "deterministic_eval",
        "self_play",
        "constraint_kwargs",
    }
)
#: The keys of :data:`ZOO_KEYS` that only PettingZoo envs take.
MULTI_AGENT_KEYS: frozenset[str] = frozenset({"policies", "groups", "agent_id", "critic"})
#: The keys of :data:`ZOO_KEYS` that only turn-based games take.
GAME_KEYS: frozenset[str] = frozenset({"self_play"})


class ZooLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader that also reads ``1e6`` / ``3e-4`` as floats (YAML 1.2 style)."""


ZooLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+$"), list("-+0123456789.")
)


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file safely; malformed YAML raises :class:`UsageError` naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UsageError(f"cannot read config file {path}: {exc.strerror}") from None
    try:
        return yaml.load(text, Loader=ZooLoader)  # noqa: S506 - ZooLoader is a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise UsageError(f"malformed YAML in {path}{where}: {problem}") from None


def default_config_path(algo: str) -> Path:
    """The shipped ``zoo_configs/<algo>.yml``."""
    return Path(str(resources.files("sbagents.zoo_configs").joinpath(f"{algo}.yml")))


def lookup_entry(path: str | Path, keys: str | tuple[str, ...], atari: bool = False) -> dict[str, Any]:
    """The hyperparameters for an env in the zoo file ``path``.

    :param keys: the env id, or the entries to try in order (an env's
        :attr:`~sbagents.pipeline.env_names.EnvRef.config_keys`); ``default`` comes last.
    :param atari: with a single id: try RL Zoo's ``atari`` entry after it.

    Lookup order as RL Zoo: the exact env id, then ``atari`` for Atari ids (``pettingzoo`` for PettingZoo envs),
    then ``default``. A missing file counts as an empty one (every key then comes from the CLI and the defaults).
    """
    path = Path(path)
    names = (keys, *(("atari",) if atari else ())) if isinstance(keys, str) else tuple(keys)
    data = load_yaml(path) if path.exists() else {}
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise UsageError(f"{path} must map env ids to hyperparameters, got a {type(data).__name__}")
    for key in (*names, "default"):
        if key in data:
            entry = data[key] or {}
            if not isinstance(entry, dict):
                raise UsageError(f"{path}: entry {key!r} must be a mapping of hyperparameters")
            return dict(entry)
    if not path.exists():
        return {}
    known = ", ".join(str(k) for k in data) or "none"
    raise UsageError(f"{path} has no entry for {names[0]!r} and no 'default' (entries: {known})")


def parse_overrides(pairs: list[str] | None, flag: str = "-params") -> dict[str, Any]:
    """Parse ``key:value`` pairs; each value is read as a YAML scalar, list or mapping (never executed).

    >>> parse_overrides(["learning_rate:3e-4", "policy_kwargs:{net_arch: [64, 64]}"])
    {'learning_rate': 0.0003, 'policy_kwargs': {'net_arch': [64, 64]}}
    """
    result: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, raw = pair.partition(":")
        key = key.strip()
        if not sep or not key:
            raise UsageError(f"{flag} expects key:value pairs, got {pair!r}")
        try:
            value = yaml.load(raw, Loader=ZooLoader) if raw.strip() else None  # noqa: S506 - a yaml.SafeLoader
        except yaml.YAMLError:
            raise UsageError(
                f"{flag} {key}: value {raw!r} is not a YAML scalar, list or mapping"
            ) from None
        result[key] = value
    return result


def spec_entry(spec: TrainSpec, config_name: str, ref: EnvRef) -> tuple[dict[str, Any], str]:
    """The zoo entry of the env ``ref`` with the spec's overrides (``-params``, ``-n``, ``--env-kwargs``) applied,
    and where it came from (file and entry, for error messages). Shared by every backend's experiment builder.

    :param config_name: the shipped file to read when ``spec.conf_file`` is None (``zoo_configs/<name>.yml``).
    """
    spec.validate()
    path = Path(spec.conf_file) if spec.conf_file is not None else default_config_path(config_name)
    if spec.conf_file is not None and not path.exists():
        raise UsageError(f"config file {path} does not exist")
    entry = lookup_entry(path, ref.config_keys)
    entry.update(spec.hyperparams)
    if spec.n_timesteps is not None:
        entry["n_timesteps"] = spec.n_timesteps
    if spec.env_kwargs:
        entry["env_kwargs"] = {**(entry.get("env_kwargs") or {}), **spec.env_kwargs}
    return entry, f"{path}, entry for {ref.env_id}"
