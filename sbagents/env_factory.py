"""Building the vectorised training and evaluation envs of an :class:`~sbagents.core.experiment.Experiment` (one env
of each kind comes from :mod:`sbagents.env_construction`).

It knows every kind of env (Gymnasium ids, PettingZoo teams, turn-based games, batched and EnvPool vec envs), so it
sits among the feature packages it composes (:mod:`sbagents.multiagent`, :mod:`sbagents.games`,
:mod:`sbagents.batched`, :mod:`sbagents.atari`), below those that play a finished run (:mod:`sbagents.deploy`,
:mod:`sbagents.visualize`) and the pipeline; none of the packages it composes imports it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    SubprocVecEnv,
    VecEnv,
    VecFrameStack,
    VecNormalize,
)

from sbagents.core.env_kinds import EnvKind, GameKind, TeamKind, kind_operation
from sbagents.core.env_names import EnvRef
from sbagents.core.experiment import Experiment
from sbagents.core.team_options import TeamOptions
from sbagents.env_construction import check_env_kwargs, env_fn, env_kwargs_error, missing_dependency_error
from sbagents.errors import UsageError
from sbagents.state_files import existing, load_vecnormalize

VEC_ENV_CLASSES: dict[str, type[DummyVecEnv] | type[SubprocVecEnv]] = {
    "dummy": DummyVecEnv,
    "subproc": SubprocVecEnv,
}
VEC_ENV_TYPES = ("auto", "dummy", "subproc", "batched", "envpool")


def _chain(wrappers: list[tuple[Any, dict[str, Any]]]) -> Callable[[gym.Env], gym.Env] | None:
    if not wrappers:
        return None

    def wrap(env: gym.Env) -> gym.Env:
        for wrapper, kwargs in wrappers:
            env = _wrapped(wrapper, env, kwargs, "env_wrapper")
        return env

    return wrap


def _wrapped(wrapper: Any, env: Any, kwargs: dict[str, Any], key: str) -> Any:
    """``wrapper(env, **kwargs)``; a wrapper of the config that rejects its arguments (a ``TypeError`` or
    ``ValueError`` as it is built) is one :class:`UsageError` line naming it."""
    try:
        return wrapper(env, **kwargs)
    except (TypeError, ValueError) as exc:
        name = f"{getattr(wrapper, '__module__', '')}.{getattr(wrapper, '__qualname__', wrapper)}"
        given = ", ".join(f"{k}={v!r:.40}" for k, v in kwargs.items()) or "no arguments"
        reason = " ".join(str(exc).split())[:160] or type(exc).__name__
        raise UsageError(f"{key} {name} cannot be built with {given}: {reason}") from None


def _team_vecs(
    exp: Experiment, ref: EnvRef, n_envs: int, seed: int | None, monitor: str | None, kind: str,
    kwargs: dict[str, Any], wrapper: Callable[[Any], Any] | None,
) -> dict[str, VecEnv]:
    """The group VecEnvs of one team of ``n_envs`` copies of a PettingZoo env (one group for ``shared``)."""
    from sbagents.multiagent.factory import ParallelEnvFactory
    from sbagents.multiagent.groups import team_vec_envs

    wrappers = [*exp.env_wrapper, *([(wrapper, {})] if wrapper is not None else [])]
    factory = ParallelEnvFactory(ref.source, ref.modules, kwargs, wrappers)
    return dict(team_vec_envs(factory, n_envs, TeamOptions.of(exp), seed=seed, monitor_dir=monitor,
                              subproc=kind == "subproc"))


def make_team_vecs(
    exp: Experiment, ref: EnvRef, n_envs: int, seed: int | None, monitor_dir: str | Path | None = None,
    vec_env: str = "auto", env_kwargs: dict[str, Any] | None = None, wrapper: Callable[[Any], Any] | None = None,
) -> dict[str, VecEnv]:
    """The VecEnv of every group of a PettingZoo experiment (group -> VecEnv; ``shared``: one group), each with
    the experiment's VecEnv wrappers and frame stacking, before normalisation. They step one team together.

    :param wrapper: an extra outermost PettingZoo parallel wrapper of every copy (rules out the batched VecEnvs).
    """
    kwargs = {**exp.env_kwargs, **(env_kwargs or {})}
    check_env_kwargs(ref, {k: v for k, v in kwargs.items() if k != "render_mode"})
    kind = vec_env_kind(vec_env, exp, ref, kwargs)
    if wrapper is not None and kind == "batched":
        kind = "dummy"
    monitor = str(monitor_dir) if monitor_dir is not None else None
    with _one_line_env_errors(ref, kwargs):
        venvs = (_team_vecs(exp, ref, n_envs, seed, monitor, kind, kwargs, wrapper) if kind != "batched" else
                 {"shared": _make_base_vec(exp, ref, n_envs, seed, monitor_dir, kind, kwargs, None)})
    return {name: _vec_wrappers(venv, exp) for name, venv in venvs.items()}


def _vec_wrappers(venv: VecEnv, exp: Experiment) -> VecEnv:
    for wrapper, wrapper_kwargs in exp.vec_env_wrapper:
        venv = _wrapped(wrapper, venv, wrapper_kwargs, "vec_env_wrapper")
    if exp.frame_stack:
        venv = VecFrameStack(venv, exp.frame_stack)
    return venv


@kind_operation(GameKind)
def _batchable_options(kind: EnvKind, exp: Experiment) -> bool:
    """Whether the kind's options of ``exp`` leave it to a batched VecEnv (no options: yes)."""
    return True


@_batchable_options.register
def _team_batchable_options(kind: TeamKind, exp: Experiment) -> bool:
    """A team: a plain ``policies: shared`` team (no agent id, a local critic)."""
    team = TeamOptions.of(exp)
    return team.policies == "shared" and not team.agent_id and team.critic == "local"


def vec_env_kind(vec_env: str, exp: Experiment, ref: EnvRef, env_kwargs: dict[str, Any] | None = None) -> str:
    """Which VecEnv ``--vec-env`` means here: ``auto`` picks ``batched`` where a batched implementation exists
    (GridWorld, TreasureHunt, MPE simple spread with batchable ``env_kwargs``; no Gymnasium wrappers, Monitor
    kwargs, or team options other than a plain ``policies: shared`` team), else ``dummy``.

    :param env_kwargs: the env kwargs the VecEnv is built with (the experiment's and the call's).
    :raises UsageError: an unknown ``vec_env``, or ``batched`` where it does not apply.
    """
    from sbagents.batched import BATCHED_SUPPORT, batched_env_id, unbatchable_kwargs

    if vec_env not in VEC_ENV_TYPES:
        raise UsageError(f"--vec-env must be one of {', '.join(VEC_ENV_TYPES)}, got {vec_env!r}")
    plain_team = _batchable_options(exp.env_kind, exp)
    batched_id = batched_env_id(ref.env_id, ref.kind.batched_source(ref))
    problems = [] if batched_id is None else unbatchable_kwargs(batched_id, env_kwargs or {})
    batchable = (batched_id is not None and not problems and not exp.env_wrapper and not exp.monitor_kwargs
                 and plain_team)
    if vec_env == "batched" and not batchable:
        got = f"; got {', '.join(problems)}" if problems else ""
        raise UsageError(f"--vec-env batched supports {BATCHED_SUPPORT} with a plain policies: shared team, "
                         f"without env_wrapper/monitor_kwargs{got}")
    if vec_env == "envpool":  # EnvPool's Atari (sbagents.atari): training picks it for auto, see training_vec_env
        from sbagents.atari.envpool_support import check_envpool

        check_envpool(exp, ref, env_kwargs)
    if vec_env == "auto":
        return "batched" if batchable else "dummy"
    return vec_env


def make_vec(
    exp: Experiment,
    ref: EnvRef,
    n_envs: int,
    seed: int | None,
    monitor_dir: str | Path | None = None,
    vec_env: str = "auto",
    env_kwargs: dict[str, Any] | None = None,
    wrapper: Callable[[Any], Any] | None = None,
) -> VecEnv:
    """The vectorised env with wrappers and frame stacking, before normalisation.

    :param n_envs: number of copies (for multi-agent envs: copies of the whole team).
    :param vec_env: ``auto``, ``dummy``, ``subproc`` or ``batched`` (see :func:`vec_env_kind`); multi-agent envs
        use :class:`~sbagents.multiagent.parameter_sharing.ParameterSharingVecEnv` unless batched.
    :param env_kwargs: extra env kwargs on top of the experiment's (e.g. ``render_mode``).
    :param wrapper: an extra outermost wrapper of every env copy (a Gymnasium wrapper, or a PettingZoo parallel
        wrapper for multi-agent envs); it rules out the batched VecEnvs.
    """
    kwargs = {**exp.env_kwargs, **(env_kwargs or {})}
    user_kwargs = {k: v for k, v in kwargs.items() if k != "render_mode"}
    check_env_kwargs(ref, user_kwargs)
    kind = vec_env_kind(vec_env, exp, ref, kwargs)
    if wrapper is not None and kind in ("batched", "envpool"):
        kind = "dummy"
    with _one_line_env_errors(ref, kwargs):
        venv = _make_base_vec(exp, ref, n_envs, seed, monitor_dir, kind, kwargs, wrapper)
    return _vec_wrappers(venv, exp)


@contextlib.contextmanager
def _one_line_env_errors(ref: EnvRef, kwargs: dict[str, Any]) -> Iterator[None]:
    """Turn what building ``ref``'s envs with ``kwargs`` raises into one-line usage errors (a missing
    optional dependency, kwargs the env rejects)."""
    try:
        yield
    except UsageError:
        raise
    except gym.error.DependencyNotInstalled as exc:
        raise missing_dependency_error(ref, exc) from None
    except (TypeError, ValueError, AssertionError) as exc:
        raise env_kwargs_error(ref, kwargs, exc) from None


def _make_base_vec(
    exp: Experiment, ref: EnvRef, n_envs: int, seed: int | None, monitor_dir: str | Path | None, kind: str,
    kwargs: dict[str, Any], wrapper: Callable[[Any], Any] | None,
) -> VecEnv:
    """The VecEnv of ``kind`` (see :func:`vec_env_kind`) before VecEnv wrappers and frame stacking."""
    monitor = str(monitor_dir) if monitor_dir is not None else None
    venv: VecEnv
    if kind == "envpool":
        from sbagents.atari.envpool_vec_env import make_envpool_vec_env

        venv = make_envpool_vec_env(exp, ref, n_envs, seed, kwargs, monitor)
    elif kind == "batched":
        from sbagents.batched import batched_env_id, make_batched_vec_env

        batched_id = batched_env_id(ref.env_id, ref.kind.batched_source(ref))
        assert batched_id is not None, "vec_env_kind chose batched for an env without a batched VecEnv"
        venv = make_batched_vec_env(batched_id, n_envs, seed, kwargs, monitor)
    else:
        venv = _plain_vec(ref.kind, exp, ref, n_envs, seed, _VecArgs(monitor, kind, kwargs, wrapper))
    return venv


class _VecArgs(NamedTuple):
    """How :func:`_plain_vec` builds its VecEnv: the monitor folder, ``dummy`` or ``subproc``, env kwargs, wrapper."""

    monitor: str | None
    vec_kind: str
    kwargs: dict[str, Any]
    wrapper: Callable[[Any], Any] | None


@kind_operation(GameKind)
def _plain_vec(env_kind: EnvKind, exp: Experiment, ref: EnvRef, n_envs: int, seed: int | None,
               how: _VecArgs) -> VecEnv:
    """SB3's ``make_vec_env`` (``dummy`` or ``subproc``) for a Gymnasium env or a game's seat env."""
    monitor, kind, kwargs, wrapper = how
    return make_vec_env(
        env_fn(ref.kind, ref),  # imports the env's modules first, also in SubprocVecEnv workers
        n_envs=n_envs,
        seed=seed,
        monitor_dir=monitor,
        wrapper_class=_chain([*exp.env_wrapper, *([(wrapper, {})] if wrapper is not None else [])]),
        env_kwargs=kwargs,
        vec_env_cls=VEC_ENV_CLASSES[kind],
        monitor_kwargs=exp.monitor_kwargs or None,
    )


@_plain_vec.register
def _team_plain_vec(env_kind: TeamKind, exp: Experiment, ref: EnvRef, n_envs: int, seed: int | None,
                    how: _VecArgs) -> VecEnv:
    """A team: the one VecEnv of a parameter-sharing team (:func:`make_team_vecs` for one model per group)."""
    venvs = _team_vecs(exp, ref, n_envs, seed, *how)
    if len(venvs) != 1:
        raise UsageError(f"{TeamOptions.of(exp).policies} experiments train one model per group: use make_team_vecs")
    return next(iter(venvs.values()))


def _off_policy(algo: str) -> bool:
    """Whether ``algo`` (a name of :data:`sbagents.algos.ALGOS`) learns from a replay buffer."""
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    from sbagents.algos import ALGOS

    entry = ALGOS.get(algo)
    return entry is not None and issubclass(entry.cls, OffPolicyAlgorithm)


def new_vec_normalize(venv: VecEnv, exp: Experiment) -> VecNormalize:
    """A fresh :class:`VecNormalize` of the experiment's ``normalize`` settings around ``venv``.

    :raises UsageError: one line where the settings do not fit the env: observation normalisation of observations
        that are not ``Box`` (or ``Dict`` of ``Box``), or keyword arguments ``VecNormalize`` does not take.
    """
    kwargs = dict(exp.normalize) if isinstance(exp.normalize, dict) else {}
    space = venv.observation_space
    if kwargs.get("norm_obs", True) and not isinstance(space, gym.spaces.Box | gym.spaces.Dict):
        raise UsageError(f"normalize needs Box (or Dict) observations to normalize; {exp.env_id}'s are {space}: drop "
                         "normalize, or set normalize: {norm_obs: false} to scale rewards only")
    if not isinstance(space, gym.spaces.Box | gym.spaces.Dict) and _off_policy(exp.algo):
        # SB3's off-policy _store_transition indexes each terminal observation as next_obs[i, :] under
        # VecNormalize, which fails on the 1-D batch of scalar observations (IndexError at the first episode end)
        raise UsageError(f"normalize on {space} observations works with on-policy algorithms only (SB3's replay "
                         f"buffer needs array observations under VecNormalize); drop normalize for {exp.algo}")
    try:
        return VecNormalize(venv, **kwargs)
    except (TypeError, ValueError) as exc:
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise UsageError(f"normalize {exp.normalize!r:.80} does not fit {exp.env_id}: {reason}") from None


def normalize_for_training(venv: VecEnv, exp: Experiment, stats_path: Path | None = None,
                           trust: bool = False) -> VecEnv:
    """Wrap ``venv`` in :class:`VecNormalize` when the experiment asks for it (or resume saved statistics).

    :param stats_path: saved statistics to resume (``vecnormalize.npz``; a legacy ``.pkl`` beside it only with
        ``trust``, see :mod:`sbagents.state_files`).
    """
    found = existing(stats_path)
    if found is not None:
        loaded = load_vecnormalize(found, venv, trust)
        loaded.training = True
        return loaded
    if not exp.normalize:
        return venv
    return new_vec_normalize(venv, exp)


def normalize_for_eval(venv: VecEnv, exp: Experiment, stats_path: Path | None = None,
                       trust: bool = False) -> VecEnv:
    """Frozen normalisation for evaluation: saved statistics if given, never reward normalisation.

    :param trust: a legacy ``vecnormalize.pkl`` may be unpickled (``--trust-run``).
    """
    found = existing(stats_path)
    if found is not None:
        loaded = load_vecnormalize(found, venv, trust)
    elif exp.normalize:
        loaded = new_vec_normalize(venv, exp)
    else:
        return venv
    loaded.training = False
    loaded.norm_reward = False
    return loaded


def make_eval_vec(
    exp: Experiment,
    ref: EnvRef,
    n_envs: int,
    seed: int | None,
    stats_path: Path | None = None,
    vec_env: str = "auto",
    env_kwargs: dict[str, Any] | None = None,
    wrapper: Callable[[Any], Any] | None = None,
    trust: bool = False,
) -> VecEnv:
    """An evaluation env wrapped exactly as in training, with frozen normalisation (:func:`normalize_for_eval`:
    the run's saved statistics, or fresh ones that SB3's eval callbacks sync from the training env; ``trust``:
    a legacy ``.pkl`` of them may be unpickled).

    Its env kwargs are the experiment's ``env_kwargs``, then its ``eval_env_kwargs`` (settings that shape training
    only, such as a curriculum, reset to the task's), then ``env_kwargs`` of the call."""
    extra = {**exp.eval_env_kwargs, **(env_kwargs or {})}
    venv = make_vec(exp, ref, n_envs, seed, vec_env=vec_env, env_kwargs=extra, wrapper=wrapper)
    return normalize_for_eval(venv, exp, stats_path, trust)
