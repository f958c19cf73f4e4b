"""Reading RL Zoo format hyperparameter files safely.

A zoo file maps env ids (then ``atari``, then ``default``) to hyperparameters. Unlike RL Zoo nothing is
``eval``'d: values are YAML data, classes are named by import path, and CLI overrides ``key:value`` are
parsed as YAML scalars, lists or mappings with a safe loader. RL Zoo's Python-expression strings for mappings
(``policy_kwargs: "dict(activation_fn=nn.ReLU, net_arch=dict(pi=[64], vf=[64]))"``) are read by
:func:`python_literal`, which walks the expression's syntax tree and accepts data only (numbers, strings,
``True``/``False``/``None``, lists, tuples, ``{...}`` and ``dict(key=...)``, and dotted names such as ``nn.ReLU``,
kept as their text for the import allow-list): nothing in the string is run.
"""

from __future__ import annotations

import ast
import re
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from sbagents.core.env_kinds import GAME_KEYS, MULTI_AGENT_KEYS
from sbagents.core.env_names import EnvRef
from sbagents.core.options import TrainSpec
from sbagents.errors import UsageError

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
        "deterministic_eval",
    }
) | MULTI_AGENT_KEYS | GAME_KEYS  # and the keys the env kinds own (sbagents.core.env_kinds)


class ZooLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader that also reads ``1e6`` / ``3e-4`` as floats (YAML 1.2 style)."""


ZooLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+$"), list("-+0123456789.")
)


#: The deepest nesting of lists/mappings a YAML file (zoo config, ``-conf``, a run's ``config.yml`` / ``args.yml``)
#: may have, and the most values it may stand for once its aliases are expanded.
MAX_FILE_DEPTH = 64
MAX_FILE_NODES = 200_000


class FileLoader(ZooLoader):
    """:class:`ZooLoader` with bounds: at most :attr:`max_depth` levels of nesting (PyYAML's composer recurses
    once per level: a file of 5,000 ``[`` would end in a RecursionError) and integer literals no longer than an
    int64's (so ``int()`` never meets a 100,000-digit string). Aliases are accepted (RL Zoo files use anchors);
    :func:`load_yaml` bounds what they expand to."""

    max_depth = MAX_FILE_DEPTH
    _depth = 0

    def fetch_flow_collection_start(self, token_class: Any) -> None:
        """Refuse a ``[`` or ``{`` past :attr:`max_depth` open ones while scanning: PyYAML's scanner keeps
        every open bracket as a possible simple key and walks them all for each token (quadratic: ~0.8 s for a
        value of 1,000 ``[``), so the composer's check below would come only after that work."""
        if self.flow_level >= self.max_depth:
            raise yaml.scanner.ScannerError(None, None, f"nested deeper than {self.max_depth} levels",
                                            self.get_mark())
        super().fetch_flow_collection_start(token_class)  # type: ignore[misc]

    def compose_node(self, parent: Any, index: Any) -> Any:
        """Refuse deep nesting before composing the node."""
        if self._depth >= self.max_depth:
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {self.max_depth} levels",
                                              self.peek_event().start_mark)
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_bounded_int(self, node: yaml.ScalarNode) -> Any:
        """YAML's int, refused (a :class:`~yaml.constructor.ConstructorError`) when its literal is too long to
        be an int64."""
        if len(str(node.value).replace("_", "")) > 2 + 64:  # 0b + 64 binary digits is the longest int64
            raise yaml.constructor.ConstructorError(None, None, "integer out of range", node.start_mark)
        return self.construct_yaml_int(node)


FileLoader.add_constructor("tag:yaml.org,2002:int", FileLoader.construct_bounded_int)


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file safely (:class:`FileLoader`: nesting, expansion through aliases and integer literals
    bounded); malformed or oversized YAML raises :class:`UsageError` naming the file (and line)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UsageError(f"cannot read config file {path}: {exc.strerror}") from None
    try:
        data = yaml.load(text, Loader=FileLoader)  # noqa: S506 - FileLoader is a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise UsageError(f"malformed YAML in {path}{where}: {problem}") from None
    except (ValueError, TypeError, OverflowError) as exc:  # the SafeLoader's constructors on bad tagged values
        reason = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise UsageError(f"malformed YAML in {path}: {reason}") from None
    _check_expansion(data, path)
    return data


def _check_expansion(data: Any, path: Path) -> None:
    """Raise :class:`UsageError` if ``data`` (a loaded file) is nested deeper than :data:`MAX_FILE_DEPTH` or holds
    more than :data:`MAX_FILE_NODES` values once its aliases are expanded (``*name`` reuses a node, so a few lines
    can stand for billions of values, or for a structure that contains itself): code walking the settings would
    then recurse without end or run for hours."""
    stack: list[tuple[Any, int]] = [(data, 0)]
    seen = 0
    while stack:
        value, depth = stack.pop()
        seen += 1
        if seen > MAX_FILE_NODES:
            raise UsageError(f"{path} holds more than {MAX_FILE_NODES:,} values once its aliases (*name) are "
                             "expanded; a settings file is far smaller")
        if depth > MAX_FILE_DEPTH:
            raise UsageError(f"{path} is nested deeper than {MAX_FILE_DEPTH} levels (or an alias *name refers to "
                             "a value that contains it)")
        if isinstance(value, dict):
            stack.extend((item, depth + 1) for pair in value.items() for item in pair)
        elif isinstance(value, list | tuple | set):
            stack.extend((item, depth + 1) for item in value)


#: Entry keys whose value may be one of RL Zoo's Python-expression strings of a mapping (:func:`python_literal`).
EXPRESSION_KEYS: frozenset[str] = frozenset({"policy_kwargs", "normalize", "env_kwargs", "eval_env_kwargs",
                                             "monitor_kwargs", "replay_buffer_kwargs", "normalize_kwargs"})
#: Longest expression string read (RL Zoo's are a few hundred characters).
MAX_EXPRESSION_CHARS = 4096


def python_literal(text: str, where: str) -> Any:
    """The data of one of RL Zoo's Python-expression strings (``"dict(ortho_init=False, activation_fn=nn.ReLU)"``)
    without running it: ``dict(k=v, ...)`` and ``{...}`` become dicts, lists and tuples lists, constants stay,
    and a dotted name (``nn.ReLU``) becomes its text, which the caller resolves (activations by name, classes
    through the import allow-list).

    :raises UsageError: anything else (a call other than ``dict``, an operator, a subscript, a lambda, ...), or a
        string longer than :data:`MAX_EXPRESSION_CHARS`; one line naming ``where`` and what is accepted.
    """
    accepted = ("accepted: numbers, strings, True/False/None, lists, {...}, dict(key=value, ...) and dotted names "
                "like nn.ReLU")
    if len(text) > MAX_EXPRESSION_CHARS:
        raise UsageError(f"{where}: an expression of {len(text)} characters; at most {MAX_EXPRESSION_CHARS}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
        return _literal(tree.body, where, accepted)
    except SyntaxError as exc:
        raise UsageError(f"{where}: {text!r:.60} is not an expression ({exc.msg}); {accepted}") from None
    except (RecursionError, MemoryError):
        raise UsageError(f"{where}: the expression is nested too deeply; {accepted}") from None


def _dotted(node: ast.expr) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value)
        return None if head is None else f"{head}.{node.attr}"
    return None


def _literal(node: ast.expr, where: str, accepted: str) -> Any:
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float | str | bool | type(None)):
        return node.value
    if (isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant)
            and isinstance(node.operand.value, int | float) and not isinstance(node.operand.value, bool)):
        return -node.operand.value
    if isinstance(node, ast.List | ast.Tuple):
        return [_literal(item, where, accepted) for item in node.elts]
    if isinstance(node, ast.Dict):
        if any(key is None for key in node.keys):
            raise UsageError(f"{where}: ** inside a mapping is not data; {accepted}")
        return {_literal(k, where, accepted): _literal(v, where, accepted)  # type: ignore[arg-type]
                for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        if any(kw.arg is None for kw in node.keywords):
            raise UsageError(f"{where}: ** inside dict(...) is not data; {accepted}")
        return {str(kw.arg): _literal(kw.value, where, accepted) for kw in node.keywords}
    name = _dotted(node)
    if name is not None and name not in ("True", "False", "None"):
        return name
    shown = ast.unparse(node)
    raise UsageError(f"{where}: {shown[:60]!r} is not data; {accepted}")


def expression_values(entry: dict[str, Any], source: str) -> dict[str, Any]:
    """``entry`` with RL Zoo's expression strings under :data:`EXPRESSION_KEYS` read by :func:`python_literal`
    (a string that starts with ``dict(`` or ``{``); other values unchanged."""
    out = dict(entry)
    for key in EXPRESSION_KEYS & set(entry):
        value = entry[key]
        if isinstance(value, str) and value.lstrip().startswith(("dict(", "{")):
            out[key] = python_literal(value, f"{key} ({source})")
    return out


def default_config_path(algo: str) -> Path:
    """The shipped ``zoo_configs/<algo>.yml``."""
    return Path(str(resources.files("sbagents.zoo_configs").joinpath(f"{algo}.yml")))


def lookup_entry(path: str | Path, keys: str | tuple[str, ...], atari: bool = False) -> dict[str, Any]:
    """The hyperparameters for an env in the zoo file ``path``.

    :param keys: the env id, or the entries to try in order (an env's
        :attr:`~sbagents.core.env_names.EnvRef.config_keys`); ``default`` comes last.
    :param atari: with a single id: try RL Zoo's ``atari`` entry after it.

    Lookup order as RL Zoo: the exact env id, then ``atari`` for Atari ids (``pettingzoo`` for PettingZoo envs),
    then ``default``. A missing file counts as an empty one (every key then comes from the CLI and the defaults).
    """
    path = Path(path)
    names = (keys, *(("atari",) if atari else ())) if isinstance(keys, str) else tuple(keys)
    data = _entries(path)
    key = entry_name(path, names, data)
    if key is not None:
        entry = data[key] or {}
        if not isinstance(entry, dict):
            raise UsageError(f"{path}: entry {key!r} must be a mapping of hyperparameters")
        return dict(entry)
    if not path.exists():
        return {}
    known = ", ".join(str(k) for k in data) or "none"
    raise UsageError(f"{path} has no entry for {names[0]!r} and no 'default' (entries: {known})")


def _entries(path: Path) -> dict[Any, Any]:
    """The entries of the zoo file ``path`` (a missing file has none)."""
    data = load_yaml(path) if path.exists() else {}
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise UsageError(f"{path} must map env ids to hyperparameters, got a {type(data).__name__}")
    return data


def entry_name(path: str | Path, keys: tuple[str, ...], data: dict[Any, Any] | None = None) -> str | None:
    """Which entry of the zoo file ``path`` :func:`lookup_entry` reads for ``keys``: the first of them the file
    has, else ``default``, else None.

    :param data: the file's entries, when already read.
    """
    data = _entries(Path(path)) if data is None else data
    return next((key for key in (*keys, "default") if key in data), None)


#: The longest value ``-params`` / ``--env-kwargs`` take (characters), and their deepest nesting of lists/mappings.
MAX_OVERRIDE_CHARS = 10_000
MAX_OVERRIDE_DEPTH = 32
#: Integers a value may hold: numpy's and torch's int64 (no hyperparameter or env argument takes more).
INT64_RANGE = (-(2**63), 2**63 - 1)
_SCALARS = (str, bool, int, float, type(None))
_YAML_KINDS = {"bytes": "!!binary", "date": "date", "datetime": "timestamp", "set": "!!set"}


class OverrideLoader(FileLoader):
    """:class:`FileLoader` for one command-line value: no aliases either (``*name``: a value can then not expand
    into a huge or self-referencing structure), and at most :data:`MAX_OVERRIDE_DEPTH` levels of nesting."""

    max_depth = MAX_OVERRIDE_DEPTH

    def compose_node(self, parent: Any, index: Any) -> Any:
        """Refuse aliases, then compose as :class:`FileLoader`."""
        if self.check_event(yaml.AliasEvent):
            raise yaml.composer.ComposerError(None, None, "aliases (*name) are not accepted here",
                                              self.peek_event().start_mark)
        return super().compose_node(parent, index)


def _shorten(text: str, limit: int = 60) -> str:
    """``text`` for a one-line message: as is, or its start and its length."""
    return repr(text) if len(text) <= limit else f"{text[:40]!r}... ({len(text):,} characters)"


def _check_plain(value: Any, where: str, depth: int = 0) -> None:
    """Raise :class:`UsageError` unless ``value`` is plain data: None, bool, str, float, an int64, and lists and
    mappings (with scalar keys) of them."""
    if isinstance(value, bool) or value is None or isinstance(value, str | float):
        return
    if isinstance(value, int):
        if not INT64_RANGE[0] <= value <= INT64_RANGE[1]:
            raise UsageError(f"{where}: integer {_shorten(str(value))} is outside the 64-bit range "
                             "(-2**63 .. 2**63-1)")
        return
    if isinstance(value, list):
        for item in value:
            _check_plain(item, where, depth + 1)
        return
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, _SCALARS):
                raise UsageError(f"{where}: mapping keys must be plain names or numbers, got {_shorten(str(key))}")
            _check_plain(key, where, depth + 1)
            _check_plain(item, where, depth + 1)
        return
    kind = _YAML_KINDS.get(type(value).__name__, type(value).__name__)
    raise UsageError(f"{where}: the value reads as a YAML {kind}; quote it to pass text (key:'...')")


def parse_value(raw: str, where: str) -> Any:
    """One ``key:value`` value read as a YAML scalar, list or mapping (never executed), checked to be plain data
    (:func:`_check_plain`); :class:`UsageError` (one line naming ``where``) for anything else.

    >>> parse_value("[64, 64]", "-params net_arch")
    [64, 64]
    """
    if len(raw) > MAX_OVERRIDE_CHARS:
        raise UsageError(f"{where}: value of {len(raw):,} characters is too long (at most {MAX_OVERRIDE_CHARS:,})")
    if not raw.strip():
        return None
    try:
        value = yaml.load(raw, Loader=OverrideLoader)  # noqa: S506 - a yaml.SafeLoader
    except Exception as exc:  # the SafeLoader's constructors raise more than YAMLError on bad tagged values
        problem = " ".join(str(getattr(exc, "problem", None) or "").split())
        detail = f" ({problem[:100]})" if problem else ""
        raise UsageError(f"{where}: value {_shorten(raw)} is not a YAML scalar, list or mapping{detail}") from None
    _check_plain(value, where)
    return value


def parse_overrides(pairs: list[str] | None, flag: str = "-params") -> dict[str, Any]:
    """Parse ``key:value`` pairs; each value is read as a YAML scalar, list or mapping, never executed
    (:func:`parse_value`); keys are keyword names. Anything else is one :class:`UsageError` line.

    >>> parse_overrides(["learning_rate:3e-4", "policy_kwargs:{net_arch: [64, 64]}"])
    {'learning_rate': 0.0003, 'policy_kwargs': {'net_arch': [64, 64]}}
    """
    result: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, raw = pair.partition(":")
        key = key.strip()
        if not sep or not key:
            raise UsageError(f"{flag} expects key:value pairs, got {_shorten(pair)}")
        if not key.isidentifier() or len(key) > 100:
            raise UsageError(f"{flag} key {_shorten(key)} is not a keyword name (letters, digits and _)")
        result[key] = parse_value(raw, f"{flag} {key}")
    return result


def feature_overrides(entry: dict[str, Any], keys: tuple[str, ...], source: str) -> dict[str, Any]:
    """The hyperparameters the entry's override mappings ``keys`` set (the ``overrides_key`` of the run's training
    extensions, e.g. ``robust_overrides`` with ``--robust``: the flag's defaults then carry the recipe the entry's
    results were measured with; ``-params`` and ``-n`` still win), merged in order; :class:`UsageError` for a value
    that is not a mapping."""
    merged: dict[str, Any] = {}
    for key in keys:
        value = entry.get(key)
        if value is None:
            continue
        if not isinstance(value, dict):
            raise UsageError(f"{key} must be a mapping of hyperparameters, got {value!r} ({source})")
        merged.update(value)
    return merged


def spec_entry(spec: TrainSpec, config_name: str, ref: EnvRef, overrides: tuple[str, ...] = ()
               ) -> tuple[dict[str, Any], str]:
    """The zoo entry of the env ``ref`` with the spec's overrides (``-params``, ``-n``, ``--env-kwargs``) applied,
    and where it came from (file and entry, for error messages). Shared by every backend's experiment builder.

    :param config_name: the shipped file to read when ``spec.conf_file`` is None (``zoo_configs/<name>.yml``).
    :param overrides: entry keys of hyperparameter overrides (the run's extensions') applied between the entry and
        ``-params``.
    """
    spec.validate()
    path = Path(spec.conf_file) if spec.conf_file is not None else default_config_path(config_name)
    if spec.conf_file is not None and not path.exists():
        raise UsageError(f"config file {path} does not exist")
    entry = lookup_entry(path, ref.config_keys)
    entry.update(feature_overrides({**entry, **spec.hyperparams}, overrides, f"{path}, entry for {ref.env_id}"))
    entry.update(spec.hyperparams)
    if spec.n_timesteps is not None:
        entry["n_timesteps"] = spec.n_timesteps
    if spec.env_kwargs:
        entry["env_kwargs"] = {**(entry.get("env_kwargs") or {}), **spec.env_kwargs}
    return entry, f"{path}, entry for {ref.env_id}"
