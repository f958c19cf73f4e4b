"""Each training extension declares what it supports (algorithms, env kinds) and what it needs of other extensions
(``requires``); the capability table is built from the declarations, and :func:`sbagents.extensions.prepare_extensions`
applies the requirements and refuses what a declaration does not take, each in one line."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import pytest

from sbagents.algos import ALGOS, algos_with, capability_legend, capability_rows, declared_capabilities
from sbagents.callbacks.extension import TrustOptions
from sbagents.constrained.options import ConstraintSpec
from sbagents.errors import UsageError
from sbagents.extensions import (
    TAKEN,
    Capability,
    ExtensionPlan,
    TrainingExtension,
    activate,
    prepare_extensions,
    register_extension,
    unregister_extension,
)
from sbagents.robust.options import parse_robust

#: The algorithm sets of the columns before the declarations moved to the features (the old ``FEATURES`` table).
BEFORE = {
    "dp": ("a2c", "ppo", "ddpg", "td3", "sac"),
    "robust:sa": ("ddpg", "td3"),
    "robust:adv": ("ddpg", "td3", "sac"),
    "robust:sa+adv": ("ddpg", "td3"),
    "constrained": ("ppo", "sac"),
    "pretrain": ("a2c", "ppo", "trpo", "ppo_mask", "sac", "tqc", "td3", "ddpg", "dqn", "qrdqn"),  # ppo_mask: games
    "demos": ("sac", "tqc", "td3", "ddpg", "dqn", "qrdqn"),  # added with --demos
    "federated": ("a2c", "ppo", "ddpg", "td3", "sac"),
    "centralized_critic": ("a2c", "ppo"),
    "rllib": ("ppo", "dqn", "sac"),  # RLlib trains Gymnasium envs too (appo and impala have no SB3 row)
}


@dataclass(frozen=True)
class Boost:
    """The spec of the test's extension."""

    factor: float = 2.0


class BoostExtension(TrainingExtension[Boost]):
    """An extension of a user: ``--boost``, for two algorithms and single-agent envs."""

    name = "boost"
    title = "boost (a test extension)"
    flags = "--boost"
    spec_type = Boost
    algos = ("ppo", "a2c")
    kinds = ("single-agent",)


@dataclass(frozen=True)
class Cap:
    """The spec of the test's extensions that need settings of the trust extension."""

    on: bool = True


class CapExtension(TrainingExtension[Cap]):
    """Needs the trust extension's safety counting with at most 3 violations (a conflict with a run's 5)."""

    name = "cap"
    title = "needs a violation cap"
    flags = "--cap"
    spec_type = Cap

    def requires(self, spec: Cap) -> Mapping[str, Mapping[str, Any]]:
        return {"trust": {"safety": True, "max_violations": 3}}


@pytest.fixture
def boost() -> Iterator[BoostExtension]:
    extension = BoostExtension()
    register_extension(extension)
    yield extension
    unregister_extension(extension.name)


@pytest.fixture
def cap() -> Iterator[CapExtension]:
    extension = CapExtension()
    register_extension(extension)
    yield extension
    unregister_extension(extension.name)


def plan(algo: str, specs: list[Any], kind: str = "single-agent", env_id: str = "sbagents/SmartHome-v0"
         ) -> ExtensionPlan:
    """The plan of a run of ``algo`` on an env of ``kind`` with these specs, paired as the pipeline pairs them
    (:func:`~sbagents.extensions.activate`; the replay buffer's ``configure`` adds its spec)."""
    exp = SimpleNamespace(algo=algo, env_id=env_id, hyperparams={})
    ref = SimpleNamespace(env_id=env_id, kind=SimpleNamespace(name=kind))
    return ExtensionPlan(algo, exp, ref, resuming=False,
                         specs={active.name: active.spec for active in activate(specs)})


def test_the_columns_keep_the_algorithms_of_the_old_table() -> None:
    columns = {column.name: column.algos for column in declared_capabilities()}
    assert list(columns) == list(BEFORE)
    for name, algos in BEFORE.items():
        assert set(columns[name] or ()) == set(algos), name
        assert algos_with(name) == tuple(a for a in ALGOS if a in algos), name  # in table order


def test_a_registered_extension_is_a_column_of_the_table(boost: BoostExtension) -> None:
    rows = {row["algo"]: row for row in capability_rows()}
    assert [algo for algo, row in rows.items() if row["boost"] == "yes"] == ["a2c", "ppo"]
    assert list(rows["ppo"])[-1] == "rllib"  # the extensions' columns come before the other sources'
    assert "boost: boost (a test extension); single-agent envs" in capability_legend()
    assert algos_with("boost") == ("a2c", "ppo")


def test_an_undeclared_algorithm_or_kind_is_refused_in_one_line(boost: BoostExtension) -> None:
    with pytest.raises(UsageError) as err:
        prepare_extensions(plan("sac", [Boost()]))
    assert str(err.value) == "--boost trains ppo, a2c, not sac"
    with pytest.raises(UsageError) as err:
        prepare_extensions(plan("ppo", [Boost()], kind="team", env_id="mpe2.simple_spread_v3"))
    assert str(err.value) == "--boost trains single-agent envs, not team envs (mpe2.simple_spread_v3)"
    assert [a.name for a in prepare_extensions(plan("ppo", [Boost()]))] == ["replay_buffer", "boost"]


def test_the_built_in_declarations_refuse_as_before() -> None:
    """Robust's refusal comes from its method's column; constrained's from its own."""
    with pytest.raises(UsageError, match="^--robust sa trains ddpg, td3, not sac$"):
        prepare_extensions(plan("sac", [parse_robust("sa:0.2")]))
    with pytest.raises(UsageError, match="^--robust adv trains single-agent envs, not team envs"):
        prepare_extensions(plan("td3", [parse_robust("adv:0.2")], kind="team"))
    with pytest.raises(UsageError, match="^--constraint trains ppo, sac, not a2c$"):
        prepare_extensions(plan("a2c", [ConstraintSpec("pid", 0.1)]))
    assert Capability("x", "", ("ppo",), label="--x").subject == "--x"


def test_constrained_training_turns_safety_counting_on_without_the_stop() -> None:
    """The constraint's requirement, applied by prepare_extensions: the trust spec counts violations and has no cost
    limit (the multiplier holds it), whether the run gave a trust spec or not; the constraint keeps the limit."""
    given = TrustOptions(cost_limit=0.5, transparency_log="")  # what --constraint pid --cost-limit 0.5 gives
    for specs in ([ConstraintSpec("pid", 0.5), given], [ConstraintSpec("pid", 0.5)]):
        run = plan("ppo", specs)
        actives = {a.name: a.spec for a in prepare_extensions(run)}
        assert actives["trust"].safety and actives["trust"].cost_limit is None
        assert actives["trust"].transparency_log == ("" if len(specs) == 2 else None)  # the rest as given
        assert actives["constraint"].cost_limit == 0.5
    assert run.given["constraint"] == ConstraintSpec("pid", 0.5) and "trust" not in run.given  # as the run gave them
    # a run from Python may give the limit on the trust spec only: the constraint takes it over
    taken = plan("ppo", [ConstraintSpec("pid"), TrustOptions(cost_limit=0.25)])
    actives = {a.name: a.spec for a in prepare_extensions(taken)}
    assert actives["constraint"].cost_limit == 0.25 and actives["trust"].cost_limit is None


def test_the_constraint_declares_its_requirement_instead_of_editing_the_trust_spec() -> None:
    from sbagents.constrained.extension import ConstraintExtension

    assert ConstraintExtension().requires(ConstraintSpec("pid", 0.5)) == {
        "trust": {"safety": True, "cost_limit": TAKEN}}
    assert not hasattr(ExtensionPlan, "replace")


def test_a_conflicting_requirement_is_refused_in_one_line(cap: CapExtension) -> None:
    with pytest.raises(UsageError) as err:
        prepare_extensions(plan("ppo", [Cap(), TrustOptions(max_violations=5)]))
    assert str(err.value) == "--cap needs trust max_violations=3, but the run asks max_violations=5 (drop one of them)"
    actives = {a.name: a.spec for a in prepare_extensions(plan("ppo", [Cap(), TrustOptions(max_violations=3)]))}
    assert actives["trust"] == TrustOptions(safety=True, max_violations=3)


@dataclass(frozen=True)
class NoCap:
    """The spec of an extension that needs the opposite of :class:`CapExtension`."""


class NoCapExtension(TrainingExtension[NoCap]):
    """Needs the trust extension to allow 10 violations."""

    name = "no_cap"
    title = "needs room"
    flags = "--no-cap"
    spec_type = NoCap

    def requires(self, spec: NoCap) -> Mapping[str, Mapping[str, Any]]:
        return {"trust": {"max_violations": 10}}


def test_two_extensions_that_require_different_values_are_refused_in_one_line(cap: CapExtension) -> None:
    register_extension(NoCapExtension())
    try:
        with pytest.raises(UsageError) as err:
            prepare_extensions(plan("ppo", [Cap(), NoCap()]))
    finally:
        unregister_extension("no_cap")
    assert str(err.value) == ("--cap and --no-cap need different trust settings: max_violations=3 and "
                              "max_violations=10 (drop one of them)")


def test_a_requirement_of_an_unregistered_extension_is_refused(monkeypatch: pytest.MonkeyPatch,
                                                               cap: CapExtension) -> None:
    monkeypatch.setattr(CapExtension, "requires", lambda self, spec: {"nowhere": {"x": 1}})
    with pytest.raises(UsageError, match="^--cap needs the nowhere extension, which is not registered$"):
        prepare_extensions(plan("ppo", [Cap()]))


def test_a_taken_setting_gets_its_default_and_the_specs_stay_dataclasses() -> None:
    run = plan("ppo", [ConstraintSpec("lagrangian", 1.0), TrustOptions(cost_limit=1.0, max_violations=7)])
    trust = {a.name: a.spec for a in prepare_extensions(run)}["trust"]
    assert dataclasses.replace(trust, safety=False, max_violations=None) == TrustOptions()
    assert trust.max_violations == 7  # not required: as the run gave it


def test_two_extensions_that_each_pick_the_model_class_are_refused_in_one_line() -> None:
    """Robust and constrained training each train a class of their own (their contributions' model_class): the run is
    refused before anything is written, whichever of the two the user named first."""
    for specs in ([parse_robust("adv:0.2"), ConstraintSpec("lagrangian", 0.1)],
                  [ConstraintSpec("lagrangian", 0.1), parse_robust("adv:0.2")]):
        with pytest.raises(UsageError) as err:
            prepare_extensions(plan("sac", specs))
        assert str(err.value) == ("--robust and --constraint each train a model class of their own: they cannot be "
                                  "combined yet (one or the other)")
