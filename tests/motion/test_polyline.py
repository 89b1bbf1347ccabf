"""keymps.motion.polyline: one primitive rollout along a polyline (a continuous icing stroke)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from keymps.designs.patterns import spiral, star
from keymps.motion.polyline import CORNER_ROUNDING_M, rollout_along, smooth_path
from keymps.primitives.demos import Preprocessing, write_demo_csv
from keymps.primitives.dictionary import BUNDLED_DIR, learn_primitive, load_primitives

Z = 0.065  # the top surface plus the 5 mm margin, where icing pairs are grounded
DIP = 0.004  # the `line` primitive pipes 4 mm lower


@pytest.fixture(scope="module")
def line():
    return load_primitives(["line"], [BUNDLED_DIR])["line"]


def at_height(xy: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy, float)
    return np.column_stack([xy, np.full(len(xy), Z)])


def distance_to_polyline(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Each point's distance (board xy) to the polyline."""
    a, b = vertices[:-1, None, :2], vertices[1:, None, :2]
    p = points[None, :, :2]
    step = b - a
    t = np.clip(((p - a) * step).sum(-1) / (step**2).sum(-1), 0.0, 1.0)
    return np.linalg.norm(a + t[..., None] * step - p, axis=-1).min(axis=0)


def test_a_straight_chain_is_the_rollout_to_its_ends(line) -> None:
    """Bending a straight rollout onto a straight chain changes nothing: every sample of the
    rollout to the chain's ends is kept as it is, and the samples added on the way (the path's
    own points) lie on the same line at the heights between their neighbours."""
    vertices = at_height([[0.10, 0.06], [0.13, 0.10], [0.16, 0.14]])
    bent = rollout_along(line, vertices, speed=0.03, spacing=0.001)
    straight = line.rollout(vertices[0], vertices[-1], speed=0.03, spacing=0.001).y
    nearest = np.linalg.norm(straight[:, None] - bent[None], axis=2).min(axis=1)
    assert nearest.max() < 1e-12
    direction = (vertices[-1, :2] - vertices[0, :2]) / np.linalg.norm(
        vertices[-1, :2] - vertices[0, :2]
    )
    offset = bent[:, :2] - vertices[0, :2]
    assert np.abs(offset[:, 0] * direction[1] - offset[:, 1] * direction[0]).max() < 1e-12
    assert len(bent) > len(straight)


@pytest.mark.parametrize(
    "name,vertices",
    [
        ("spiral", np.vstack([p[0] for p in spiral((0.15, 0.09), 0.002, 0.035, 3.0, 48)])),
        ("star", np.vstack([p[0] for p in star((0.15, 0.09), 0.04, 5)] + [[0.15, 0.13]])),
        ("zigzag", np.array([[0.10 + 0.004 * k, 0.09 + 0.003 * (k % 2)] for k in range(12)])),
    ],
)
def test_the_nozzle_stays_down_along_the_whole_chain(line, name: str, vertices: np.ndarray) -> None:
    """It goes down once at the start and up once at the end: between them the tip stays at
    the drawing height, through every vertex, with no lift at the joints."""
    vertices = at_height(vertices)
    points = rollout_along(line, vertices, speed=0.03, spacing=0.001)
    assert np.linalg.norm(np.diff(points, axis=0), axis=1).max() <= 0.001 + 1e-9
    near = distance_to_polyline(points, vertices).max()
    assert near < (CORNER_ROUNDING_M if name == "spiral" else 1e-5)  # 1e-5: the DMP at rest
    for vertex in vertices[1:-1]:  # a sharp corner exactly: a star's tips are not cut short
        closest = np.abs(points[:, :2] - vertex[:2]).sum(axis=1).min()
        assert closest < (2 * CORNER_ROUNDING_M if name == "spiral" else 1e-12)
    assert np.linalg.norm(points[0] - vertices[0]) < 1e-9
    assert np.linalg.norm(points[-1] - vertices[-1]) < 2e-6  # the DMP's fit at rest
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(vertices, axis=0), axis=1))])
    moved = np.linalg.norm(points[:, :2] - vertices[0, :2], axis=1)
    left = np.linalg.norm(points[:, :2] - vertices[-1, :2], axis=1)
    between = (moved > 0.0005) & (left > 0.0005)
    if np.array_equal(vertices[0], vertices[-1]):  # a loop: its start and end coincide
        between = np.ones(len(points), bool)
        between[: np.argmax(moved > 0.0005)] = False
        between[len(points) - np.argmax(moved[::-1] > 0.0005) :] = False
    assert arc[-1] > 0.05
    assert np.abs(points[between, 2] - (Z - DIP)).max() < 5e-5
    assert points[:, 2].max() <= Z + 1e-6 and points[:, 2].min() >= Z - DIP - 1e-5


def sideways_primitive(folder: Path):
    """An icing primitive that swings 3 mm sideways as it pipes (a learned zigzag)."""
    t = np.linspace(0.0, 3.0, 301)
    progress = np.clip((t - 0.5) / 2.0, 0.0, 1.0)
    smooth = progress**3 * (10 - 15 * progress + 6 * progress**2)
    y = np.column_stack(
        [
            0.05 * smooth,
            0.003 * np.sin(6 * math.pi * smooth),
            -0.004 * np.minimum(1.0, np.minimum(t, 3.0 - t) / 0.5),
        ]
    )
    write_demo_csv(folder / "zigzag.csv", t, y)
    return learn_primitive(
        "zigzag", folder / "zigzag.csv", description="A zigzag line.", family="icing",
        preprocessing=Preprocessing(trim_mm=0.0),
    )  # fmt: skip


def test_sideways_offsets_turn_with_the_path_and_stay_continuous(tmp_path: Path) -> None:
    """A primitive that swings sideways keeps its swing across the path at every heading, and
    turns it smoothly round a corner: no jump where one segment's sideways meets the next's."""
    primitive = sideways_primitive(tmp_path)
    vertices = at_height([[0.10, 0.05], [0.16, 0.05], [0.16, 0.11], [0.12, 0.08]])
    points = rollout_along(primitive, vertices, speed=0.03, spacing=0.001)
    assert np.linalg.norm(np.diff(points, axis=0), axis=1).max() < 0.0011  # 1.8 mm unblended
    off = distance_to_polyline(points, vertices)
    assert 0.0025 < off.max() < 0.0035  # the 3 mm swing, sideways on every leg
    straight = primitive.rollout(vertices[0], vertices[1], speed=0.03, spacing=0.001).y
    assert distance_to_polyline(straight, vertices[:2]).max() == pytest.approx(off.max(), abs=5e-4)


def test_overshoot_past_the_ends_is_limited_to_the_reach(tmp_path: Path) -> None:
    """A primitive that runs past its goal (as a learned stroke may) is held within `reach`
    of the chain's ends, as a single pair's rollout is near the object's edge."""
    t = np.linspace(0.0, 3.0, 301)
    x = 0.06 * np.sin(0.5 * math.pi * np.clip(t / 2.0, 0, 1)) - 0.01 * np.clip(t - 2.0, 0, 1)
    write_demo_csv(tmp_path / "over.csv", t, np.column_stack([x, 0 * t, 0 * t]))
    primitive = learn_primitive(
        "over", tmp_path / "over.csv", description="x", family="icing",
        preprocessing=Preprocessing(trim_mm=0.0),
    )  # fmt: skip
    vertices = at_height([[0.10, 0.05], [0.14, 0.05], [0.14, 0.09]])
    free = rollout_along(primitive, vertices, speed=0.03, spacing=0.001)
    held = rollout_along(primitive, vertices, speed=0.03, spacing=0.001, reach=(0.0, 0.002))
    assert free[:, 1].max() > 0.09 + 0.005  # past the end by the demo's 20 %
    assert held[:, 1].max() <= 0.09 + 0.002 + 1e-9


def test_a_spiral_of_short_pairs_is_piped_as_a_curve_near_its_pairs(line) -> None:
    """Turns under the corner angle are rounded: the piped spiral turns gradually (no kink for
    the joints to follow at speed) and stays within CORNER_ROUNDING_M of its 48 pairs."""
    pairs = spiral((0.15, 0.09), 0.002, 0.035, 3.0, 48)
    vertices = at_height(np.vstack([pairs[:, 0], pairs[-1:, 1]]))
    points = rollout_along(line, vertices, speed=0.03, spacing=0.001)
    on_path = points[points[:, 2] < Z - DIP + 1e-5]
    assert distance_to_polyline(on_path, vertices).max() < CORNER_ROUNDING_M
    steps = np.diff(on_path[:, :2], axis=0)
    steps = steps[np.linalg.norm(steps, axis=1) > 1e-5]
    heading = np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))
    assert np.degrees(np.abs(np.diff(heading))).max() < 3.5  # vs 19-22 degrees at each pair


def test_random_chains_stay_near_their_pairs_and_keep_their_sharp_corners() -> None:
    """300 random chains, segments 1-20 mm, turns up to 60 degrees: the path is within
    CORNER_ROUNDING_M of the polyline, passes exactly through its ends and every turn of 30
    degrees or more, and elsewhere turns by at most 3 degrees per sample."""
    rng = np.random.default_rng(39)
    for _ in range(300):
        count = int(rng.integers(2, 30))
        lengths = rng.uniform(0.001, 0.02, count)
        heading = np.cumsum(rng.uniform(-1.0, 1.0, count)) + rng.uniform(0, 2 * math.pi)
        moves = lengths[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        vertices = at_height(0.1 + np.vstack([[0.0, 0.0], np.cumsum(moves, axis=0)]))
        path = smooth_path(vertices)
        assert distance_to_polyline(path, vertices).max() <= CORNER_ROUNDING_M + 1e-12
        assert np.array_equal(path[0], vertices[0]) and np.array_equal(path[-1], vertices[-1])
        turns = np.abs(np.remainder(np.diff(heading) + math.pi, 2 * math.pi) - math.pi)
        for k in np.flatnonzero(turns >= math.radians(30.0)) + 1:
            assert (path == vertices[k]).all(axis=1).any()
        steps = np.diff(path[:, :2], axis=0)
        bends = np.abs(
            np.remainder(np.diff(np.arctan2(steps[:, 1], steps[:, 0])) + math.pi, 2 * math.pi)
            - math.pi
        )
        assert np.sum(bends > math.radians(3.0) + 1e-9) <= np.sum(turns >= math.radians(30.0))
