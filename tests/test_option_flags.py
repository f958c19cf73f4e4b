"""Each CLI flag is declared once, with its field: for ``train``, ``evaluate`` and ``tune``, every parser flag set to a
non-default value changes exactly one field of the option groups the CLI builds (or belongs to a training extension,
or is one of the few flags that steer the CLI itself), every field of those groups is set by exactly one flag, and
the field's ``:param:`` line names that flag. The mapping is derived by parsing, not listed by hand: a flag that
stops reaching its field, or a field that no flag sets, fails here."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from sbagents import evaluate as evaluate_cli
from sbagents import train as train_cli
from sbagents import tune as tune_cli
from sbagents.api import ExecOptions, RllibOptions, Sb3Options, TrainSpec, train
from sbagents.errors import UsageError
from sbagents.extensions import registered_extensions

#: Flags that steer the CLI itself rather than filling an option group (dest -> why).
CLI_ONLY = {
    "help": "prints the usage",
    "list": "train --list prints the envs and algorithms, then exits",
    "json": "evaluate --json prints the summary as JSON",
    "policy": "evaluate --policy plays a baseline instead of a run (evaluate_baseline, no run to pick)",
}
#: Fields no flag sets (group type -> field -> why).
NO_FLAG = {"OutputOptions": {"command": "the command line itself, recorded in command.txt"}}

Builder = Callable[[argparse.Namespace], Any]


def extension_dests() -> set[str]:
    """The destinations of every registered training extension's flags (their specs are the extensions' own)."""
    parser = argparse.ArgumentParser(add_help=False)
    for extension in registered_extensions():
        extension.add_arguments(parser.add_argument_group(extension.title))
    return {action.dest for action in parser._actions}


def flag_actions(parser: argparse.ArgumentParser) -> Iterator[argparse.Action]:
    """The parser's optional arguments."""
    return (action for action in parser._actions if action.option_strings)


def non_default_argv(action: argparse.Action) -> list[str]:
    """The flag of ``action`` with a value that differs from its default."""
    flag = max(action.option_strings, key=len)
    if action.nargs == 0:  # store_true / store_false
        return [flag]
    if action.choices:
        value: Any = next(c for c in action.choices if c != action.default)
    elif action.type in (int, float):
        value = (action.default or 0) + 7
    else:
        value = "key:1" if action.metavar == "KEY:VALUE" else "other"
    return [flag, str(value)]


def groups_of(built: Any) -> dict[str, Any]:
    """The option groups (dataclasses, by type name) and plain arguments (by name) a CLI built."""
    items = built.items() if isinstance(built, dict) else ((type(g).__name__, g) for g in built)
    return {type(v).__name__ if dataclasses.is_dataclass(v) else k: v for k, v in items if k != "features"}


def changed(before: dict[str, Any], after: dict[str, Any]) -> set[tuple[str, str]]:
    """(group, field) pairs, or (argument, "") for plain arguments, that differ between two builds."""
    out = set()
    for name, old in before.items():
        new = after[name]
        if dataclasses.is_dataclass(old):
            out |= {(name, f.name) for f in dataclasses.fields(old) if getattr(old, f.name) != getattr(new, f.name)}
        elif old != new:
            out.add((name, ""))
    return out


def param_docs(cls: type) -> dict[str, str]:
    """The ``:param name:`` texts of a class docstring."""
    doc = inspect.getdoc(cls) or ""
    return dict(re.findall(r":param (\w+):(.*?)(?=\n:param |\n\n|\Z)", doc, re.S))


def named_flags(text: str) -> set[str]:
    """The flags named in the code spans of ``text`` (``-P/--progress`` names both)."""
    return {token for span in re.findall(r"``(.+?)``", text, re.S) for token in re.split(r"[\s/]+", span)}


CLIS: dict[str, tuple[Callable[[], argparse.ArgumentParser], Builder, list[str], bool]] = {
    # name: (parser, builder, required argv, whether every field of every group must have a flag)
    "train": (train_cli.build_parser, lambda a: train_cli.options_from_args(a, ""), [], True),
    "evaluate": (evaluate_cli.build_parser, evaluate_cli.options_from_args, ["--algo", "ppo", "--env", "E"], True),
    "tune": (tune_cli.build_parser, tune_cli.options_from_args, ["--algo", "ppo", "--env", "E"], False),
}


def flag_fields(cli: str) -> tuple[dict[str, set[tuple[str, str]]], dict[str, Any], set[str]]:
    """Per flag of ``cli``, the fields it changes; the baseline groups; the extension-owned flags."""
    make_parser, build, required, _ = CLIS[cli]
    parser = make_parser()
    baseline = groups_of(build(parser.parse_args(required)))
    owned = extension_dests() if cli == "train" else set()
    reached: dict[str, set[tuple[str, str]]] = {}
    extension_flags = set()
    for action in flag_actions(parser):
        flag = "/".join(action.option_strings)
        if action.dest in CLI_ONLY:
            continue
        if action.dest in owned:
            extension_flags.add(flag)
            continue
        reached[flag] = changed(baseline, groups_of(build(parser.parse_args(required + non_default_argv(action)))))
    return reached, baseline, extension_flags


@pytest.mark.parametrize("cli", list(CLIS))
def test_every_flag_sets_one_field_and_every_field_has_one_flag(cli: str) -> None:
    reached, baseline, extension_flags = flag_fields(cli)
    assert {flag: fields for flag, fields in reached.items() if len(fields) != 1} == {}
    setters: dict[tuple[str, str], set[str]] = {}
    for flag, fields in reached.items():
        setters.setdefault(next(iter(fields)), set()).add(flag)
    # --deterministic / --stochastic are the two values of one field; no other field has two flags
    pairs = {("EvaluateOptions", "deterministic"): {"--deterministic", "--stochastic"}} if cli == "evaluate" else {}
    assert {f: flags for f, flags in setters.items() if len(flags) > 1} == pairs
    if CLIS[cli][3]:
        every = {(name, f.name) for name, group in baseline.items() if dataclasses.is_dataclass(group)
                 for f in dataclasses.fields(group) if f.name not in NO_FLAG.get(name, {})}
        assert every - setters.keys() == set(), "fields no flag sets"
    if cli == "train":  # the extensions' flags: --robust, --dp-*, the trust flags, --constraint, ...
        assert {"--robust", "--dp-epsilon", "--save-replay-buffer"} <= extension_flags


@pytest.mark.parametrize("cli", list(CLIS))
def test_each_field_docstring_names_its_flag(cli: str) -> None:
    reached, baseline, _ = flag_fields(cli)
    missing = {}
    for flag, fields in reached.items():
        (group, name), = fields
        if not name:  # a plain argument of the library call (tune's log_folder, seed, verbose)
            continue
        text = param_docs(type(baseline[group])).get(name, "")
        if not named_flags(text) & set(flag.split("/")):
            missing[f"{group}.{name}"] = flag
    assert missing == {}, "these fields' :param: lines do not name their flag"


def test_extension_flags_are_not_option_fields() -> None:
    """A training feature's flag lives in its extension only: no option group field has its name."""
    fields = {f.name for group in groups_of(train_cli.options_from_args(train_cli.build_parser().parse_args([]), ""))
              .values() if dataclasses.is_dataclass(group) for f in dataclasses.fields(group)}
    assert extension_dests() & fields == set()


@pytest.mark.parametrize(("backend", "options", "message"), [
    ("sb3", {"rllib": RllibOptions(address="auto")}, "--address and --num-env-runners need --backend rllib"),
    ("rllib", {"sb3": Sb3Options(log_interval=5)}, "--log-interval not supported with --backend rllib"),
])
def test_each_backend_refuses_the_other_backends_options(backend: str, options: dict[str, Any], message: str) -> None:
    """From Python as from the CLI: the options of one library given to a run of the other are refused in one line,
    before anything is written."""
    with pytest.raises(UsageError, match=message):
        train(TrainSpec("ppo", "treasure_hunt_v0"), execution=ExecOptions(backend=backend), **options)
