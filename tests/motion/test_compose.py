"""keymps.motion.compose: composing travel moves and re-targeted primitives into one tool path."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from keymps.errors import KeympsError
from keymps.motion.compose import compose_tool_path
from keymps.primitives.dictionary import BUNDLED_DIR, load_primitives
from keymps.types import Segment, ToolPath

TOP = 0.05
MARGIN = 0.005
CLEARANCE = 0.03
HOME = np.array([0.15, 0.09, 0.13])
LOAF = (0.08, 0.05, 0.22, 0.13)
"""x0, y0, x1, y1 of a loaf on the board, metres."""


@pytest.fixture(scope="module")
def dictionary() -> dict:
    return load_primitives(["sawing", "straight", "line"], [BUNDLED_DIR])


def cut(x0: float, y0: float, x1: float, y1: float) -> Segment:
    """A cutting pair as grounding makes it: start on top (+margin), goal on the board."""
    return Segment(
        start=np.array([x0, y0, TOP + MARGIN]),
        goal=np.array([x1, y1, 0.0]),
        start_px=(0.0, 0.0),
        goal_px=(0.0, 0.0),
    )


def dot_or_line(x0: float, y0: float, x1: float, y1: float) -> Segment:
    """An icing pair: both ends on the top surface (+margin)."""
    return Segment(
        start=np.array([x0, y0, TOP + MARGIN]),
        goal=np.array([x1, y1, TOP + MARGIN]),
        start_px=(0.0, 0.0),
        goal_px=(0.0, 0.0),
    )


def compose(segments, primitive, yaw_mode="follow", **kw) -> ToolPath:
    options = dict(
        object_top=TOP, clearance=CLEARANCE, work_speed=0.03, travel_speed=0.15, home=HOME
    )
    options.update(kw)
    return compose_tool_path(segments, primitive, yaw_mode=yaw_mode, **options)


SLICES = [cut(x, 0.04, x, 0.14) for x in (0.11, 0.14, 0.17, 0.20)]


def test_structure_continuity_and_speeds(dictionary: dict) -> None:
    path = compose(SLICES, dictionary["sawing"])
    kinds = [p.kind for p in path.pieces]
    assert kinds == ["travel", "work"] * 4 + ["travel"]
    assert [p.pair_index for p in path.pieces] == [0, 0, 1, 1, 2, 2, 3, 3, 3]
    assert path.keyword == "sawing"
    assert np.array_equal(path.pieces[0].points[0], HOME)
    assert np.array_equal(path.pieces[-1].points[-1], HOME)
    for before, after in zip(path.pieces[:-1], path.pieces[1:], strict=True):
        assert np.array_equal(before.points[-1], after.points[0])
    for piece in path.pieces:
        assert len(piece.points) == len(piece.yaw) >= 2
        assert piece.speed == (0.03 if piece.kind == "work" else 0.15)
    works = [p for p in path.pieces if p.kind == "work"]
    for piece, segment in zip(works, SLICES, strict=True):
        assert np.array_equal(piece.points[0], segment.start)
        assert np.linalg.norm(piece.points[-1] - segment.goal) < 1e-6
        assert np.linalg.norm(np.diff(piece.points, axis=0), axis=1).max() <= 0.001
        assert piece.points[:, 2].min() > -1e-4  # never below the board


def test_work_piece_is_the_retargeted_primitive(dictionary: dict) -> None:
    sawing = dictionary["sawing"]
    path = compose(SLICES[:1], sawing)
    work = path.pieces[1].points
    expected = sawing.rollout(SLICES[0].start, SLICES[0].goal, speed=0.03).y
    assert np.array_equal(work, expected)
    # The strokes run along the cut (y), the blade does not wander sideways.
    assert np.abs(work[:, 0] - 0.11).max() < 1e-3
    along = work[:, 1] - np.linspace(0.04, 0.14, len(work))
    assert along.max() - along.min() > 0.02


def footprint_contains(xy: np.ndarray, shrink: float = 0.0) -> np.ndarray:
    x0, y0, x1, y1 = LOAF
    return (
        (xy[:, 0] > x0 + shrink)
        & (xy[:, 0] < x1 - shrink)
        & (xy[:, 1] > y0 + shrink)
        & (xy[:, 1] < y1 - shrink)
    )


def test_no_travel_move_passes_through_the_object(dictionary: dict) -> None:
    path = compose(SLICES, dictionary["straight"])
    for piece in path.pieces:
        if piece.kind != "travel":
            continue
        inside = footprint_contains(piece.points[:, :2])
        assert (piece.points[inside, 2] >= TOP).all()


point_xy = st.tuples(st.floats(0.0, 0.3), st.floats(0.0, 0.18))


@settings(max_examples=40, deadline=None)
@given(
    pairs=st.lists(st.tuples(point_xy, point_xy), min_size=1, max_size=5),
    home_z=st.floats(0.02, 0.3),
)
def test_travel_is_vertical_or_above_the_clearance_height(
    dictionary: dict, pairs: list, home_z: float
) -> None:
    """Any travel point is at the travel height or above, or straight above/below an end."""
    segments = [cut(a[0], a[1], b[0], b[1]) for a, b in pairs]
    home = np.array([0.15, 0.09, home_z])
    path = compose(segments, dictionary["straight"], home=home)
    travel_z = TOP + CLEARANCE
    for piece in path.pieces:
        if piece.kind != "travel":
            continue
        ends = piece.points[[0, -1], :2]
        for point in piece.points:
            vertical = np.linalg.norm(ends - point[:2], axis=1).min() < 1e-12
            assert vertical or point[2] >= travel_z - 1e-12
        # The yaw turns only in the air.
        turning = np.abs(np.diff(piece.yaw)) > 0
        assert (piece.points[1:][turning, 2] >= travel_z - 1e-12).all()


def test_knife_yaw_is_the_cut_direction_so_the_blade_trails_the_tip(dictionary: dict) -> None:
    """The edge lies along the tool's -x axis: the tool x axis points along the cut, never
    against it (a yaw taken modulo 180 degrees let the edge lead and left the start uncut)."""
    back_and_forth = [cut(0.1, 0.04, 0.1, 0.14), cut(0.13, 0.14, 0.13, 0.04)]
    path = compose(back_and_forth, dictionary["straight"])
    works = [p for p in path.pieces if p.kind == "work"]
    assert np.allclose(works[0].yaw, math.pi / 2) and np.allclose(works[1].yaw, -math.pi / 2)

    center = np.array([0.15, 0.09])
    radial = []
    for k in range(12):
        angle = k * 2 * math.pi / 12
        end = center + 0.05 * np.array([math.cos(angle), math.sin(angle)])
        radial.append(cut(center[0], center[1], end[0], end[1]))
    path = compose(radial, dictionary["straight"])
    for piece in path.pieces:
        if piece.kind != "work":
            continue
        travel = piece.points[-1, :2] - piece.points[0, :2]
        tool_x = np.array([math.cos(piece.yaw[0]), math.sin(piece.yaw[0])])
        assert tool_x @ travel > 0.999 * np.linalg.norm(travel)
    yaws = np.concatenate([piece.yaw for piece in path.pieces])
    assert np.abs(np.diff(yaws)).max() <= math.pi / 6 + 1e-9  # 30 degrees a ray, the short way


def test_chords_turn_from_the_arms_home_yaw_and_the_wrist_always_the_short_way(
    dictionary: dict,
) -> None:
    """Random chords across a disc (any count, direction and order) and a random home yaw: the
    first chord runs the way nearer the home yaw (an arm whose roll is short of a whole turn,
    the Panda's, has room both ways), and no move turns the wrist by more than half a turn,
    across +-180 degrees included (yaws are unwrapped)."""
    rng = np.random.default_rng(37)
    angles = np.linspace(0.0, 2 * math.pi, 48, endpoint=False)
    centre = np.array([0.15, 0.09])
    circle = centre + 0.05 * np.c_[np.cos(angles), np.sin(angles)]
    for _ in range(150):
        home_yaw = float(rng.uniform(-math.pi, math.pi))
        chords = []
        for direction in rng.uniform(0.0, 2 * math.pi, int(rng.integers(1, 7))):
            half = 0.06 * np.array([math.cos(direction), math.sin(direction)])
            offset = rng.uniform(-0.03, 0.03) * np.array([-half[1], half[0]]) / 0.06
            a, b = centre + offset - half, centre + offset + half
            chords.append(cut(a[0], a[1], b[0], b[1]))
        path = compose(chords, dictionary["straight"], footprint=circle, home_yaw=home_yaw)
        works = [p for p in path.pieces if p.kind == "work"]
        assert abs(works[0].yaw[0] - home_yaw) <= math.pi / 2 + 1e-9
        for piece in path.pieces:
            assert np.abs(np.diff(piece.yaw)).sum() <= math.pi + 1e-9
        for work in works:
            travel = work.points[-1, :2] - work.points[0, :2]
            tool_x = np.array([math.cos(work.yaw[0]), math.sin(work.yaw[0])])
            assert tool_x @ travel > 0.999 * np.linalg.norm(travel)


def test_a_chord_runs_the_way_that_turns_the_wrist_least_with_the_edge_trailing(
    dictionary: dict,
) -> None:
    """Cuts across the food (both ends beyond its edge) may run either way: back-and-forth
    chords run the same way (no half turn of the wrist between them), each still starting
    above the food and ending on the board with the tool x axis along the travel. A ray that
    ends at the centre keeps its direction (reversed, the trailing edge would cross the far
    half)."""
    angles = np.linspace(0.0, 2 * math.pi, 48, endpoint=False)
    circle = np.array([0.15, 0.09]) + 0.05 * np.c_[np.cos(angles), np.sin(angles)]
    chords = [cut(0.13, 0.03, 0.13, 0.15), cut(0.15, 0.15, 0.15, 0.03), cut(0.17, 0.03, 0.17, 0.15)]
    ray = cut(0.15, 0.15, 0.15, 0.09)
    path = compose([*chords, ray], dictionary["straight"], footprint=circle)
    works = [p for p in path.pieces if p.kind == "work"]
    assert np.allclose([w.yaw[0] for w in works[:3]], math.pi / 2)
    assert works[1].piped_pairs == (1,) and works[1].points[0, 1] < works[1].points[-1, 1]
    for work in works:
        travel = work.points[-1, :2] - work.points[0, :2]
        tool_x = np.array([math.cos(work.yaw[0]), math.sin(work.yaw[0])])
        assert tool_x @ travel > 0.999 * np.linalg.norm(travel)
        assert work.points[0, 2] > TOP and work.points[-1, 2] == pytest.approx(0.0, abs=1e-6)
    assert np.allclose(works[3].yaw, -math.pi / 2)  # the ray, as planned: rim to centre


@pytest.mark.parametrize("primitive", ["straight", "sawing"])
def test_a_chord_longer_than_the_blade_is_cut_from_both_ends(
    dictionary: dict, primitive: str
) -> None:
    """The blade lies on the board only along the end of a cut: a chord through 24 cm of food
    with a 16 cm blade is two strokes of the same pair, each from one edge to past the middle
    (they overlap by BLADE_OVERLAP_M), each starting above the food and ending on the board
    with the edge trailing; a 14 cm chord stays one stroke."""
    from keymps.motion.compose import BLADE_OVERLAP_M

    angles = np.linspace(0.0, 2 * math.pi, 96, endpoint=False)
    cake = np.array([0.20, 0.15]) + 0.12 * np.c_[np.cos(angles), np.sin(angles)]
    long_chord, short_chord = cut(0.075, 0.15, 0.325, 0.15), cut(0.13, 0.10, 0.27, 0.10)
    path = compose(
        [long_chord, short_chord], dictionary[primitive], footprint=cake, blade_length=0.16
    )
    works = [p for p in path.pieces if p.kind == "work"]
    assert [w.pair_index for w in works] == [0, 0, 1]
    first, second = works[0], works[1]
    reach = [float(np.ptp(w.points[:, 0])) for w in works[:2]]
    assert all(0.125 + BLADE_OVERLAP_M / 2 - 0.01 < r < 0.16 for r in reach), reach
    # from opposite edges, meeting past the middle
    assert first.points[0, 0] < 0.10 and second.points[0, 0] > 0.30
    assert first.points[-1, 0] > 0.20 > second.points[-1, 0]
    for work in works:
        travel = work.points[-1, :2] - work.points[0, :2]
        tool_x = np.array([math.cos(work.yaw[0]), math.sin(work.yaw[0])])
        assert tool_x @ travel > 0.999 * np.linalg.norm(travel)
        assert work.points[0, 2] > TOP and work.points[-1, 2] == pytest.approx(0.0, abs=1e-6)
    without = compose([long_chord], dictionary[primitive], footprint=cake)
    assert sum(p.kind == "work" for p in without.pieces) == 1  # no blade given: as planned


def test_piping_bag_keeps_a_fixed_yaw_and_dots_are_dots(dictionary: dict) -> None:
    segments = [dot_or_line(0.1, 0.08, 0.1, 0.08), dot_or_line(0.12, 0.06, 0.18, 0.1)]
    path = compose(segments, dictionary["line"], yaw_mode="fixed", home_yaw=0.3)
    assert all(np.all(p.yaw == 0.3) for p in path.pieces)
    dot, line = [p.points for p in path.pieces if p.kind == "work"]
    assert np.abs(dot[:, :2] - [0.1, 0.08]).max() < 1e-6
    assert dot[:, 2].min() == pytest.approx(TOP + MARGIN - 0.004, abs=2e-4)
    assert np.linalg.norm(line[-1] - segments[1].goal) < 1e-6
    assert line[:, 2].min() == pytest.approx(TOP + MARGIN - 0.004, abs=2e-4)  # axial: same dip


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"segments": []}, "no keypoint pairs"),
        ({"yaw_mode": "spin"}, "yaw mode 'spin'"),
        ({"work_speed": 0.0}, "work_speed must be a positive"),
        ({"home": np.array([0.0, np.nan, 0.1])}, "home must be a finite"),
        ({"segments": [cut(0.1, 0.1, np.inf, 0.1)]}, "segment 1 goal"),
    ],
)
def test_bad_input_gives_one_clear_line(dictionary: dict, kwargs: dict, message: str) -> None:
    segments = kwargs.pop("segments", SLICES)
    with pytest.raises(KeympsError, match=message) as info:
        compose(segments, dictionary["straight"], **kwargs)
    assert "\n" not in str(info.value)


def test_a_vertical_plunge_saws_along_the_blade(dictionary: dict) -> None:
    """A pair with start and goal at the same xy has no direction: the blade keeps the previous
    cut's yaw, and the sawing strokes run along the blade, not along the demo's world x."""
    segments = [cut(0.1, 0.04, 0.1, 0.14), cut(0.15, 0.09, 0.15, 0.09)]
    path = compose(segments, dictionary["sawing"])
    first, plunge = [p for p in path.pieces if p.kind == "work"]
    assert plunge.yaw[0] == first.yaw[0]
    blade = np.array([math.cos(plunge.yaw[0]), math.sin(plunge.yaw[0])])
    horizontal = plunge.points[:, :2] - [0.15, 0.09]
    along = horizontal @ blade
    across = horizontal @ np.array([-blade[1], blade[0]])
    assert np.ptp(along) > 0.005
    assert np.abs(across).max() < 1e-9


def test_a_sawing_path_runs_on_the_real_ur3_pipeline(dictionary: dict) -> None:
    """Real Pinocchio IK, Ruckig timing and the safety validator accept a composed sawing path,
    and the timed tool follows the composed points."""
    from keymps.config.task import load_task
    from keymps.motion.timing import time_trajectory
    from keymps.robot.model import RobotModel, solve_path
    from keymps.robot.safety import validate

    task = load_task(Path(__file__).resolve().parents[2] / "tasks" / "object_cutting.yaml")
    robot = RobotModel.from_task(task)
    top = task.scene.object_height
    segments = [
        Segment(np.array([x, 0.05, top + 0.005]), np.array([x, 0.13, 0.0]), (0, 0), (0, 0))
        for x in (0.13, 0.17)
    ]
    path = compose_tool_path(
        segments,
        dictionary["sawing"],
        object_top=top,
        clearance=task.motion.clearance,
        work_speed=task.motion.work_speed,
        travel_speed=task.motion.travel_speed,
        yaw_mode=robot.tool.yaw,
        home=robot.home_tool_position(),
    )
    joints = solve_path(robot, path)
    assert joints.max_position_error_m < 1e-4
    trajectory = time_trajectory(robot, path, joints, task)
    # The loaf spans y 0.04-0.14: the +-2 cm strokes reach 6 mm past its ends, within the
    # validator's 10 mm (pairs reaching past the object would need a wider margin for sawing).
    outline = np.array([[0.1, 0.04], [0.2, 0.04], [0.2, 0.14], [0.1, 0.14]])
    checked = validate(robot, trajectory, path, outline, task)
    assert checked.report.ok
    work = trajectory.kind == "work"
    # Every timed work sample lies on the composed sawing path (within 1 mm).
    composed = np.concatenate([p.points for p in path.pieces if p.kind == "work"])
    timed = trajectory.tool_xyz[work][::10]
    distance = np.linalg.norm(timed[:, None, :] - composed[None, ::2, :], axis=2).min(axis=1)
    assert distance.max() < 0.001


def spiral_and_dots() -> list[Segment]:
    """Paper Table IV case 3 as the offline planner lays it out: dots round the edge, then a
    spiral of 48 segments that meet end to end."""
    from keymps.designs.patterns import ring_points, spiral

    dots = [dot_or_line(x, y, x, y) for x, y in ring_points((0.15, 0.09), 0.05, 12)]
    lines = [dot_or_line(*a, *b) for a, b in spiral((0.15, 0.09), 0.002, 0.035, 3.0, 48)]
    return dots + lines


def test_icing_lines_that_meet_are_one_stroke_with_no_travel_between(dictionary: dict) -> None:
    """Eq. 6 with an empty travel move: the spiral is one work piece (the nozzle goes down once
    and up once), not 48 pieces each followed by a 3 cm lift; the dots stay dots."""
    segments = spiral_and_dots()
    path = compose(segments, dictionary["line"], yaw_mode="fixed", join_distance=0.002)
    kinds = [p.kind for p in path.pieces]
    assert kinds == ["travel", "work"] * 13 + ["travel"]
    works = [p for p in path.pieces if p.kind == "work"]
    assert [p.pairs for p in works] == [(k,) for k in range(12)] + [tuple(range(12, 60))]
    assert [p.pair_index for p in works] == list(range(13))
    spiral_piece = works[-1]
    drawing = TOP + MARGIN - 0.004
    inner = np.linalg.norm(spiral_piece.points[:, :2] - segments[12].start[:2], axis=1) > 1e-3
    inner &= np.linalg.norm(spiral_piece.points[:, :2] - segments[-1].goal[:2], axis=1) > 1e-3
    assert np.abs(spiral_piece.points[inner, 2] - drawing).max() < 5e-5  # no lift at a joint
    for before, after in zip(path.pieces[:-1], path.pieces[1:], strict=True):
        assert np.array_equal(before.points[-1], after.points[0])


def test_cuts_that_meet_keep_their_retract(dictionary: dict) -> None:
    """A knife must leave its cut: cuts whose ends meet are still one piece each, with the
    lift between them, as are icing lines with a blade-following tool."""
    corner = [cut(0.10, 0.05, 0.15, 0.05), cut(0.15, 0.05, 0.15, 0.10)]
    for kind in ("straight", "sawing"):
        path = compose(corner, dictionary[kind], join_distance=0.002)
        assert [p.kind for p in path.pieces] == ["travel", "work"] * 2 + ["travel"]
        assert path.pieces[2].points[:, 2].max() == pytest.approx(TOP + CLEARANCE)
    lines = [dot_or_line(0.10, 0.05, 0.15, 0.05), dot_or_line(0.15, 0.05, 0.15, 0.10)]
    followed = compose(lines, dictionary["line"], yaw_mode="follow", join_distance=0.002)
    assert len([p for p in followed.pieces if p.kind == "work"]) == 2


def test_a_star_is_piped_round_in_one_stroke_whatever_order_the_plan_gives(
    dictionary: dict,
) -> None:
    """The offline star lists its 5 lines tip to every second tip, not end to start; a VLM may
    give any order and direction. The stroke visits each line once and closes on itself."""
    from keymps.designs.patterns import star

    lines = star((0.15, 0.09), 0.04, 5)
    rng = np.random.default_rng(5)
    for _ in range(20):
        order = rng.permutation(5)
        flips = rng.random(5) < 0.5
        segments = [
            dot_or_line(*(lines[k][::-1] if f else lines[k]).ravel())
            for k, f in zip(order, flips, strict=True)
        ]
        path = compose(segments, dictionary["line"], yaw_mode="fixed", join_distance=0.002)
        (work,) = [p for p in path.pieces if p.kind == "work"]
        assert sorted(work.pairs) == list(range(5)) and work.pair_index == work.pairs[0]
        assert np.linalg.norm(work.points[0] - work.points[-1]) < 1e-5
        tips = np.array([t[0] for t in lines])
        for tip in tips:  # every tip is reached exactly
            assert np.abs(work.points[:, :2] - tip).sum(axis=1).min() < 1e-12
