"""Gymnasium registration of the sbagents environment IDs (done once, on ``import sbagents``)."""

from __future__ import annotations

#: Gymnasium ID -> entry point. Multi-agent PettingZoo envs are listed in :data:`PETTINGZOO_ENVS` instead.
GYM_ENVS: dict[str, str] = {
    "sbagents/GridWorld-v0": "sbagents.envs.gridworld:GridWorldEnv",
    "sbagents/HazardGridWorld-v0": "sbagents.envs.hazard_gridworld:HazardGridWorldEnv",
    "sbagents/SmartHome-v0": "sbagents.envs.smart_home:SmartHomeEnv",
    "sbagents/PickAndPlace-v0": "sbagents.envs.kuka:PickAndPlaceEnv",
    "sbagents/RobustPickAndPlace-v0": "sbagents.envs.kuka:RobustPickAndPlaceEnv",
    "sbagents/PickAndPlaceGoal-v0": "sbagents.envs.kuka:PickAndPlaceGoalEnv",
    "sbagents/KukaPickAndPlace-v0": "sbagents.envs.kuka:KukaPickAndPlaceEnv",
    "sbagents/RobustKukaPickAndPlace-v0": "sbagents.envs.kuka:RobustKukaPickAndPlaceEnv",
    "sbagents/CartPoleNoVel-v1": "sbagents.envs.no_velocity:CartPoleNoVelEnv",
    "sbagents/SmartHomePrefOnce-v0": "sbagents.envs.smart_home:SmartHomeEnv",
}

#: Env id -> the scripted expert that ``--policy scripted`` plays, imported when asked for: ``module:class`` of a
#: controller built on one env (``reset()``, ``act(obs)``), or of a policy built on the VecEnv (a team's; its class
#: says ``acts_on_vec_env``) (:mod:`sbagents.baselines`).
SCRIPTED_POLICIES: dict[str, str] = {
    "sbagents/GridWorld-v0": "sbagents.baselines.experts:ShortestPath",
    "sbagents/HazardGridWorld-v0": "sbagents.baselines.experts:ShortestPath",
    "sbagents/SmartHome-v0": "sbagents.baselines.experts:ComfortController",
    "sbagents/SmartHomePrefOnce-v0": "sbagents.baselines.experts:ComfortController",
    "sbagents/PickAndPlace-v0": "sbagents.envs.kuka.scripted:ScriptedPusher",
    "sbagents/RobustPickAndPlace-v0": "sbagents.envs.kuka.scripted:ScriptedPusher",
    "sbagents/KukaPickAndPlace-v0": "sbagents.envs.kuka.scripted_pick:ScriptedPicker",
    "sbagents/RobustKukaPickAndPlace-v0": "sbagents.envs.kuka.scripted_pick:ScriptedPicker",
    "treasure_hunt_v0": "sbagents.baselines.experts:GreedyTreasureTeam",
}

#: Registration keywords of the IDs in :data:`GYM_ENVS` that need more than an entry point.
GYM_ENV_KWARGS: dict[str, dict[str, object]] = {
    "sbagents/CartPoleNoVel-v1": {"max_episode_steps": 500, "reward_threshold": 475.0},
    "sbagents/SmartHomePrefOnce-v0": {"kwargs": {"preference_steps": 1}},  # preferences told at the reset only
}


def register_envs() -> None:
    """Register every ID in :data:`GYM_ENVS` that is not registered yet (idempotent).

    Does nothing where gymnasium is not installed (an edge device that only runs ``sbagents.serve``).
    """
    try:
        import gymnasium as gym
    except ImportError:
        return
    for env_id, entry_point in GYM_ENVS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, **GYM_ENV_KWARGS.get(env_id, {}))  # type: ignore[arg-type]


#: Short names of PettingZoo envs the CLIs accept -> where the env comes from: a module exposing
#: ``parallel_env(**kwargs)`` (PettingZoo's layout), or ``module:callable`` returning a ``ParallelEnv``.
PETTINGZOO_ENVS: dict[str, str] = {"treasure_hunt_v0": "sbagents.envs.treasure_hunt_v0"}


#: PettingZoo env modules with an equivalent array implementation -> the ``module:function`` that builds it from the
#: env kwargs, or returns None for kwargs it does not reproduce (then the module's own env is built). Named by path,
#: like :data:`GYM_ENVS`, so that resolving env names never imports the packages that implement them.
ARRAY_IMPLEMENTATIONS: dict[str, str] = {"mpe2.simple_spread_v3": "sbagents.batched.spread_env:array_parallel_env"}

#: PettingZoo env modules whose own env sbagents wraps in an observer that adds episode metrics (declared
#: ``info_metrics``) -> the ``module:function`` that wraps an env of the module (the array implementation above
#: declares the same metrics itself): simple spread's collisions and landmarks covered.
METRIC_OBSERVERS: dict[str, str] = {"mpe2.simple_spread_v3": "sbagents.batched.spread_metrics:spread_metrics_env"}

#: The modules that define env-kind operations (:func:`sbagents.core.env_kinds.kind_operation`): importing them
#: fills :data:`sbagents.core.env_kinds.KIND_OPERATIONS`.
KIND_OPERATION_MODULES: tuple[str, ...] = (
    "sbagents.env_construction",
    "sbagents.env_factory",
    "sbagents.pipeline.kinds",
    "sbagents.pipeline.models",
    "sbagents.pipeline.evaluation",
    "sbagents.pipeline.collecting",
    "sbagents.deploy.exporting",
    "sbagents.visualize.video",
)

#: The built-in training backends (``--backend``, :mod:`sbagents.core.backends`) as ``module:class`` paths, imported
#: the first time a backend is asked for (the default one first).
BACKENDS: dict[str, str] = {
    "sb3": "sbagents.pipeline.sb3_backend:Sb3Backend",
    "rllib": "sbagents.rllib.backend:RllibBackend",
}

#: Where the capability table's columns come from, in column order (the training extensions' first): ``module:function``
#: paths of functions returning :class:`sbagents.capabilities.Capability` objects, imported by :mod:`sbagents.algos`
#: when the table or ``algos_with`` needs them (by path: the federated package is of a higher layer, and the
#: extensions' and backends' registries are in :mod:`sbagents.core`, which imports ``sbagents.algos``).
CAPABILITY_SOURCES: tuple[str, ...] = (
    "sbagents.core.extensions:extension_capabilities",
    "sbagents.federated.settings:capabilities",
    "sbagents.core.team_options:capabilities",
    "sbagents.core.backends:backend_capabilities",
)

#: The built-in training extensions (:mod:`sbagents.extensions`), in hook order, as ``module:class`` paths like
#: :data:`GYM_ENVS`: :func:`sbagents.extensions.registered_extensions` imports them the first time extensions are
#: consulted, so that nothing below the pipeline imports the feature packages.
TRAINING_EXTENSIONS: tuple[str, ...] = (
    "sbagents.replay.extension:ReplayBufferExtension",
    "sbagents.private.extension:PrivacyExtension",
    "sbagents.robust.extension:RobustExtension",
    "sbagents.constrained.extension:ConstraintExtension",
    "sbagents.callbacks.extension:TrustExtension",
    "sbagents.datasets.extension:PretrainExtension",
    "sbagents.datasets.extension:DemosExtension",
)


def register_pettingzoo_env(name: str, source: str) -> None:
    """Let ``--env NAME`` mean the PettingZoo env at ``source`` (``pkg.my_env_v0`` or ``pkg.module:make_env``).

    Call it when your package is imported, and name the package with ``--gym-packages`` (any env module path works
    on the CLI without registering; a short name is a convenience). Run dirs and zoo config entries then use
    ``NAME``. Re-registering a name with another source replaces it.

    :raises ValueError: ``name`` is empty or holds ``/`` or ``:``, or ``source`` is not a dotted module path.
    """
    if not name or "/" in name or ":" in name:
        raise ValueError(f"a PettingZoo env name must be a plain word like 'my_env_v0', got {name!r}")
    module = source.partition(":")[0]
    if not module or not all(part.isidentifier() for part in module.split(".")):
        raise ValueError(f"source must be a module path like 'my_pkg.my_env_v0' (or 'pkg.mod:fn'), got {source!r}")
    PETTINGZOO_ENVS[name] = source

