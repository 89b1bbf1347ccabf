"""Fuzzed task files: every input ends in a Task or in clean, located, one-line errors."""

from __future__ import annotations

import re
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from keymps.config.task import parse_task
from keymps.errors import TaskFileError

REPO = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((REPO / "tasks/cake_icing.yaml").read_text())
LINE = re.compile(r"^fuzz\.yaml(:\d+:\d+)?: \S.*$")

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
    st.sampled_from(["../../../etc/passwd", "/dev/zero", "é🍰\u202e", "\x00", "1e999", ".nan"]),
)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


def _leaf_paths(data: object, prefix: tuple = ()) -> list[tuple]:
    if isinstance(data, dict):
        return [p for k, v in data.items() for p in _leaf_paths(v, (*prefix, k))] + [prefix]
    if isinstance(data, list):
        return [p for i, v in enumerate(data) for p in _leaf_paths(v, (*prefix, i))] + [prefix]
    return [prefix]


PATHS = [p for p in _leaf_paths(BASE) if p]


def _outcome(text: str) -> None:
    try:
        task = parse_task(text, source="fuzz.yaml", path=REPO / "tasks/fuzz.yaml")
    except TaskFileError as error:
        assert error.problems, "an error must say what is wrong"
        for line in error.problems:
            assert LINE.match(line), line
            assert "\n" not in line and "Traceback" not in line
    else:
        assert task.instruction.strip()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=st.text(max_size=300))
def test_random_text_is_a_task_or_clean_errors(text: str) -> None:
    _outcome(text)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(path=st.sampled_from(PATHS), value=values)
def test_one_broken_field_gives_clean_located_errors(path: tuple, value: object) -> None:
    data = yaml.safe_load(yaml.safe_dump(BASE))
    target = data
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    _outcome(yaml.safe_dump(data, allow_unicode=True))


def test_alias_bomb_is_refused_quickly() -> None:
    bomb = "a: &a [x, x, x, x, x, x, x, x, x, x]\n"
    for level in range(1, 9):
        previous = chr(ord("a") + level - 1)
        name = chr(ord("a") + level)
        bomb += f"{name}: &{name} [{', '.join(['*' + previous] * 10)}]\n"
    try:
        parse_task(bomb, source="fuzz.yaml")
    except TaskFileError as error:
        assert "alias bomb" in str(error)
    else:
        raise AssertionError("an alias bomb must be refused")


def test_deep_nesting_is_refused() -> None:
    deep = "name: " + "[" * 5000 + "]" * 5000
    try:
        parse_task(deep, source="fuzz.yaml")
    except TaskFileError as error:
        assert str(error).startswith("fuzz.yaml:")
    else:
        raise AssertionError("deep nesting must be refused")
