"""Fuzzed task files: every input ends in a Task or in clean, located, one-line errors."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from keymps.config.task import parse_task
from keymps.errors import TaskFileError

REPO = Path(__file__).resolve().parents[2]
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


# Whole task files on disk through `keymps validate` (load, plugins, primitives, robot): every
# field of a task that sets them all, and YAML-level damage (tags, anchors, non-text keys ...).
# Found by this fuzzer before the fix: bare `!!int`, `!!bool yesx` and bad `!!timestamp`
# tracebacks, `true:` keys reported as `[1]` at their value, `planner.backend` unlocated.

FULL = {
    **BASE,
    "scene": {
        **BASE["scene"],
        "source": "file",
        "source_options": {},
        "camera": {"board_corners_px": [[0, 360], [600, 360], [600, 0], [0, 0]]},
        "max_image_pixels": 64_000_000,
    },
    "detector": {"name": "threshold", "threshold": 30, "blur": 5, "padding": 10},
    "planner": {
        **BASE["planner"],
        "backend": "offline",
        "temperature": 0.0,
        "timeout_s": 60,
        "max_pairs": 64,
        "attempts": 2,
        "combined": True,
        "cache": False,
    },
    "motion": {**BASE["motion"], "max_path_length": 50, "max_duration_s": 1800},
    "robot": {
        "model": "ur3",
        "base": [0.15, -0.2, 0.0, 90.0],
        "tool": {"name": "piping_bag", "tcp": [0, 0, 0.1]},
        "rate_hz": 125,
        "max_joint_acceleration": 3.0,
        "max_joint_jerk": 100,
        "max_tool_acceleration": 0.5,
        "max_tool_jerk": 20,
    },
    "executor": {"name": "file"},
}
FULL_PATHS = [p for p in _leaf_paths(FULL) if p]
EXTREMES = st.sampled_from(
    [0, -0.0, 1e-9, -1, 1e7, -1e7, 1e300, -1e300, 2**31, 2**63, 10**30, 360.5, 65536, 1e5]
)
YAML_DAMAGE = [
    *("true:", "1:", "null:", "~:", "? [a, b]\n:", "<<: {a: 1}", "<<: *a", "&a", "*a"),
    *("!!int", "!!float", "!!bool yesx", "!!timestamp 2001-1", "!!binary x", "!!set {a}"),
    *("!!python/object:os.system", "!!omap [a: 1]", "- ", "{", "]", "\t", "---\n", "...\n"),
    *("'", '"', ":", ",", "#", "|", ">", "%YAML 1.1\n", "1e999", "0x1F", "0o17", "yes", "\x00"),
    *("\ufeff", "\u0085", "é", "2001-12-14", "12:30:00", "-.inf", ".NaN"),
]


def _validate_outcome(path: Path, fuzz_counter: object, suite: str) -> None:
    from keymps.pipeline.validation import validate_task_file

    problems = validate_task_file(path)  # any exception here is a traceback for the user
    for line in problems:
        assert re.match(r"^\S+:\d+:\d+: \S", line), f"no file:line:col: {line!r}"
        assert "\n" not in line and "Traceback" not in line
    fuzz_counter.add(suite, path.read_bytes(), "refused" if problems else "valid")  # type: ignore[attr-defined]


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(edits=st.lists(st.tuples(st.sampled_from(FULL_PATHS), EXTREMES | values), max_size=3))
def test_every_field_at_extremes_gives_located_errors(
    edits: list, tmp_path_factory: object, fuzz_counter: object
) -> None:
    data = yaml.safe_load(yaml.safe_dump(FULL))
    data["scene"]["image"] = str(REPO / "tasks/scenes/round_cake.png")
    data["planner"]["prompt"] = str(REPO / "prompts/icing.md")
    for path, value in edits:
        target = data
        try:
            for key in path[:-1]:
                target = target[key]
            target[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit replaced this field's parent
    folder = tmp_path_factory.mktemp("fields")  # type: ignore[attr-defined]
    (folder / "fuzz.yaml").write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")
    _validate_outcome(folder / "fuzz.yaml", fuzz_counter, "task files/every field, validate")


@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), database=None)
@given(
    damage=st.lists(
        st.tuples(st.integers(0, 10**6), st.integers(0, 10**6), st.sampled_from(YAML_DAMAGE)),
        min_size=1,
        max_size=3,
    ),
    mode=st.sampled_from(["insert", "replace", "key"]),
)
def test_yaml_damage_gives_located_errors(
    damage: list, mode: str, tmp_path_factory: object, fuzz_counter: object
) -> None:
    lines = yaml.safe_dump(FULL).splitlines(keepends=True)
    for line_at, column_at, token in damage:
        index = line_at % len(lines)
        line = lines[index]
        column = column_at % (len(line) + 1)
        if mode == "insert":
            line = line[:column] + token + line[column:]
        elif mode == "replace":
            line = line[:column] + token + line[column + 1 + column_at % 6 :]
        else:  # the token as a mapping key
            key = token.rstrip(":") + ":"
            line = re.sub(r"^(\s*)[^:\s]+:", lambda m, key=key: m.group(1) + key, line)
        lines[index] = line
    folder = tmp_path_factory.mktemp("damage")  # type: ignore[attr-defined]
    path = folder / "fuzz.yaml"
    path.write_text("".join(lines), encoding="utf-8")
    _validate_outcome(path, fuzz_counter, "task files/YAML damage, validate")


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ("scene:\n  true: 3\n", "6:3", "key 'true' is a boolean in YAML, not a name"),
        ("scene:\n  true: 3\n  1: 2\n", "6:3", "key 'true' is a boolean"),
        ("True: 5\n", "4:1", "key 'True' is a boolean"),
        ("scene:\n  null: 3\n", "6:3", "key 'null' is null in YAML"),
        ("scene:\n  3: x\n", "6:3", "key '3' is int in YAML"),
        ("robot: {max_tool_jerk: !!int }\n", "4:24", "'' is not a valid int"),
        ("robot: {model: !!timestamp 2001-1}\n", "4:16", "'2001-1' is not a valid timestamp"),
        ("planner: {backend: nope}\n", "4:20", "planner.backend: unknown planner backend 'nope'"),
    ],
    ids=[
        "true key",
        "true then 1",
        "True at top",
        "null key",
        "int key",
        "!!int",
        "!!timestamp",
        "backend",
    ],
)
def test_keys_tags_and_backends_are_located(
    text: str, where: str, message: str, tmp_path: Path
) -> None:
    from keymps.pipeline.validation import validate_task_file

    head = "name: t\ninstruction: cut it\nprimitives: [line]\n"  # then line 4
    if text.startswith("scene:\n"):  # the scene's own keys from line 6
        body = "scene:\n  source: synthetic\n" + text.removeprefix("scene:\n")
    else:
        body = text + "scene: {source: synthetic}\n"
    path = tmp_path / "task.yaml"
    path.write_text(head + body)
    problems = validate_task_file(path)
    assert problems and all(p.count(":") >= 3 for p in problems), problems
    assert any(f"task.yaml:{where}: " in p and message in p for p in problems), problems
