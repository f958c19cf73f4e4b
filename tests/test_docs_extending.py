"""docs/extending.md names the Extension API as it is: the hook table lists every hook of ``TrainingExtension`` and
nothing else, and every ``ctx.<name>`` / ``plan.<name>`` the page mentions is an attribute of ``TrainingContext`` /
``ExtensionPlan`` (the experiment is ``ctx.exp``, not ``ctx``)."""

from __future__ import annotations

import dataclasses
import re

from cli_helpers import REPO

from sbagents.extensions import ExtensionPlan, TrainingContext, TrainingExtension

PAGE = REPO / "docs" / "extending.md"
#: Attributes of TrainingExtension that are declarations, not hooks.
DECLARATIONS = {"name", "title", "flags", "spec_type", "group_runs", "backends"}


def hook_table() -> set[str]:
    text = PAGE.read_text()
    table = text[text.index("| hook | when | what it does |"):]
    table = table[:table.index("\n\n")]
    return {name for row in table.splitlines()[2:] for name in re.findall(r"`(\w+)[(`]", row.split("|")[1])}


def test_the_hook_table_is_the_extension_api() -> None:
    api = {name for name in vars(TrainingExtension) if not name.startswith("_")} - DECLARATIONS
    assert hook_table() == api


def test_ctx_and_plan_names_exist() -> None:
    text = PAGE.read_text()
    context = set(TrainingContext.__annotations__) | {n for n in vars(TrainingContext) if not n.startswith("_")}
    plan = {f.name for f in dataclasses.fields(ExtensionPlan)}
    assert {"exp", "model", "state", "make_eval_env"} <= context
    ctx_names = set(re.findall(r"\bctx\.(\w+)", text))
    plan_names = set(re.findall(r"\bplan\.(\w+)", text))
    assert ctx_names and ctx_names <= context, ctx_names - context
    assert plan_names and plan_names <= plan, plan_names - plan
    assert "the experiment is `ctx.exp`" in text
