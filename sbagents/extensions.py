"""Training extensions: how a feature plugs into ``python -m sbagents.train`` without the pipeline knowing its name.

A feature (DP-SGD training, robust training, constrained training, the trust callbacks, replay-buffer saving, or one
of your own) is a :class:`TrainingExtension`. It declares its flags, parses them into a frozen spec at the CLI
boundary, checks the spec against the backend and the experiment, and then takes part in a one-model SB3 run
through the hooks below, which :func:`sbagents.pipeline.training.train_sb3` calls in this fixed order for every
extension whose spec the run carries (in registration order: the built-in ones first, then yours). A run of one
model per group (``policies: per_group|per_agent``) takes the same steps and calls the model hooks
(``wrap_train_env`` to ``results``) once per group's model, with a context whose ``group`` names it
(``ctx.file_name("x.json")`` is ``x.<group>.json``; ``summary.json`` keeps each group's items under ``by_group``);
an extension that cannot serve such runs sets
:attr:`TrainingExtension.group_runs` to False and is refused in one line before anything is written::

    add_arguments(group)                      the extension's flags, in an argument group of its own
    from_args(args) -> spec | None            the parsed flags as a frozen spec (None: not used by this run)
    unsupported_flags(spec, backend)          flags a backend cannot honour (refused in one line); default: SB3 only
    overrides_key                             zoo entry key of hyperparameters applied when the spec is present
    prepare(spec, plan) -> spec               check against the experiment (after the declared checks below)
    adjust_experiment(spec, exp) -> exp       e.g. DP's smaller networks
    record(spec) -> dict                      entries of args.yml (command_args(spec): flags for command.txt)
    wrap_train_env(spec, env) -> env          the training vec env
    model_class(spec, algo, cls, kwargs)      the SB3 class and extra keyword arguments of the model
    load_model(spec, cls, path, **kw)         how ``-i`` continues a model (None: the default rebuild from plain data)
    setup(spec, ctx)                          once the model exists (e.g. load what -i left beside it)
    callbacks(spec, ctx) -> [BaseCallback]    after sbagents' own callbacks, before the caller's
    after_learn(spec, ctx)                    once learning stopped (also after Ctrl-C), before the summary
    summary(spec, ctx) -> dict                keys of summary.json
    judge_evaluation(spec, summary, result)   after the final evaluation
    results(spec, callbacks) -> dict          what ``TrainResult.results``/the console shows of the callbacks

and, for any run (the spec is no longer there): :meth:`~TrainingExtension.summary_lines` (the console lines of
``train`` from ``summary.json``) and :meth:`~TrainingExtension.load_class` (the SB3 class that loads a run whose
``args.yml`` says it used the extension).

An extension also declares what it supports and what it needs, instead of checking it in its hooks::

    algos (class variable)                    the --algo names it trains (None: any)
    kinds (class variable)                    the env kinds it trains, by EnvKind.name (None: any)
    capabilities() -> [Capability]            its capabilities, with algos: its columns of the capability table
                                              (sbagents.algos.capability_rows); default: one named like the
                                              extension, of algos and kinds, when either is declared
    capability(spec) -> Capability | None     what a spec uses (default: the one capability; robust: its method's)
    requires(spec) -> {extension: {field: value}}   settings it needs of other extensions' specs (TAKEN: a setting
                                              it takes over)

:func:`prepare_extensions` (the pipeline's checks before the run dir exists) applies every requirement, refuses an
algorithm or env kind outside a spec's :meth:`~TrainingExtension.capability` in one line, then calls ``prepare``
and ``adjust_experiment``, or ``check_unused``, of every registered extension in order.

The built-in extensions are named in :data:`sbagents.registration.TRAINING_EXTENSIONS` and imported the first time
extensions are consulted. Register one of your own with :func:`register_extension` (``sbagents.register_extension``)
before building the ``train`` parser or calling :func:`sbagents.pipeline.backends.train` (``train --gym-packages
your_module`` imports it first); ``docs/extending.md`` has a worked example.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, TypeVar

from sbagents.errors import UsageError

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnv

SpecT = TypeVar("SpecT")


@dataclass(frozen=True)
class Capability:
    """What a feature supports: one column of the capability table (:func:`sbagents.algos.capability_rows`, ``train
    --list``), declared by the feature itself (a training extension, a backend, federated homes, the team kind's
    centralized critic).

    :param name: the column name (e.g. ``"dp"``, ``"robust:sa"``).
    :param description: what the column means (the legend of ``train --list``).
    :param algos: the ``--algo`` names it trains (None: any; such a capability adds no column).
    :param kinds: the env kinds it trains, by :attr:`~sbagents.core.env_kinds.EnvKind.name` (None: any).
    :param label: what its refusals call it (default: ``name``), e.g. ``"--robust sa"``.
    :param refusal: the refusal of an algorithm outside ``algos``, a :meth:`str.format` template of ``{label}``,
        ``{algos}`` (comma-separated) and ``{algo}``.
    """

    name: str
    description: str
    algos: tuple[str, ...] | None = None
    kinds: tuple[str, ...] | None = None
    label: str = ""
    refusal: str = "{label} trains {algos}, not {algo}"

    @property
    def subject(self) -> str:
        """What refusals call the capability."""
        return self.label or self.name

    def check_algo(self, algo: str) -> None:
        """Raise :class:`UsageError` (one line naming the accepted algorithms) unless the capability takes ``algo``."""
        if self.algos is not None and algo not in self.algos:
            raise UsageError(self.refusal.format(label=self.subject, algos=", ".join(self.algos), algo=algo))

    def check_kind(self, kind: str, env_id: str) -> None:
        """Raise :class:`UsageError` (one line naming the accepted kinds) unless the capability takes an env of the
        kind named ``kind`` (``env_id``: the env, for the message)."""
        if self.kinds is not None and kind not in self.kinds:
            raise UsageError(f"{self.subject} trains {' and '.join(self.kinds)} envs, not {kind} envs ({env_id})")


class _Taken:
    """The type of :data:`TAKEN`."""

    def __repr__(self) -> str:
        return "TAKEN"


#: A value of :meth:`TrainingExtension.requires`: the requiring extension takes the setting over (its ``prepare`` reads
#: the value the run gave from :attr:`ExtensionPlan.given`); the other extension gets the field's default, and a value
#: the run gave it is no conflict. Constrained training takes the trust extension's ``cost_limit`` (``--cost-limit``
#: is the limit it trains for, not a safety stop).
TAKEN: Any = _Taken()


class TrainingContext(Protocol):
    """What an extension's :meth:`~TrainingExtension.callbacks` / :meth:`~TrainingExtension.summary` see of an SB3 run.

    ``exp`` is the resolved :class:`~sbagents.core.experiment.Experiment`, ``ref`` the env reference.
    """

    exp: Any
    ref: Any
    run_dir: Path
    train_env: VecEnv
    model: BaseAlgorithm
    seed: int
    eval_freq: int
    eval_episodes: int
    #: the model ``-i`` continues (None: a new model) and whether its files may hold pickles (``--trust-run``)
    trained_agent: Path | None
    trust_run: bool
    #: env steps between checkpoints (``--save-freq``; <= 0: none)
    save_freq: int
    #: per-run scratch space of the extensions (keyed by extension name): extensions are shared objects
    state: dict[str, Any]
    #: the group of agents of this model in a run of one model per group (None: the run's one model)
    group: str | None

    def file_name(self, name: str) -> str:
        """The name of a file this model writes (``safety.json`` -> ``safety.<group>.json`` for a group's model)."""
        ...

    def calls(self, env_steps: int) -> int:
        """An env-step period as callback calls, at least 1 (one call per vec step of ``train_env``; for a group's
        model, one per step of the whole team, whose agents in every group count as env steps)."""
        ...

    def make_eval_env(self, n_envs: int, seed: int | None) -> VecEnv:
        """A fresh evaluation vec env of the run's env (VecNormalize statistics are not synced: a callback copies
        them from the training env when it evaluates)."""
        ...


@dataclass
class ExtensionPlan:
    """What :meth:`TrainingExtension.prepare` checks a spec against, before the run dir exists.

    :param algo: the ``--algo`` name.
    :param exp: the resolved experiment (already adjusted by the extensions before this one).
    :param ref: the env reference (``ref.env_id``).
    :param team: a PettingZoo env (a team of agents) rather than one Gymnasium agent.
    :param resuming: ``-i`` continues a model.
    :param n_models: models the run trains (one per group of a team with ``policies: per_group``; else 1).
    :param specs: every extension's spec of this run by extension name (after the requirements of
        :meth:`TrainingExtension.requires`, and each extension's own ``prepare`` once it ran).
    :param hyperparams: the ``-params`` overrides.
    :param given: every extension's spec as the run gave it, before the requirements (filled by
        :func:`prepare_extensions`).
    """

    algo: str
    exp: Any
    ref: Any
    team: bool
    resuming: bool
    n_models: int = 1
    specs: dict[str, Any] = field(default_factory=dict)
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    given: Mapping[str, Any] = field(default_factory=dict)


class TrainingExtension(Generic[SpecT]):
    """A feature of ``train`` (see the module docstring for the order of the hooks).

    Subclasses set :attr:`name` (unique), :attr:`title` (the ``--help`` group), :attr:`flags` (their flags, for
    refusals) and :attr:`spec_type`, and override the hooks they need; every hook has a do-nothing default.
    """

    #: Unique name (the key of :attr:`ExtensionPlan.specs`).
    name: ClassVar[str] = ""
    #: Title of the extension's argument group in ``--help``.
    title: ClassVar[str] = ""
    #: The flags of the extension, as refusals name them (e.g. ``"--dp-*"``).
    flags: ClassVar[str] = ""
    #: The frozen spec type this extension's hooks take (:func:`extension_for` finds the extension of a spec).
    spec_type: ClassVar[type]
    #: Whether runs of one model per group (``policies: per_group``) take the extension: its model hooks then run
    #: once per group's model (else the run is refused in one line before anything is written).
    group_runs: ClassVar[bool] = True
    #: Backends the extension works with.
    backends: ClassVar[tuple[str, ...]] = ("sb3",)
    #: The ``--algo`` names the extension trains (None: any); :func:`prepare_extensions` refuses the others in one line.
    algos: ClassVar[tuple[str, ...] | None] = None
    #: The env kinds the extension trains, by :attr:`~sbagents.core.env_kinds.EnvKind.name` (``"single-agent"``,
    #: ``"team"``, ``"turn-based game"``, or a kind of yours; None: any); the others are refused in one line.
    kinds: ClassVar[tuple[str, ...] | None] = None
    #: Zoo entry key whose mapping overrides hyperparameters when the spec is present (None: none).
    overrides_key: ClassVar[str | None] = None
    #: Zoo entry keys the extension reads (accepted in config files besides RL Zoo's).
    config_keys: ClassVar[frozenset[str]] = frozenset()

    # --- the CLI boundary -------------------------------------------------------------------------------------
    def add_arguments(self, group: argparse._ArgumentGroup) -> None:
        """Add the extension's flags to ``group`` (its own group of the ``train`` parser)."""

    def from_args(self, args: argparse.Namespace) -> SpecT | None:
        """The spec the parsed flags ask for, or None when the run does not use the extension.

        :raises UsageError: flags that do not fit together (one line naming them).
        """
        return None

    def default_spec(self) -> SpecT | None:
        """The spec of a run that gave none for this extension (None: the extension is off by default)."""
        return None

    def is_active(self, spec: SpecT) -> bool:
        """Whether ``spec`` asks for anything (a spec of defaults given through the Python API may not)."""
        return True

    def validate(self, spec: SpecT) -> None:
        """Check the spec's own values (default: its ``validate()`` method, if it has one)."""
        check = getattr(spec, "validate", None)
        if callable(check):
            check()

    # --- what the extension supports and needs -----------------------------------------------------------------
    def capabilities(self) -> list[Capability]:
        """The extension's columns of the capability table (:func:`sbagents.algos.capability_rows`).

        Default: one column named :attr:`name`, described by :attr:`title`, of :attr:`algos` and :attr:`kinds` (refusals
        name :attr:`flags`), when either is declared; none otherwise. Override it to name the column otherwise, or to
        declare several (methods that train different algorithms), with :meth:`capability` picking a spec's.
        """
        if self.algos is None and self.kinds is None:
            return []
        return [Capability(self.name, self.title, self.algos, self.kinds, label=self.flags)]

    def capability(self, spec: SpecT) -> Capability | None:
        """The capability ``spec`` uses, whose algorithms and env kinds :func:`prepare_extensions` checks before
        :meth:`prepare` (None: nothing to check). Default: the one of :meth:`capabilities` (None when it declares
        several)."""
        declared = self.capabilities()
        return declared[0] if len(declared) == 1 else None

    def requires(self, spec: SpecT) -> Mapping[str, Mapping[str, Any]]:
        """Settings the extension needs of other extensions' specs: extension name -> {spec field: value}.

        :func:`prepare_extensions` applies them before any :meth:`prepare`, to the other extension's spec of the run
        (or its :meth:`default_spec`, else its :attr:`spec_type` built with defaults, turning it on); specs are then
        dataclasses. A value the run gave that is neither the field's default nor the required one is refused in one
        line, unless the required value is :data:`TAKEN`. Default: nothing.
        """
        return {}

    # --- checks before the run dir exists ---------------------------------------------------------------------
    def unsupported_flags(self, spec: SpecT, backend: str) -> list[str]:
        """The flags of ``spec`` that ``backend`` cannot honour (default: :attr:`flags` unless the backend is one of
        :attr:`backends`); the backend refuses them all in one line."""
        return [] if backend in self.backends else [self.flags]

    def prepare(self, spec: SpecT, plan: ExtensionPlan) -> SpecT:
        """Check ``spec`` against the experiment of ``plan`` and return the spec to train with (the algorithm and env
        kind are already checked against :meth:`capability`, and the requirements applied).

        :raises UsageError: what the extension cannot do with this algorithm, env or combination of features.
        """
        return spec

    def check_unused(self, plan: ExtensionPlan) -> None:
        """Called instead of :meth:`prepare` when the run does not use the extension (e.g. refuse its config key
        given by ``-params``). Default: :attr:`overrides_key` given by ``-params`` is refused (it would do nothing;
        an entry's own overrides wait for a run with the extension's flags)."""
        if self.overrides_key and self.overrides_key in plan.hyperparams:
            raise UsageError(f"-params {self.overrides_key} applies only to runs with {self.flags} (here it would "
                             "change nothing); drop it, or train with those flags")

    def adjust_experiment(self, spec: SpecT, exp: Any) -> Any:
        """The experiment to train (default: ``exp`` unchanged)."""
        return exp

    def record(self, spec: SpecT) -> dict[str, Any]:
        """Entries of the run's ``args.yml`` (what :meth:`load_class` reads back)."""
        return {}

    def command_args(self, spec: SpecT) -> list[str]:
        """The flags that ask for ``spec``, for the ``command.txt`` of a run started from Python."""
        return []

    # --- building the run ---------------------------------------------------------------------------------------
    def wrap_train_env(self, spec: SpecT, env: VecEnv) -> VecEnv:
        """The training vec env (default: ``env`` unchanged)."""
        return env

    def model_class(self, spec: SpecT, algo: str, cls: type, kwargs: dict[str, Any]) -> tuple[type, dict[str, Any]]:
        """The SB3 class of the model and the extra keyword arguments it is built (or loaded) with."""
        return cls, kwargs

    def load_model(self, spec: SpecT, cls: type, path: Path, **kwargs: Any) -> BaseAlgorithm | None:
        """Load ``path`` to continue training (``-i``); None leaves it to :func:`sbagents.safe_load.load_model`."""
        return None

    def setup(self, spec: SpecT, ctx: TrainingContext) -> None:
        """Called once the model is built (or loaded by ``-i``), before :meth:`callbacks`."""

    def callbacks(self, spec: SpecT, ctx: TrainingContext) -> list[BaseCallback]:
        """SB3 callbacks of the run."""
        return []

    # --- after learning -----------------------------------------------------------------------------------------
    def after_learn(self, spec: SpecT, ctx: TrainingContext) -> None:
        """Called once learning stopped (normally, by Ctrl-C or by an error), after the model is saved."""

    def summary(self, spec: SpecT, ctx: TrainingContext) -> dict[str, Any]:
        """Keys added to ``summary.json``."""
        return {}

    def judge_evaluation(self, spec: SpecT, summary: dict[str, Any], result: dict[str, Any]) -> None:
        """Look at the final evaluation ``result`` (may update ``summary`` in place)."""

    def results(self, spec: SpecT, callbacks: Sequence[BaseCallback]) -> dict[str, Any]:
        """Final results of the run's callbacks worth showing (``TrainResult.results``)."""
        return {}

    # --- any finished run ---------------------------------------------------------------------------------------
    def summary_lines(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        """The console lines of ``train`` for the extension's ``summary.json`` keys (none when absent)."""
        return []

    def result_lines(self, results: Mapping[str, Any]) -> list[str]:
        """The console lines for :meth:`results` (and for ``evaluate``'s summary)."""
        return []

    def load_class(self, algo: str, args: Mapping[str, Any]) -> type | None:
        """The class that loads a run whose ``args.yml`` holds ``args`` (None: the algorithm's own class)."""
        return None


_REGISTRY: dict[str, TrainingExtension[Any]] = {}
_BUILTINS_LOADED = False


def _load_builtins() -> None:
    """Import the built-in extensions (:data:`sbagents.registration.TRAINING_EXTENSIONS`) once, ahead of any
    registered before."""
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    from sbagents.registration import TRAINING_EXTENSIONS

    earlier = dict(_REGISTRY)
    _REGISTRY.clear()
    for path in TRAINING_EXTENSIONS:
        module, _, name = path.partition(":")
        extension = getattr(importlib.import_module(module), name)()
        _REGISTRY[extension.name] = extension
    _REGISTRY.update({name: ext for name, ext in earlier.items() if name not in _REGISTRY})


def register_extension(extension: TrainingExtension[Any]) -> TrainingExtension[Any]:
    """Add ``extension`` to ``train`` (its flags, checks and hooks); returns it.

    Registering an extension of the same name again replaces it in place (a reloaded module, a test).

    :raises ValueError: an extension without a name or a spec type.
    """
    if not extension.name or not isinstance(getattr(extension, "spec_type", None), type):
        raise ValueError(f"{type(extension).__name__} needs a name and a spec_type")
    _REGISTRY[extension.name] = extension
    return extension


def unregister_extension(name: str) -> None:
    """Remove the extension ``name`` (no error when absent)."""
    _REGISTRY.pop(name, None)


def registered_extensions() -> list[TrainingExtension[Any]]:
    """Every registered extension: the built-in ones first (in hook order), then yours in registration order."""
    _load_builtins()
    return list(_REGISTRY.values())


def extension_for(spec: object) -> TrainingExtension[Any]:
    """The registered extension whose :attr:`~TrainingExtension.spec_type` ``spec`` is.

    :raises UsageError: a spec no registered extension takes.
    """
    for extension in registered_extensions():
        if isinstance(spec, extension.spec_type):
            return extension
    raise UsageError(f"{type(spec).__name__} is not the spec of a registered training extension "
                     "(sbagents.register_extension)")


def specs_from_args(args: argparse.Namespace) -> list[Any]:
    """The specs of every registered extension the parsed flags ask for, in registration order."""
    specs = []
    for extension in registered_extensions():
        spec = extension.from_args(args)
        if spec is not None:
            specs.append(spec)
    return specs


def config_keys() -> frozenset[str]:
    """The zoo entry keys the registered extensions read."""
    keys: frozenset[str] = frozenset()
    for extension in registered_extensions():
        keys |= extension.config_keys | ({extension.overrides_key} if extension.overrides_key else set())
    return keys


@dataclass(frozen=True)
class ActiveExtension:
    """An extension together with the spec of one run."""

    extension: TrainingExtension[Any]
    spec: Any

    @property
    def name(self) -> str:
        """The extension's name."""
        return self.extension.name


def activate(specs: Sequence[Any]) -> list[ActiveExtension]:
    """Pair each spec with its extension, in registration order, adding the default spec of extensions given none
    (:meth:`~TrainingExtension.default_spec`); specs that ask for nothing are dropped.

    :raises UsageError: a spec of no registered extension, or two specs of one extension.
    """
    given = {extension_for(spec).name for spec in specs}
    defaults = [ext.default_spec() for ext in registered_extensions() if ext.name not in given]
    by_name: dict[str, ActiveExtension] = {}
    for spec in [*specs, *(d for d in defaults if d is not None)]:
        extension = extension_for(spec)
        if not extension.is_active(spec):
            continue
        if extension.name in by_name:
            raise UsageError(f"two {extension.name} specs given; a run takes one")
        by_name[extension.name] = ActiveExtension(extension, spec)
    order = [ext.name for ext in registered_extensions()]
    return sorted(by_name.values(), key=lambda active: order.index(active.name))


def extension_capabilities() -> list[Capability]:
    """Every registered extension's :meth:`~TrainingExtension.capabilities`, in registration order."""
    return [capability for extension in registered_extensions() for capability in extension.capabilities()]


def prepare_extensions(plan: ExtensionPlan) -> list[ActiveExtension]:
    """Check every registered extension against ``plan`` before the run dir exists; the run's extensions.

    In this order: the specs as given are kept in ``plan.given``; the requirements of every spec
    (:meth:`~TrainingExtension.requires`) are applied to ``plan.specs`` (:func:`apply_requirements`); then, for each
    registered extension in registration order, one with a spec is checked against its
    :meth:`~TrainingExtension.capability` (:func:`check_capability`), and its
    :meth:`~TrainingExtension.prepare` replaces its spec in ``plan.specs`` and its
    :meth:`~TrainingExtension.adjust_experiment` replaces ``plan.exp``; one without calls
    :meth:`~TrainingExtension.check_unused`.

    :param plan: the run's plan (``plan.ref.kind.name`` and ``plan.ref.env_id`` name its env); updated in place.
    :returns: the extensions with their prepared specs, as :func:`activate` pairs them.
    :raises UsageError: (one line) a requirement that conflicts with the run's specs, an algorithm or env kind a spec's
        capability does not take, or whatever an extension's own checks refuse.
    """
    plan.given = dict(plan.specs)
    apply_requirements(plan)
    for extension in registered_extensions():
        spec = plan.specs.get(extension.name)
        if spec is None:
            extension.check_unused(plan)
            continue
        check_capability(extension, spec, plan)
        spec = extension.prepare(spec, plan)
        plan.specs[extension.name] = spec
        plan.exp = extension.adjust_experiment(spec, plan.exp)
    return activate(list(plan.specs.values()))


def check_capability(extension: TrainingExtension[Any], spec: Any, plan: ExtensionPlan) -> None:
    """Refuse in one line the env kind (first) or the algorithm of ``plan`` when the capability ``spec`` uses
    (:meth:`~TrainingExtension.capability`) does not take it."""
    capability = extension.capability(spec)
    if capability is not None:
        capability.check_kind(plan.ref.kind.name, plan.ref.env_id)
        capability.check_algo(plan.algo)


def apply_requirements(plan: ExtensionPlan) -> None:
    """Apply the :meth:`~TrainingExtension.requires` of every spec in ``plan.specs`` to the specs they name (a spec is
    added for an extension the run does not use yet). The requirements of a spec added this way are not applied.

    :raises UsageError: (one line) two extensions that require different values of one setting, a required setting
        the run gave another value, or a required extension that is not registered.
    """
    wanted: dict[str, dict[str, tuple[Any, str]]] = {}  # extension -> field -> (value, the flags that need it)
    for extension in registered_extensions():
        spec = plan.specs.get(extension.name)
        if spec is None:
            continue
        for target, settings in extension.requires(spec).items():
            fields_wanted = wanted.setdefault(target, {})
            for key, value in settings.items():
                earlier = fields_wanted.get(key)
                if earlier is not None and earlier[0] != value:
                    raise UsageError(f"{earlier[1]} and {extension.flags} need different {target} settings: "
                                     f"{key}={earlier[0]!r} and {key}={value!r} (drop one of them)")
                fields_wanted[key] = (value, extension.flags)
    for target, settings in wanted.items():
        plan.specs[target] = _required_spec(target, plan.specs.get(target), settings)


def _required_spec(target: str, given: Any, settings: Mapping[str, tuple[Any, str]]) -> Any:
    """The spec of the extension ``target`` with the required ``settings`` (field -> (value, who needs it)), from
    ``given`` (the run's spec; None: the extension's default)."""
    needed_by = ", ".join(dict.fromkeys(by for _, by in settings.values()))
    _load_builtins()
    extension = _REGISTRY.get(target)
    if extension is None:
        raise UsageError(f"{needed_by} needs the {target} extension, which is not registered")
    base = given if given is not None else _default_spec(extension, needed_by)
    if not dataclasses.is_dataclass(base) or isinstance(base, type):
        raise TypeError(f"{needed_by} requires settings of {target}, whose spec {type(base).__name__} is not a "
                        "dataclass")
    defaults = {f.name: _field_default(f) for f in dataclasses.fields(base)}
    changes: dict[str, Any] = {}
    for key, (value, by) in settings.items():
        if key not in defaults:
            raise TypeError(f"{by} requires {target} setting {key!r}, which {type(base).__name__} does not have")
        current = getattr(base, key)
        if value is TAKEN:
            if defaults[key] is dataclasses.MISSING:
                raise TypeError(f"{by} takes {target} setting {key!r} over, which has no default")
            changes[key] = defaults[key]
            continue
        if given is not None and current != value and current != defaults[key]:
            raise UsageError(f"{by} needs {target} {key}={value!r}, but the run asks {key}={current!r} (drop one of "
                             "them)")
        changes[key] = value
    return dataclasses.replace(base, **changes)


def _default_spec(extension: TrainingExtension[Any], needed_by: str) -> Any:
    """The spec a requirement starts from for an extension the run does not use: its default spec, else its spec
    type built with defaults."""
    spec = extension.default_spec()
    if spec is not None:
        return spec
    try:
        return extension.spec_type()
    except TypeError:
        raise UsageError(f"{needed_by} needs the {extension.name} extension, whose spec "
                         f"{extension.spec_type.__name__} has no defaults: give it one") from None


def _field_default(spec_field: dataclasses.Field[Any]) -> Any:
    """A dataclass field's default (:data:`dataclasses.MISSING`: none)."""
    if spec_field.default is not dataclasses.MISSING:
        return spec_field.default
    if spec_field.default_factory is not dataclasses.MISSING:
        return spec_field.default_factory()
    return dataclasses.MISSING
