"""Property-based tests of the ``-params`` / ``--env-kwargs`` parser
(:func:`sbagents.core.zoo_config.parse_overrides`).

Any text either parses to plain data (None, bool, str, float, int64, lists and mappings of them) or raises the
one-line :class:`~sbagents.errors.UsageError`; it never evaluates or imports anything, and never raises anything
else. Seeded (``derandomize``) and bounded, so every run checks the same examples.
"""

from __future__ import annotations

import builtins
import sys
from typing import Any

import pytest

from sbagents.core.zoo_config import INT64_RANGE, MAX_OVERRIDE_CHARS, parse_overrides
from sbagents.errors import UsageError

hypothesis = pytest.importorskip("hypothesis", reason="the test extra's hypothesis runs these fuzz tests")
st = hypothesis.strategies

FUZZ = hypothesis.settings(derandomize=True, max_examples=400, deadline=None, database=None,
                           suppress_health_check=list(hypothesis.HealthCheck))

#: YAML's syntax characters, tags and words that mean something to a YAML reader, mixed with plain text.
_ATOMS = ["[", "]", "{", "}", ":", ", ", "&a ", "*a", "!!", "!!python/object/apply:os.system ", "!!binary ",
          "!!set ", "!!timestamp ", "!!int ", "!!float ", "!!str ", "? ", "- ", "|", ">", "'", '"', "#", "%",
          "@", "`", "\n", "\t", " ", "0x", "0b", "0o", "1e400", "-.inf", ".nan", "null", "~", "true", "no",
          "2020-01-01", "12:30:45", "9" * 30, "_", "__import__('os')", "eval(", "\\", "\x00", "\u2028", "é"]
_yamlish = st.lists(st.one_of(st.sampled_from(_ATOMS), st.text(max_size=8)), max_size=24).map("".join)


def _is_plain(value: Any) -> bool:
    if value is None or isinstance(value, bool | str | float):
        return True
    if isinstance(value, int):
        return INT64_RANGE[0] <= value <= INT64_RANGE[1]
    if isinstance(value, list):
        return all(_is_plain(v) for v in value)
    if isinstance(value, dict):
        return all(_is_plain(k) and not isinstance(k, list | dict) and _is_plain(v) for k, v in value.items())
    return False


def _check(pairs: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``pairs`` parse to plain data or raise one UsageError line, with no eval/exec and no new module."""

    def forbidden(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the parser evaluated code")

    before = set(sys.modules)
    with monkeypatch.context() as patch:
        patch.setattr(builtins, "eval", forbidden)
        patch.setattr(builtins, "exec", forbidden)
        try:
            parsed = parse_overrides(pairs, "--env-kwargs")
        except UsageError as exc:
            message = str(exc)
            assert message and "\n" not in message and "\r" not in message, message
            assert message.startswith("--env-kwargs"), message
            assert len(message) < 400, message
        else:
            assert isinstance(parsed, dict) and all(isinstance(k, str) for k in parsed)
            assert all(_is_plain(v) for v in parsed.values()), parsed
    assert set(sys.modules) - before == set()


@FUZZ
@hypothesis.given(value=_yamlish)
def test_yaml_like_values_parse_to_plain_data_or_one_line(value: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _check([f"size:{value}"], monkeypatch)


@FUZZ
@hypothesis.given(pairs=st.lists(st.text(max_size=40), max_size=4))
def test_any_text_parses_to_plain_data_or_one_line(pairs: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    _check(pairs, monkeypatch)


@FUZZ
@hypothesis.given(digits=st.integers(min_value=1, max_value=25_000), sign=st.sampled_from(["", "-", "+"]))
def test_long_integers_are_one_line(digits: int, sign: str, monkeypatch: pytest.MonkeyPatch) -> None:
    _check([f"max_steps:{sign}{'7' * digits}"], monkeypatch)


@FUZZ
@hypothesis.given(depth=st.integers(min_value=1, max_value=5_000), kind=st.sampled_from(["[]", "{}"]))
def test_deep_nesting_is_one_line(depth: int, kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    opener, closer = kind
    body = "a: 1" if kind == "{}" else "1"
    _check([f"x:{opener * depth}{body}{closer * depth}"], monkeypatch)


@pytest.mark.parametrize(("text", "expected"), [
    ("max_steps:" + "1" * 100_000, f"value of 100,000 characters is too long (at most {MAX_OVERRIDE_CHARS:,})"),
    ("max_steps:" + "1" * 26, "integer '11111111111111111111111111' is outside the 64-bit range"),
    ("size:&a [*a]", "aliases (*name) are not accepted"),
    ("size:" + "[" * 100, "nested deeper than 32 levels"),
    ("start:2020-01-01", "the value reads as a YAML date; quote it"),
    ("start:!!binary aGk=", "reads as a YAML !!binary"),
    ("start:!!python/object/apply:os.system [true]", "is not a YAML scalar, list or mapping"),
    ("a b:1", "key 'a b' is not a keyword name"),
])
def test_absurd_values_are_refused_in_one_line(text: str, expected: str) -> None:
    with pytest.raises(UsageError, match=None) as info:
        parse_overrides([text], "--env-kwargs")
    assert expected in str(info.value) and "\n" not in str(info.value)


def test_int64_bounds_are_accepted() -> None:
    low, high = INT64_RANGE
    assert parse_overrides([f"a:{high}", f"b:{low}", "c:0x10", "d:1_000"]) == {"a": high, "b": low, "c": 16, "d": 1000}
