"""YAML loading that remembers where every key and value came from (line and column)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import yaml

Location = tuple[int, int]
"""(line, column), both 1-based."""


@dataclass(frozen=True)
class PositionedYaml:
    """Parsed YAML and where each value and key is written in the text."""

    data: Any
    positions: dict[tuple[Any, ...], Location]
    """Maps a path of keys/indices to where its value starts in the file."""
    key_positions: dict[tuple[Any, ...], Location]
    """Maps a path ending in a mapping key to where that key is written."""

    def locate(self, path: tuple[Any, ...], at_key: bool = False) -> Location:
        """Position of the deepest existing prefix of `path` (a missing key points at its parent)."""
        if at_key and tuple(path) in self.key_positions:
            return self.key_positions[tuple(path)]
        for end in range(len(path), -1, -1):
            found = self.positions.get(tuple(path[:end]))
            if found is not None:
                return found
        return (1, 1)


class YamlSyntaxError(ValueError):
    def __init__(self, message: str, location: Location):
        self.location = location
        super().__init__(message)


MAX_NODES = 200_000
"""A task or suite file is small; more nodes than this means an alias bomb or a wrong file."""
MAX_DEPTH = 100


def _mark(node: yaml.Node) -> Location:
    return (node.start_mark.line + 1, node.start_mark.column + 1)


class _Walker:
    """Builds plain Python data from a composed YAML tree, recording positions on the way."""

    def __init__(self) -> None:
        self.constructor = yaml.constructor.SafeConstructor()
        self.positions: dict[tuple[Any, ...], Location] = {}
        self.key_positions: dict[tuple[Any, ...], Location] = {}
        self.nodes = 0

    def scalar(self, node: yaml.Node) -> Any:
        try:
            return self.constructor.construct_object(node, deep=True)
        except Exception as error:  # PyYAML's tag constructors raise anything (`!!int` alone)
            message = getattr(error, "problem", None) or (str(error).splitlines() or [""])[0]
            if isinstance(error, (IndexError, KeyError, AttributeError)) or not message:
                message = f"{node.value!r} is not a valid {node.tag.rsplit(':', 1)[-1]}"
            raise YamlSyntaxError(f"invalid value: {message}", _mark(node)) from None

    def walk(self, node: yaml.Node, path: tuple[Any, ...]) -> Any:
        self.nodes += 1
        if self.nodes > MAX_NODES:
            raise YamlSyntaxError(f"more than {MAX_NODES} values (an alias bomb?)", _mark(node))
        if len(path) > MAX_DEPTH:
            raise YamlSyntaxError(f"nested deeper than {MAX_DEPTH} levels", _mark(node))
        self.positions[path] = _mark(node)
        if isinstance(node, yaml.MappingNode):
            result: dict[Any, Any] = {}
            merged: dict[Any, Any] = {}
            for key_node, value_node in node.value:
                if key_node.tag == MERGE_TAG:  # `<<: *defaults`: their keys, unless given here
                    merged.update(self._merge(value_node, path))
                    continue
                if not isinstance(key_node, yaml.ScalarNode):
                    raise YamlSyntaxError("a key must be a plain value", _mark(key_node))
                key = self.scalar(key_node)
                if not isinstance(key, str):
                    raise YamlSyntaxError(_not_a_name(key_node, key), _mark(key_node))
                if key in result:
                    raise YamlSyntaxError(f"duplicate key {key!r}", _mark(key_node))
                self.key_positions[(*path, key)] = _mark(key_node)
                result[key] = self.walk(value_node, (*path, key))
            return {**merged, **result}
        if isinstance(node, yaml.SequenceNode):
            return [self.walk(item, (*path, i)) for i, item in enumerate(node.value)]
        return self.scalar(node)

    def _merge(self, node: yaml.Node, path: tuple[Any, ...]) -> dict[Any, Any]:
        """The mapping(s) a merge key names: one alias, or a list of them (the first wins)."""
        sources = node.value if isinstance(node, yaml.SequenceNode) else [node]
        merged: dict[Any, Any] = {}
        for source in reversed(sources):
            if not isinstance(source, yaml.MappingNode):
                raise YamlSyntaxError("'<<' merges mappings only (an alias of one)", _mark(source))
            merged.update(self.walk(source, path))
        return merged


MERGE_TAG = "tag:yaml.org,2002:merge"


def _not_a_name(node: yaml.ScalarNode, key: Any) -> str:
    kind = "a boolean" if isinstance(key, bool) else "null" if key is None else type(key).__name__
    return f"key {node.value!r} is {kind} in YAML, not a name (quote it if it is meant)"


FAST_PARSE_CHARS = 8000
"""Texts up to this long may be parsed by libyaml: they cannot nest deep enough (one level per
character at most) to overflow its recursive composer's C stack, which longer ones can."""


def _compose(text: str) -> yaml.Node | None:
    """The YAML node tree: libyaml's parser for short texts when there is one (ten times
    faster), the pure Python one otherwise and for text libyaml refuses, so that every error
    reads the same everywhere."""
    fast = getattr(yaml, "CSafeLoader", None)
    if fast is not None and len(text) <= FAST_PARSE_CHARS:
        try:
            return yaml.compose(text, Loader=fast)
        except (yaml.YAMLError, RecursionError):
            pass
    return yaml.compose(text, Loader=yaml.SafeLoader)


def load_yaml_with_positions(text: str) -> PositionedYaml:
    """Parse YAML text; raise YamlSyntaxError with the position of the first problem."""
    try:
        root = _compose(text)
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        location = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise YamlSyntaxError(
            str(error.problem or error.context or "invalid YAML"), location
        ) from None
    except yaml.YAMLError as error:
        raise YamlSyntaxError(str(error).splitlines()[0], (1, 1)) from None
    except RecursionError:
        raise YamlSyntaxError(f"nested deeper than {MAX_DEPTH} levels", (1, 1)) from None
    walker = _Walker()
    data = None if root is None else walker.walk(root, ())
    return PositionedYaml(data=data, positions=walker.positions, key_positions=walker.key_positions)
