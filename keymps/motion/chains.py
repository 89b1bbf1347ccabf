"""Continuous strokes: icing pairs whose ends meet are piped without lifting the nozzle.

Eq. 6 travels to each pair's start, then runs the primitive. When a pair starts where another
ends, that travel move is empty: the nozzle stays down and the lines are one stroke. The lines
form a graph (nodes: line ends that meet; edges: the lines); each connected part is piped in as
few strokes as it allows, every line once (Euler trails), and dots (pairs whose start is their
goal) stay on their own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

JOIN_LINE_WIDTHS = 0.5
"""Line ends closer than this many line widths meet. Their icing already overlaps over more
than half its width, so piping them as one stroke looks the same at the joint, less the blob
of a stop and a restart, and moves each end by at most a quarter of the width. Further apart,
the gap shows: joining would draw icing the plan did not ask for."""
MEET_M = 1e-6
"""Line ends this close meet whatever the join distance (the same keypoint grounded twice)."""
DOT_M = 1e-6
"""A pair shorter than this is a dot: it is never joined to anything."""
VIRTUAL = -1
"""The node joined to every odd node, so that one Euler circuit gives every trail."""


@dataclass(frozen=True)
class Chain:
    """Pairs piped as one stroke, in piping order."""

    pairs: tuple[int, ...]
    """Indexes of the keypoint pairs, in the order they are piped."""
    reversed: tuple[bool, ...]
    """Per pair, whether it is piped from its goal to its start."""
    vertices: np.ndarray
    """(len(pairs) + 1, 3) board metres: the stroke's start, where each pair ends (ends that
    meet within the join distance are moved to their mean) and its end."""


def pipe_chains(ends: np.ndarray, objects: Sequence[int], join_distance: float) -> list[Chain]:
    """The pairs grouped into continuous strokes: ends of lines on the same object within
    `join_distance` of each other meet (ends of one line never do), and each connected group
    of lines is cut into as few Euler trails as its odd nodes allow.

    Strokes come in plan order (by their first pair in the plan); in a group whose pairs
    already follow each other end to start, the plan's order and directions are kept. Where
    a group branches (a seven-segment "4"), a trail starts at the odd node of the earliest
    pair (its start, else its goal) and takes, at every node, the earliest pair not yet piped.

    Args:
        ends: (K, 2, 3) each pair's start and goal, board metres.
        objects: (K,) the object each pair lies on.
        join_distance: Ends at most this far apart meet, metres (MEET_M at least).

    Returns:
        Every pair exactly once; a dot or a line that meets nothing is a chain of one pair.
    """
    ends = np.asarray(ends, dtype=float).reshape(-1, 2, 3)
    lines = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1) >= DOT_M
    node_of, positions = _nodes(ends, np.asarray(objects), lines, max(join_distance, MEET_M))
    groups = _groups(node_of, lines)
    found: list[tuple[int, Chain]] = []
    for k in np.flatnonzero(~lines).tolist():
        found.append((k, Chain((k,), (False,), ends[k].copy())))
    for group in groups:
        trails = _trails([(k, int(node_of[k, 0]), int(node_of[k, 1])) for k in group])
        for trail in trails:
            pairs = tuple(k for k, _ in trail)
            flipped = tuple(back for _, back in trail)
            first = int(node_of[pairs[0], 1 if flipped[0] else 0])
            nodes = [first] + [int(node_of[k, 0 if back else 1]) for k, back in trail]
            if len(pairs) == 1 and not flipped[0]:
                vertices = ends[pairs[0]].copy()  # alone: exactly the pair
            else:
                vertices = positions[nodes]
            found.append((min(group), Chain(pairs, flipped, vertices)))
    found.sort(key=lambda item: item[0])  # stable: a group's trails keep their order
    return [chain for _, chain in found]


def _nodes(
    ends: np.ndarray, objects: np.ndarray, lines: np.ndarray, reach: float
) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) the node of each line end (-1 for dots) and the nodes' positions.

    Close ends are merged nearest first (single linkage) unless the merge would put both
    ends of one line in a node or make a node wider than `reach`."""
    count = len(ends)
    points = ends.reshape(-1, 3)
    owner = np.repeat(np.arange(count), 2)
    active = np.repeat(lines, 2)
    parent = list(range(2 * count))
    members: dict[int, list[int]] = {i: [i] for i in range(2 * count)}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    close = _close_pairs(points, reach)
    left, right = close[:, 0], close[:, 1]
    usable = active[left] & active[right] & (owner[left] != owner[right])
    usable &= objects[owner[left]] == objects[owner[right]]
    left, right = left[usable], right[usable]
    distance = np.linalg.norm(points[left] - points[right], axis=1)
    candidates = sorted(zip(distance.tolist(), left.tolist(), right.tolist(), strict=True))
    for _, first, second in candidates:
        a, b = root(first), root(second)
        if a == b:
            continue
        merged = members[a] + members[b]
        if len({int(owner[m]) for m in merged}) < len(merged):
            continue  # both ends of one line: it would shrink to a point
        group = points[merged]
        if np.linalg.norm(group[:, None] - group[None], axis=2).max() > reach:
            continue
        parent[b] = a
        members[a] = merged
        del members[b]
    roots = sorted({root(i) for i in range(2 * count) if active[i]})
    number = {r: n for n, r in enumerate(roots)}
    node_of = np.array([number[root(i)] if active[i] else -1 for i in range(2 * count)])
    positions = np.array([_centre(points[members[r]]) for r in roots]).reshape(-1, 3)
    return node_of.reshape(count, 2), positions


def _close_pairs(points: np.ndarray, reach: float) -> np.ndarray:
    """(m, 2) index pairs of the points at most `reach` apart, each pair once: a sweep along
    x (the points sorted once, each compared with those less than `reach` further along)."""
    order = np.argsort(points[:, 0], kind="stable")
    x = points[order, 0]
    following = np.searchsorted(x, x + reach, side="right") - np.arange(len(x)) - 1
    first = np.repeat(np.arange(len(x)), following)
    offset = np.arange(len(first)) - np.repeat(np.cumsum(following) - following, following)
    a, b = order[first], order[first + 1 + offset]
    near = np.linalg.norm(points[a] - points[b], axis=1) <= reach
    return np.column_stack([a[near], b[near]])


def _centre(points: np.ndarray) -> np.ndarray:
    """Where ends that meet are joined: their mean (exactly the point when they coincide)."""
    if (points == points[0]).all():
        return points[0].copy()
    return points.mean(axis=0)


def _groups(node_of: np.ndarray, lines: np.ndarray) -> list[list[int]]:
    """The lines' connected groups, each in plan order, the groups by their first line."""
    parent = list(range(len(node_of)))
    first_at: dict[int, int] = {}

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for k in np.flatnonzero(lines).tolist():
        for node in node_of[k].tolist():
            if node in first_at:
                a, b = root(first_at[node]), root(k)
                parent[max(a, b)] = min(a, b)
            else:
                first_at[node] = k
    groups: dict[int, list[int]] = {}
    for k in np.flatnonzero(lines).tolist():
        groups.setdefault(root(k), []).append(k)
    return list(groups.values())


def _trails(edges: list[tuple[int, int, int]]) -> list[list[tuple[int, bool]]]:
    """A connected group's lines (pair, start node, goal node), in plan order, as the fewest
    trails that pipe each once: per trail, (pair, whether it is piped goal to start).

    A node of odd degree must end a trail: all of them are joined to one virtual node, and
    Hierholzer's circuit from there (or, with no odd node, from the first pair's start) is
    cut wherever it passes through the virtual node."""
    adjacency: dict[int, list[tuple[int, int]]] = {}  # node -> (edge, other node)
    for edge, (_, start, goal) in enumerate(edges):
        adjacency.setdefault(start, []).append((edge, goal))
        adjacency.setdefault(goal, []).append((edge, start))
    rank: dict[
        int, int
    ] = {}  # a node's preference as a trail's start: the earliest pair's start, then goal
    for edge, (_, start, goal) in enumerate(edges):
        rank.setdefault(start, 2 * edge)
        rank[goal] = min(rank.get(goal, 2 * edge + 1), 2 * edge + 1)
    odd = sorted((n for n, out in adjacency.items() if len(out) % 2), key=rank.__getitem__)
    start = min(adjacency, key=rank.__getitem__)
    if odd:  # the virtual edges, after the real ones at each node
        for offset, node in enumerate(odd):
            adjacency[node].append((len(edges) + offset, VIRTUAL))
        adjacency[VIRTUAL] = [(len(edges) + offset, node) for offset, node in enumerate(odd)]
        start = VIRTUAL
    circuit = _circuit(adjacency, start, len(edges) + len(odd))
    trails: list[list[tuple[int, bool]]] = [[]]
    for edge, origin in circuit:
        if edge >= len(edges):
            trails.append([])
            continue
        pair, pair_start, _ = edges[edge]
        trails[-1].append((pair, origin != pair_start))
    return [trail for trail in trails if trail]


def _circuit(
    adjacency: dict[int, list[tuple[int, int]]], start: int, count: int
) -> list[tuple[int, int]]:
    """Hierholzer's Euler circuit from `start`: (edge, node it leaves from) in order; at each
    node the first unused edge of its list is taken."""
    used = [False] * count
    cursor = dict.fromkeys(adjacency, 0)
    stack: list[tuple[int, int | None, int]] = [(start, None, start)]  # node, edge, from
    circuit: list[tuple[int, int]] = []
    while stack:
        node, arrived_by, came_from = stack[-1]
        out = adjacency[node]
        while cursor[node] < len(out) and used[out[cursor[node]][0]]:
            cursor[node] += 1
        if cursor[node] < len(out):
            edge, other = out[cursor[node]]
            used[edge] = True
            stack.append((other, edge, node))
        else:
            stack.pop()
            if arrived_by is not None:
                circuit.append((arrived_by, came_from))
    circuit.reverse()
    return circuit
