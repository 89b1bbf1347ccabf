"""YAML loading that remembers where every key and value came from (line and column)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import yaml

Location = tuple[int, int]
"""(line, column), both 1-based."""


@dataclass(frozen=True)
class PositionedYaml:
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


_constructor = yaml.constructor.SafeConstructor()


def _scalar(node: yaml.Node) -> Any:
    return _constructor.construct_object(node, deep=True)


def _mark(node: yaml.Node) -> Location:
    return (node.start_mark.line + 1, node.start_mark.column + 1)


def _walk(
    node: yaml.Node,
    path: tuple[Any, ...],
    positions: dict[tuple[Any, ...], Location],
    key_positions: dict[tuple[Any, ...], Location],
) -> Any:
    positions[path] = _mark(node)
    if isinstance(node, yaml.MappingNode):
        result: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = _scalar(key_node)
            if key in result:
                raise YamlSyntaxError(f"duplicate key {key!r}", _mark(key_node))
            key_positions[(*path, key)] = _mark(key_node)
            result[key] = _walk(value_node, (*path, key), positions, key_positions)
        return result
    if isinstance(node, yaml.SequenceNode):
        return [
            _walk(item, (*path, i), positions, key_positions) for i, item in enumerate(node.value)
        ]
    return _scalar(node)


def load_yaml_with_positions(text: str) -> PositionedYaml:
    """Parse YAML text; raise YamlSyntaxError with the position of the first problem."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        location = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        raise YamlSyntaxError(
            str(error.problem or error.context or "invalid YAML"), location
        ) from None
    except yaml.YAMLError as error:
        raise YamlSyntaxError(str(error).splitlines()[0], (1, 1)) from None
    positions: dict[tuple[Any, ...], Location] = {}
    key_positions: dict[tuple[Any, ...], Location] = {}
    data = None if root is None else _walk(root, (), positions, key_positions)
    return PositionedYaml(data=data, positions=positions, key_positions=key_positions)
