"""The three kinds of env sbagents trains, as objects resolved once with the env's name.

- :data:`SINGLE_AGENT`: a Gymnasium env (one agent; SB3's VecEnvs, EvalCallback, ONNX export).
- :data:`TEAM`: a PettingZoo ``ParallelEnv`` trained as a team of agents (parameter sharing or one model per group;
  the zoo keys ``policies``, ``groups``, ``agent_id``, ``critic``).
- :data:`GAME`: a turn-based PettingZoo (AEC) game with action masks, trained from one seat against opponents
  (self-play; the zoo key ``self_play``).

:class:`~sbagents.core.env_names.EnvRef` holds its kind (``ref.kind``). What a kind means in this layer (config
entries, the keys it owns, the experiment settings it adds, how to probe its observation spaces) lives on the kind;
what it means in a higher layer (building its VecEnvs, periodic and final evaluation, export, video) is registered
for the kind's class where that code lives, as a :func:`kind_operation` (a :func:`functools.singledispatch` whose
base refuses a kind it has no implementation for, instead of falling back to single-agent behaviour), so no layer
tests booleans to tell kinds apart. :data:`KIND_OPERATIONS` lists every operation; :func:`missing_operations` says
which ones a kind lacks (a test holds every registered kind to all of them), and :func:`register_env_kind` adds a
kind from outside the package: its :meth:`EnvKind.claim` is asked first when an ``--env`` name is resolved.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from sbagents.errors import UsageError

if TYPE_CHECKING:
    from sbagents.core.env_names import EnvRef

#: Zoo keys only PettingZoo teams take (:class:`TeamKind`).
MULTI_AGENT_KEYS: frozenset[str] = frozenset({"policies", "groups", "agent_id", "critic"})
#: Zoo keys only turn-based games take (:class:`GameKind`).
GAME_KEYS: frozenset[str] = frozenset({"self_play"})
#: Zoo entry of every PettingZoo team env without an entry of its own (before ``default``).
PETTINGZOO_DEFAULT_ENTRY = "pettingzoo"
#: The preprocessing wrapper an image env without an entry gets (as a zoo entry's ``env_wrapper`` item;
#: :mod:`sbagents.core.image_obs`): a PettingZoo parallel wrapper for teams, a Gymnasium wrapper otherwise.
PARALLEL_IMAGE_WRAPPER = {"sbagents.multiagent.preprocessing.ImagePreprocessing": {"grayscale": True,
                                                                                   "shape": [84, 84]}}
GYM_IMAGE_WRAPPER = {"stable_baselines3.common.atari_wrappers.WarpFrame": {"width": 84, "height": 84}}


class EnvKind:
    """What kind of env an :class:`~sbagents.core.env_names.EnvRef` names (see the module docstring).

    :cvar name: a short name for messages.
    :cvar pettingzoo: built from a PettingZoo module (``ref.source``).
    :cvar masked: its agents act with action masks (``action_masks()``).
    :cvar backends: the training backends that take it.
    :cvar image_wrapper: the wrapper of the image recipe for pixel observations (None: no recipe).
    :cvar own_keys: the kind-specific zoo keys this kind takes (the others' are refused).
    """

    name: ClassVar[str] = ""
    pettingzoo: ClassVar[bool] = False
    masked: ClassVar[bool] = False
    backends: ClassVar[tuple[str, ...]] = ("sb3",)
    image_wrapper: ClassVar[Mapping[str, Any] | None] = None
    own_keys: ClassVar[frozenset[str]] = frozenset()

    def config_entries(self, ref: EnvRef) -> tuple[str, ...]:
        """Zoo-config entries to look up, in order (``default`` comes after them)."""
        raise NotImplementedError

    def batched_source(self, ref: EnvRef) -> str:
        """The PettingZoo module a batched implementation is looked up by (``""``: by the Gymnasium id)."""
        return ""

    def check_entry(self, entry: Mapping[str, Any], source: str) -> None:
        """Refuse, in one line, zoo keys that belong to another kind.

        :param source: where the entry came from (file and entry), for the message.
        """
        for keys, owner in ((MULTI_AGENT_KEYS, "apply to PettingZoo envs only"),
                            (GAME_KEYS, "applies to turn-based games only")):
            misplaced = sorted((set(entry) & keys) - self.own_keys)
            if misplaced:
                raise UsageError(f"{', '.join(misplaced)} {owner} ({source})")

    def options(self, entry: Mapping[str, Any], source: str) -> Any:
        """The kind's own settings, read from its zoo keys (:attr:`own_keys`) of ``entry``: the experiment's
        :attr:`~sbagents.core.experiment.Experiment.kind_options` (default: None)."""
        return None

    def observation_spaces(self, ref: EnvRef, env_kwargs: dict[str, Any]) -> list[Any]:
        """The observation space of every agent (one for a Gymnasium env) of one env built with ``env_kwargs``."""
        from sbagents.core.env_names import make_registered

        env = make_registered(ref.env_id, ref.modules, **env_kwargs)
        found = [env.observation_space]
        env.close()
        return found

    def claim(self, name: str, modules: tuple[str, ...]) -> EnvRef | None:
        """The :class:`~sbagents.core.env_names.EnvRef` of ``--env name`` when it names an env of this kind, else
        None. :func:`~sbagents.core.env_names.resolve_env` asks every kind: those added with
        :func:`register_env_kind` first, then the built-in ones; ``modules`` are the ``--gym-packages`` already
        imported.

        :raises UsageError: a name of this kind's form that is wrong (e.g. a module that cannot be imported).
        """
        return None

    def refuse_backend(self, ref: EnvRef, backend: str) -> None:
        """Raise :class:`UsageError` when ``backend`` does not train this kind."""
        if backend not in self.backends:
            raise UsageError(f"{ref.env_id} is a {self.name} env: it trains with --backend "
                             f"{' / '.join(self.backends)}")

    def __repr__(self) -> str:
        return f"<env kind {self.name}>"


class SingleAgentKind(EnvKind):
    """A Gymnasium env."""

    name = "single-agent"
    backends = ("sb3", "rllib")
    image_wrapper = GYM_IMAGE_WRAPPER

    def config_entries(self, ref: EnvRef) -> tuple[str, ...]:
        return (ref.env_id, "atari") if ref.is_atari else (ref.env_id,)

    def claim(self, name: str, modules: tuple[str, ...]) -> EnvRef | None:
        from sbagents.core.env_names import claim_gymnasium_id

        return claim_gymnasium_id(name, modules)

    def refuse_backend(self, ref: EnvRef, backend: str) -> None:
        if backend not in self.backends:
            from sbagents.registration import PETTINGZOO_ENVS

            raise UsageError(f"--backend {backend} trains PettingZoo envs (e.g. {', '.join(PETTINGZOO_ENVS)} or a "
                             f"module such as mpe2.simple_spread_v3); got {ref.env_id}")


class TeamKind(EnvKind):
    """A PettingZoo ``ParallelEnv`` trained as a team."""

    name = "team"
    pettingzoo = True
    backends = ("sb3", "rllib")
    image_wrapper = PARALLEL_IMAGE_WRAPPER
    own_keys = MULTI_AGENT_KEYS

    def config_entries(self, ref: EnvRef) -> tuple[str, ...]:
        return tuple(dict.fromkeys((ref.source, ref.env_id, PETTINGZOO_DEFAULT_ENTRY)))

    def batched_source(self, ref: EnvRef) -> str:
        return ref.source

    def claim(self, name: str, modules: tuple[str, ...]) -> EnvRef | None:
        from sbagents.core.env_names import claim_pettingzoo

        return claim_pettingzoo(name, modules, self)

    def check_entry(self, entry: Mapping[str, Any], source: str) -> None:
        misplaced = sorted(set(entry) & {"monitor_kwargs", "eval_env_kwargs"})
        if misplaced:
            raise UsageError(f"{', '.join(misplaced)} apply to Gymnasium envs only (team VecEnvs write their own "
                             f"monitor and evaluate with env_kwargs) ({source})")
        super().check_entry(entry, source)

    def options(self, entry: Mapping[str, Any], source: str) -> Any:
        from sbagents.core.team_options import team_options

        return team_options(entry, source)

    def observation_spaces(self, ref: EnvRef, env_kwargs: dict[str, Any]) -> list[Any]:
        env = ref.parallel_env(**env_kwargs)
        found = [env.observation_space(agent) for agent in env.possible_agents]
        env.close()
        return found


class GameKind(EnvKind):
    """A turn-based PettingZoo (AEC) game with action masks, played from one seat."""

    name = "turn-based game"
    pettingzoo = True
    masked = True
    own_keys = GAME_KEYS

    def config_entries(self, ref: EnvRef) -> tuple[str, ...]:
        return tuple(dict.fromkeys((ref.source, ref.env_id)))

    def claim(self, name: str, modules: tuple[str, ...]) -> EnvRef | None:
        from sbagents.core.env_names import claim_pettingzoo

        return claim_pettingzoo(name, modules, self)

    def options(self, entry: Mapping[str, Any], source: str) -> Any:
        from sbagents.core.selfplay_options import SelfPlayOptions

        return SelfPlayOptions.from_mapping(entry.get("self_play"), source)

    def refuse_backend(self, ref: EnvRef, backend: str) -> None:
        if backend not in self.backends:
            raise UsageError(f"{ref.env_id} is a turn-based game: it trains with --backend sb3 and ppo_mask "
                             "(self-play with action masks)")


SINGLE_AGENT = SingleAgentKind()
TEAM = TeamKind()
GAME = GameKind()


R = TypeVar("R")

#: Every kind operation (``module.name`` -> its dispatcher), filled as the modules that define them are imported;
#: :data:`sbagents.registration.KIND_OPERATION_MODULES` names those modules.
KIND_OPERATIONS: dict[str, Any] = {}


def kind_operation(*also: type[EnvKind]) -> Callable[[Callable[..., R]], functools._SingleDispatchCallable[R]]:
    """Declare an operation every env kind must implement; the decorated function is the implementation of
    :class:`SingleAgentKind` and of the kinds in ``also``. Other kinds register theirs with ``@op.register``; calling
    the operation for a kind without one raises :class:`NotImplementedError` naming the operation (no silent
    single-agent fallback)."""

    def decorate(func: Callable[..., R]) -> functools._SingleDispatchCallable[R]:
        qualified = f"{func.__module__}.{func.__name__}"

        @functools.wraps(func)
        def missing(kind: EnvKind, *args: Any, **kwargs: Any) -> R:
            raise NotImplementedError(f"env kind {kind.name or type(kind).__name__!r} does not implement {qualified}: "
                                      f"register one with @{func.__name__}.register")

        dispatcher = functools.singledispatch(missing)
        kinds: tuple[type[EnvKind], ...] = (SingleAgentKind, *also)
        for cls in kinds:
            dispatcher.register(cls, func)
        KIND_OPERATIONS[qualified] = dispatcher
        return dispatcher

    return decorate


def load_kind_operations() -> dict[str, Any]:
    """:data:`KIND_OPERATIONS` with every module that defines operations imported."""
    import importlib

    from sbagents.registration import KIND_OPERATION_MODULES

    for module in KIND_OPERATION_MODULES:
        importlib.import_module(module)
    return KIND_OPERATIONS


def missing_operations(kind: EnvKind) -> list[str]:
    """The kind operations ``kind`` has no implementation of (after :func:`load_kind_operations`)."""
    return sorted(name for name, op in load_kind_operations().items() if op.dispatch(type(kind)) is op.registry[object])


#: Kinds added with :func:`register_env_kind`, asked first (latest first) when an ``--env`` name is resolved.
REGISTERED_KINDS: list[EnvKind] = []


def register_env_kind(kind: EnvKind) -> EnvKind:
    """Add an env kind from outside the package: ``kind.claim`` is asked before the built-in names are looked up.

    :raises ValueError: the kind lacks kind operations (:func:`missing_operations`; register them first).
    """
    missing = missing_operations(kind)
    if missing:
        raise ValueError(f"env kind {kind.name!r} lacks the operations {', '.join(missing)}")
    REGISTERED_KINDS.insert(0, kind)
    return kind


def builtin_kinds() -> tuple[EnvKind, ...]:
    """The kinds sbagents ships, in the order :func:`~sbagents.core.env_names.resolve_env` asks them."""
    return (SINGLE_AGENT, TEAM, GAME)
