"""A small URScript reader for the tests: the program's shape, its comments and its calls.

It reads what keymps writes (one `def name():` block of calls with number, joint-list and
string arguments) and checks the rules the controller's script ports impose on a program:
ASCII only, `def` in the first column, every other line indented, `end` last.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

Value = float | str | list[float]


@dataclass
class Call:
    name: str
    args: list[Value]
    kwargs: dict[str, Value]
    line: int

    def joints(self) -> np.ndarray:
        """The first argument, a joint list, as (6,) radians."""
        first = self.args[0]
        assert isinstance(first, list), (self.line, first)
        return np.array(first, dtype=float)

    def number(self, key: str) -> float:
        value = self.kwargs[key]
        assert isinstance(value, float), (self.line, key, value)
        return value


@dataclass
class Program:
    name: str
    comments: list[str] = field(default_factory=list)
    calls: list[Call] = field(default_factory=list)

    def named(self, name: str) -> list[Call]:
        return [call for call in self.calls if call.name == name]

    def comment(self, prefix: str) -> str:
        """The rest of the first comment starting with `prefix`."""
        found = [c.removeprefix(prefix) for c in self.comments if c.startswith(prefix)]
        assert found, f"no comment starts with {prefix!r}"
        return found[0].strip()


CALL = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\((.*)\)")
NUMBER = re.compile(r"-?\d+(\.\d+)?")


def read_urscript(text: str) -> Program:
    """The program in `text`; AssertionError names the line that breaks a rule."""
    text.encode("ascii")  # the controller reads extended ASCII only; keymps writes plain ASCII
    assert text.endswith("\n"), "the last line is not terminated"
    lines = text[:-1].split("\n")
    head = re.fullmatch(r"def ([A-Za-z_][A-Za-z0-9_]*)\(\):", lines[0])
    assert head, f"line 1 is not a function definition: {lines[0]!r}"
    assert lines[-1] == "end", f"the last line is not `end`: {lines[-1]!r}"
    program = Program(head.group(1))
    for number, line in enumerate(lines[1:-1], start=2):
        assert line.startswith(" ") and line.strip(), f"line {number} is not indented: {line!r}"
        statement = line.strip()
        if statement.startswith("#"):
            program.comments.append(statement[1:].strip())
            continue
        call = CALL.fullmatch(statement)
        assert call, f"line {number} is not a call: {statement!r}"
        args: list[Value] = []
        kwargs: dict[str, Value] = {}
        for part in _split(call.group(2), number):
            key, _, value = part.partition("=") if _is_keyword(part) else ("", "", part)
            if key:
                kwargs[key.strip()] = _value(value.strip(), number)
            else:
                assert not kwargs, f"line {number}: a positional argument after a named one"
                args.append(_value(part.strip(), number))
        program.calls.append(Call(call.group(1), args, kwargs, number))
    return program


def _is_keyword(part: str) -> bool:
    return re.match(r"\s*[A-Za-z_][A-Za-z0-9_]*\s*=", part) is not None


def _split(text: str, line: int) -> list[str]:
    """Arguments separated by the commas outside brackets and strings."""
    parts, depth, quoted, start = [], 0, False, 0
    for i, char in enumerate(text):
        if char == '"':
            quoted = not quoted
        elif not quoted and char == "[":
            depth += 1
        elif not quoted and char == "]":
            depth -= 1
            assert depth >= 0, f"line {line}: unbalanced ]"
        elif not quoted and depth == 0 and char == ",":
            parts.append(text[start:i])
            start = i + 1
    assert depth == 0 and not quoted, f"line {line}: unbalanced brackets or quotes"
    tail = text[start:]
    return parts + [tail] if tail.strip() or parts else parts


def _value(text: str, line: int) -> Value:
    if text.startswith('"'):
        assert text.endswith('"') and '"' not in text[1:-1], f"line {line}: bad string {text}"
        return text[1:-1]
    if text.startswith("["):
        assert text.endswith("]"), f"line {line}: bad list {text}"
        items = [item.strip() for item in text[1:-1].split(",")]
        assert all(NUMBER.fullmatch(item) for item in items), f"line {line}: bad list {text}"
        return [float(item) for item in items]
    assert NUMBER.fullmatch(text), f"line {line}: not a number: {text!r}"
    return float(text)
