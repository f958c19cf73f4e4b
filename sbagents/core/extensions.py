"""Training extensions: how a feature plugs into ``python -m sbagents.train`` without the pipeline knowing its name.

A feature (DP-SGD training, robust training, constrained training, the trust callbacks, replay-buffer saving, or one
of your own) is a :class:`TrainingExtension`. It **declares** what it is and supports (class variables: its name,
flags, spec type, the algorithms, env kinds and backends it trains, whether runs of one model per group take it) and
what it needs of other extensions (:meth:`~TrainingExtension.requires`), parses its flags into a frozen spec at the
CLI boundary, and takes part in a run through a few **phase hooks**, which
:func:`sbagents.pipeline.training.train_sb3` calls in this order for every extension of the run (in registration
order: the built-in ones first, then yours)::

    configure(spec | None, plan) -> spec | None   before the run dir exists: check the spec against the experiment
                                                  (may replace plan.exp); None: the run does not use the extension
    contribute(spec, plan) -> Contribution        same: what it adds to building each model (an env wrapper, the
                                                  model class and keyword arguments, how -i loads the model)
    callbacks(spec, ctx) -> [BaseCallback]        once each model exists: its SB3 callbacks
    finish(spec, ctx) -> dict                     once learning stopped (normally, by Ctrl-C or by an error) and the
                                                  models are saved: the model's items of summary.json
    judge(spec, summary, evaluation)              after the final evaluation (e.g. did the cost limit hold)
    describe(summary, run_dir) -> [str]           any finished run: the console lines of its summary.json items

and two hooks of the run's files: :meth:`~TrainingExtension.record` (its ``args.yml`` entries and the flags of
``command.txt``) and :meth:`~TrainingExtension.load_class` (the class that loads a run whose ``args.yml`` says it used
the extension).

A run of one model per group (``policies: per_group|per_agent``) takes the same phases, with ``callbacks``,
``finish`` and ``judge`` once per group's model and a context whose ``group`` names it (``ctx.file_name("x.json")``
is ``x.<group>.json``; ``summary.json`` keeps each group's items under ``by_group``); an extension that cannot serve
such runs sets :attr:`TrainingExtension.group_runs` to False and is refused in one line before anything is written.

:func:`prepare_extensions` (the pipeline's checks before the run dir exists) keeps the specs as given, applies every
requirement, then for each registered extension in order refuses an algorithm or env kind outside a spec's declared
:meth:`~TrainingExtension.capability` in one line and calls ``configure``, and ``contribute`` for the extensions the
run uses; two contributions that each pick the model class are refused in one line.

The built-in extensions are named in :data:`sbagents.registration.TRAINING_EXTENSIONS` and imported the first time
extensions are consulted. Register one of your own with :func:`register_extension` (``sbagents.register_extension``)
before building the ``train`` parser or calling :func:`sbagents.pipeline.backends.train` (``train --gym-packages
your_module`` imports it first); ``docs/extending.md`` has a worked example. The public module is
:mod:`sbagents.extensions`, which re-exports this one (the API lives in :mod:`sbagents.core`, beside the experiment it
types).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, TypeVar

from sbagents.capabilities import Capability
from sbagents.errors import UsageError

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnv

    from sbagents.core.env_names import EnvRef
    from sbagents.core.experiment import Experiment

SpecT = TypeVar("SpecT")


class _Taken:
    """The type of :data:`TAKEN`."""

    def __repr__(self) -> str:
        return "TAKEN"


#: A value of :meth:`TrainingExtension.requires`: the requiring extension takes the setting over (its ``configure``
#: reads the value the run gave from :attr:`ExtensionPlan.given`); the other extension gets the field's default, and a
#: value the run gave it is no conflict. Constrained training takes the trust extension's ``cost_limit``
#: (``--cost-limit`` is the limit it trains for, not a safety stop).
TAKEN: Any = _Taken()


class TrainingContext(Protocol):
    """What an extension's :meth:`~TrainingExtension.callbacks` and :meth:`~TrainingExtension.finish` see of one
    model of an SB3 run."""

    #: the resolved experiment
    exp: Experiment
    #: the env reference (``ref.env_id``, ``ref.kind``)
    ref: EnvRef
    run_dir: Path
    #: the model's training vec env (after every contribution's ``wrap_env``)
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
    #: per-model scratch space of the extensions (keyed by extension name): extensions are shared objects, so what
    #: ``callbacks`` makes for ``finish`` to read is kept here
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
    """What :meth:`TrainingExtension.configure` checks a spec against, before the run dir exists.

    :param algo: the ``--algo`` name.
    :param exp: the resolved experiment, as the extensions before this one configured it (an extension may replace
        it: ``plan.exp = dataclasses.replace(plan.exp, ...)``; :class:`~sbagents.core.experiment.Experiment` is
        frozen).
    :param ref: the env reference (``ref.env_id``, ``ref.kind``).
    :param resuming: ``-i`` continues a model.
    :param n_models: models the run trains (one per group of a team with ``policies: per_group``; else 1).
    :param groups: the groups of those models when there are several (else empty).
    :param specs: every extension's spec of this run by extension name (after the requirements of
        :meth:`TrainingExtension.requires`, and each extension's own ``configure`` once it ran).
    :param hyperparams: the ``-params`` overrides.
    :param given: every extension's spec as the run gave it, before the requirements (filled by
        :func:`prepare_extensions`).
    """

    algo: str
    exp: Experiment
    ref: EnvRef
    resuming: bool
    n_models: int = 1
    groups: tuple[str, ...] = ()
    specs: dict[str, Any] = field(default_factory=dict)
    hyperparams: Mapping[str, Any] = field(default_factory=dict)
    given: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Contribution:
    """What an extension adds to building each model of a run (:meth:`TrainingExtension.contribute`).

    :param wrap_env: wraps the model's training vec env (e.g. DP's frozen observation statistics).
    :param model_class: the SB3 class of the model instead of the algorithm's own (one extension of a run may pick
        it; two that do are refused in one line).
    :param model_kwargs: extra keyword arguments of the model (built or loaded).
    :param load: how ``-i`` continues the model, ``load(cls, path, **kwargs) -> model`` (None: sbagents' loading
        from plain data, :func:`sbagents.safe_load.load_model`).
    """

    wrap_env: Callable[[VecEnv], VecEnv] | None = None
    model_class: type | None = None
    model_kwargs: Mapping[str, Any] = field(default_factory=dict)
    load: Callable[..., BaseAlgorithm] | None = None


@dataclass(frozen=True)
class SpecRecord:
    """How a run's files record a spec (:meth:`TrainingExtension.record`).

    :param args: entries of the run's ``args.yml`` (what :meth:`TrainingExtension.load_class` reads back).
    :param flags: the command-line arguments that ask for the spec (``command.txt`` of a run started from Python; a
        backend outside :attr:`TrainingExtension.backends` names those starting with ``--`` in its refusal).
    """

    args: Mapping[str, Any] = field(default_factory=dict)
    flags: Sequence[str] = ()


class TrainingExtension(Generic[SpecT]):
    """A feature of ``train``: its declarations, its CLI boundary and its phase hooks (see the module docstring).

    Subclasses set :attr:`name` (unique), :attr:`title` (the ``--help`` group), :attr:`flags` (their flags, for
    refusals) and :attr:`spec_type`, declare what they support, and override the hooks they need; every hook has a
    do-nothing default.
    """

    #: Unique name (the key of :attr:`ExtensionPlan.specs`).
    name: ClassVar[str] = ""
    #: Title of the extension's argument group in ``--help``.
    title: ClassVar[str] = ""
    #: The flags of the extension, as refusals name them (e.g. ``"--dp-*"``).
    flags: ClassVar[str] = ""
    #: The frozen spec type this extension's hooks take (:func:`extension_for` finds the extension of a spec); a
    #: ``validate()`` method of the spec is called when a run pairs the spec with the extension (:func:`activate`).
    spec_type: ClassVar[type]
    #: Whether runs of one model per group (``policies: per_group``) take the extension: its model hooks then run
    #: once per group's model (else the run is refused in one line before anything is written).
    group_runs: ClassVar[bool] = True
    #: Backends the extension works with (another backend refuses it in one line: :func:`refused_flags`).
    backends: ClassVar[tuple[str, ...]] = ("sb3",)
    #: The ``--algo`` names the extension trains (None: any); :func:`prepare_extensions` refuses the others in one line.
    algos: ClassVar[tuple[str, ...] | None] = None
    #: The env kinds the extension trains, by :attr:`~sbagents.core.env_kinds.EnvKind.name` (``"single-agent"``,
    #: ``"team"``, ``"turn-based game"``, or a kind of yours; None: any); the others are refused in one line.
    kinds: ClassVar[tuple[str, ...] | None] = None
    #: Zoo entry key whose mapping overrides hyperparameters when the spec is present (None: none); given by
    #: ``-params`` to a run without the extension, it is refused in one line (it would change nothing).
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

    def is_active(self, spec: SpecT) -> bool:
        """Whether ``spec`` asks for anything (a spec of defaults given through the Python API may not)."""
        return True

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
        :meth:`configure` (None: nothing to check). Default: the one of :meth:`capabilities` (None when it declares
        several)."""
        declared = self.capabilities()
        return declared[0] if len(declared) == 1 else None

    def requires(self, spec: SpecT) -> Mapping[str, Mapping[str, Any]]:
        """Settings the extension needs of other extensions' specs: extension name -> {spec field: value}.

        :func:`prepare_extensions` applies them before any :meth:`configure`, to the other extension's spec of the
        run (else its :attr:`spec_type` built with defaults, turning it on); specs are then dataclasses. A value the
        run gave that is neither the field's default nor the required one is refused in one line, unless the required
        value is :data:`TAKEN`. Default: nothing.
        """
        return {}

    # --- the phase hooks ------------------------------------------------------------------------------------------
    def configure(self, spec: SpecT | None, plan: ExtensionPlan) -> SpecT | None:
        """Check ``spec`` against the experiment of ``plan`` and return the spec to train with (its algorithm and env
        kind are already checked against :meth:`capability`, and the requirements applied); may replace ``plan.exp``.

        Called for every registered extension, with None when the run gave it no spec (return a spec to take part
        anyway, e.g. to load what ``-i`` left beside its model); returning None leaves the extension out of the run.
        Default: ``spec`` unchanged.

        :raises UsageError: what the extension cannot do with this algorithm, env or combination of features.
        """
        return spec

    def contribute(self, spec: SpecT, plan: ExtensionPlan) -> Contribution:
        """What the extension adds to building each model of the run (default: nothing)."""
        return Contribution()

    def callbacks(self, spec: SpecT, ctx: TrainingContext) -> list[BaseCallback]:
        """The model's SB3 callbacks, once the model is built (or loaded by ``-i``): after sbagents' own, before the
        caller's. Keep in ``ctx.state`` what :meth:`finish` reads of them."""
        return []

    def finish(self, spec: SpecT, ctx: TrainingContext) -> dict[str, Any]:
        """Once learning stopped (normally, by Ctrl-C or by an error) and every model is saved: write what is left to
        write, and return the model's items of ``summary.json`` (JSON values: :func:`finite` clears NaNs; also
        ``TrainResult.results``)."""
        return {}

    def judge(self, spec: SpecT, summary: dict[str, Any], evaluation: Mapping[str, Any]) -> None:
        """Look at the final ``evaluation``; may update ``summary`` (the model's items) in place."""

    def describe(self, summary: Mapping[str, Any], run_dir: Path) -> list[str]:
        """The console lines of ``train`` for the extension's ``summary.json`` items (none when absent)."""
        return []

    # --- the run's files ------------------------------------------------------------------------------------------
    def record(self, spec: SpecT) -> SpecRecord:
        """The spec's entries of ``args.yml`` and its flags (default: none)."""
        return SpecRecord()

    def load_class(self, algo: str, args: Mapping[str, Any]) -> type | None:
        """The class that loads a run whose ``args.yml`` holds ``args`` (None: the algorithm's own class)."""
        return None


def finite(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, infinity) replaced by None, in nested dicts and lists: JSON that
    any reader parses (what :meth:`TrainingExtension.finish` returns goes into ``summary.json``)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {key: finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(item) for item in value]
    return value


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
    """An extension together with the spec of one run, and what it contributes to building the run's models (after
    :func:`prepare_extensions`)."""

    extension: TrainingExtension[Any]
    spec: Any
    contribution: Contribution = field(default_factory=Contribution)

    @property
    def name(self) -> str:
        """The extension's name."""
        return self.extension.name


def activate(specs: Sequence[Any]) -> list[ActiveExtension]:
    """Pair each spec with its extension, in registration order; specs that ask for nothing
    (:meth:`~TrainingExtension.is_active`) are dropped, the others' own values checked (their ``validate()`` method,
    where they have one).

    :raises UsageError: a spec of no registered extension, two specs of one extension, or a spec's own check.
    """
    by_name: dict[str, ActiveExtension] = {}
    for spec in specs:
        extension = extension_for(spec)
        if not extension.is_active(spec):
            continue
        if extension.name in by_name:
            raise UsageError(f"two {extension.name} specs given; a run takes one")
        check = getattr(spec, "validate", None)
        if callable(check):
            check()
        by_name[extension.name] = ActiveExtension(extension, spec)
    order = [ext.name for ext in registered_extensions()]
    return sorted(by_name.values(), key=lambda active: order.index(active.name))


def refused_flags(specs: Sequence[Any], backend: str) -> list[str]:
    """The flags of the extensions ``specs`` ask for that ``backend`` cannot honour (outside their
    :attr:`~TrainingExtension.backends`): each one's ``--`` flags of :meth:`~TrainingExtension.record`, else its
    :attr:`~TrainingExtension.flags`; a backend refuses them all in one line."""
    refused: list[str] = []
    for active in activate(specs):
        if backend not in active.extension.backends:
            given = [arg for arg in active.extension.record(active.spec).flags if arg.startswith("--")]
            refused += given or [active.extension.flags]
    return refused


def extension_capabilities() -> list[Capability]:
    """Every registered extension's :meth:`~TrainingExtension.capabilities`, in registration order."""
    return [capability for extension in registered_extensions() for capability in extension.capabilities()]


def prepare_extensions(plan: ExtensionPlan) -> list[ActiveExtension]:
    """Check every registered extension against ``plan`` before the run dir exists; the run's extensions.

    In this order: the specs as given are kept in ``plan.given``; the requirements of every spec
    (:meth:`~TrainingExtension.requires`) are applied to ``plan.specs`` (:func:`apply_requirements`); then, for each
    registered extension in registration order, a spec is checked against its :meth:`~TrainingExtension.capability`
    (:func:`check_capability`), and an extension without one has its :attr:`~TrainingExtension.overrides_key` refused
    when ``-params`` gives it; its :meth:`~TrainingExtension.configure` (which may replace ``plan.exp``) then gives
    its spec in ``plan.specs`` (None: none). Last, the run's extensions :meth:`~TrainingExtension.contribute`.

    :param plan: the run's plan (``plan.ref.kind.name`` and ``plan.ref.env_id`` name its env); updated in place.
    :returns: the run's extensions with their configured specs and contributions, in registration order.
    :raises UsageError: (one line) a requirement that conflicts with the run's specs, an algorithm or env kind a spec's
        capability does not take, an extension's own checks, or two contributions that each pick the model class.
    """
    plan.given = dict(plan.specs)
    apply_requirements(plan)
    for extension in registered_extensions():
        spec = plan.specs.get(extension.name)
        if spec is None:
            _refuse_unused_overrides(extension, plan)
        else:
            check_capability(extension, spec, plan)
        spec = extension.configure(spec, plan)
        if spec is None:
            plan.specs.pop(extension.name, None)
        else:
            plan.specs[extension.name] = spec
    actives = [dataclasses.replace(active, contribution=active.extension.contribute(active.spec, plan))
               for active in activate(list(plan.specs.values()))]
    pick = [active.extension.flags for active in actives if active.contribution.model_class is not None]
    if len(pick) > 1:
        raise UsageError(f"{' and '.join(pick)} each train a model class of their own: they cannot be combined yet "
                         "(one or the other)")
    return actives


def _refuse_unused_overrides(extension: TrainingExtension[Any], plan: ExtensionPlan) -> None:
    """An extension's :attr:`~TrainingExtension.overrides_key` given by ``-params`` to a run without the extension
    is refused (it would do nothing; an entry's own overrides wait for a run with the extension's flags)."""
    if extension.overrides_key and extension.overrides_key in plan.hyperparams:
        raise UsageError(f"-params {extension.overrides_key} applies only to runs with {extension.flags} (here it "
                         "would change nothing); drop it, or train with those flags")


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
    ``given`` (the run's spec; None: the extension's spec type built with defaults)."""
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
    """The spec a requirement starts from for an extension the run does not use: its spec type built with
    defaults."""
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
