"""Suite files load, every ground truth renders where the sentence says, the equal-parts check."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from keymps.config.task import Task
from keymps.eval.parts import check_equal_parts, split_areas
from keymps.eval.suites import SuiteError, load_suite, parse_suite
from keymps.eval.tasks import case_scene, case_task_data
from keymps.eval.truth import case_truth, line_hits

SUITES = Path(__file__).resolve().parents[2] / "benchmarks" / "suites"


@pytest.mark.parametrize(
    "name, kind, count", [("cutting_sim", "metric", 15), ("icing", "gallery", 8),
                          ("cake_six", "equal_parts", 2), ("real_cutting", "metric", 10),
                          ("multi_object", "metric", 6)],
)  # fmt: skip
def test_shipped_suites_load(name: str, kind: str, count: int) -> None:
    suite = load_suite(SUITES / f"{name}.yaml")
    assert (suite.name, suite.kind, len(suite.cases)) == (name, kind, count)
    for case in suite.cases:  # every case is a valid task
        Task.model_validate(case_task_data(suite, case, case.scene.seed))


def test_a_suite_by_name() -> None:
    assert load_suite("cake_six").parts == 6


def test_cutting_sim_matches_table_one() -> None:
    suite = load_suite("cutting_sim")
    assert suite.board == (0.30, 0.18)
    assert suite.case("4").instruction == "Cut it into 8 equal slices"
    assert suite.case("11").instruction == "Slice both tips of the object"
    lengths = {c.id: c.instruction.split()[3] for c in suite.cases if "cm long" in c.instruction}
    assert lengths == {"5": "10", "6": "15", "7": "20", "8": "25", "9": "30", "12": "35",
                       "13": "40", "14": "40", "15": "45"}  # fmt: skip
    for case_id, length in lengths.items():  # L / 5 cm equal slices
        cuts = suite.case(case_id).ground_truth.cuts  # type: ignore[union-attr]
        assert cuts.parts == int(length) // 5


def _object(truth) -> dict:
    return truth.scene["objects"][0]


def test_every_ground_truth_renders_on_its_object() -> None:
    for name in ("cutting_sim", "real_cutting"):
        suite = load_suite(name)
        for case in suite.cases:
            truth = case_truth(suite, case, case.scene.seed)
            if case.ground_truth is None:
                assert truth.pieces == ()
                continue
            outline = np.asarray(_object(truth)["outline_m"])
            assert len(truth.pieces) == len(truth.lines_m) >= 1, case.id
            for (start, goal), piece in zip(truth.lines_m, truth.pieces, strict=True):
                # each 3D piece runs from its line's start (above the top) to its goal (board)
                assert np.allclose(piece[0, :2], start, atol=1e-6)
                assert np.allclose(piece[-1, :2], goal, atol=1e-6)
                height = _object(truth)["height_m"]
                assert piece[0, 2] == pytest.approx(height + 0.005)
                assert piece[-1, 2] == pytest.approx(0.0, abs=1e-6)
                # and crosses the object: its midpoint lies inside the outline's box
                mid = (start + goal) / 2
                assert (outline.min(axis=0) <= mid).all() and (mid <= outline.max(axis=0)).all()


def test_eggplant_slices_divide_the_body_equally() -> None:
    """Across the eggplant's own long axis, at quarters of its purple body: from its blossom end
    to where its green cap begins (the sidecar's body_m), the cap and stem left out."""
    suite = load_suite("cutting_sim")
    case = suite.case("7")  # 20 cm, 5 cm slices: 3 vertical cuts at the quarters
    truth = case_truth(suite, case, case.scene.seed)
    scene_object = _object(truth)
    outline = np.asarray(scene_object["outline_m"])
    angle = math.radians(math.remainder(scene_object["rotation_deg"], 180.0))
    axis = np.array([math.cos(angle), math.sin(angle)])
    body = np.sort(np.asarray(scene_object["body_m"]) @ axis)
    assert body[0] == pytest.approx((outline @ axis).min(), abs=0.001)  # the blossom end
    assert (body[1] - body[0]) / scene_object["length_m"] == pytest.approx(0.73, abs=0.01)
    positions = truth.lines_m[:, 0] @ axis
    assert np.allclose(positions, body[0] + (body[1] - body[0]) * np.array([0.25, 0.5, 0.75]))
    directions = truth.lines_m[:, 1] - truth.lines_m[:, 0]
    assert np.abs(directions @ axis).max() < 1e-9  # across its own axis
    assert (truth.lines_m[:, 0, 1] > truth.lines_m[:, 1, 1]).all()  # from the top down
    for start, goal in truth.lines_m:  # 5 mm past both edges of the object
        hits = line_hits(outline, start, (goal - start) / np.linalg.norm(goal - start))
        assert hits[0] == pytest.approx(0.005, abs=1e-9)
        assert np.linalg.norm(goal - start) - hits[-1] == pytest.approx(0.005, abs=1e-9)


def test_radial_ground_truth_is_equal_angles_through_the_centre() -> None:
    suite = load_suite("cutting_sim")
    case = suite.case("3")  # 10 people: 5 diameters at 36 degrees
    truth = case_truth(suite, case, case.scene.seed)
    centre = np.asarray(_object(truth)["centre_m"])
    directions = truth.lines_m[:, 1] - truth.lines_m[:, 0]
    angles = np.degrees(np.arctan2(directions[:, 1], directions[:, 0]))
    assert np.allclose(np.diff(angles), 36.0, atol=1e-9)
    assert angles[0] == pytest.approx(-90.0)
    for start, goal in truth.lines_m:  # the centre lies on every cut
        t = np.dot(centre - start, goal - start) / np.dot(goal - start, goal - start)
        assert np.linalg.norm(start + t * (goal - start) - centre) < 1e-9


def test_tips_and_spacing_ground_truth() -> None:
    suite = load_suite("cutting_sim")
    truth = case_truth(suite, suite.case("11"), 1100)
    outline = np.asarray(_object(truth)["outline_m"])
    angle = math.radians(_object(truth)["rotation_deg"])
    axis = np.array([math.cos(angle), math.sin(angle)])
    low = (outline @ axis).min()
    cap_base = (np.asarray(_object(truth)["body_m"]) @ axis).max()
    positions = truth.lines_m[:, 0] @ axis
    # the blossom end 1.5 cm in; the cap off at its base, 2 mm into the body
    assert positions == pytest.approx([low + 0.015, cap_base - 0.002], abs=1e-9)
    real = load_suite("real_cutting")
    truth = case_truth(real, real.case("7"), 7)  # meat loaf: 4 slices of 2 cm from the left
    assert len(truth.lines_m) == 4
    outline = np.asarray(_object(truth)["outline_m"])
    angle = math.radians(_object(truth)["rotation_deg"])
    axis = np.array([math.cos(angle), math.sin(angle)])
    offsets = truth.lines_m[:, 0] @ axis - (outline @ axis).min()
    assert offsets == pytest.approx([0.02, 0.04, 0.06, 0.08], abs=1e-9)


def test_scenes_are_randomized_by_the_seed_and_reproducible() -> None:
    suite = load_suite("cutting_sim")
    case = suite.case("7")
    a, b, again = (
        case_scene(suite, case, 700),
        case_scene(suite, case, 701),
        case_scene(suite, case, 700),
    )
    assert a == again
    assert a.length != b.length and abs(a.length / 0.20 - 1) <= 0.04
    assert case_truth(suite, case, 700).scene == case_truth(suite, case, 700).scene


# --------------------------------------------------------------------------- bad suite files

GOOD = """\
name: tiny
primitives: [straight]
cases:
  - id: a
    object: round_cake
    instruction: Cut it into 4 equal parts
    ground_truth:
      primitive: straight
      cuts: {pattern: radial, parts: 4}
"""


def test_a_minimal_suite_parses() -> None:
    suite = parse_suite(GOOD, "tiny.yaml")
    assert suite.cases[0].ground_truth.cuts.parts == 4  # type: ignore[union-attr]


@pytest.mark.parametrize(
    "text, expected",
    [
        (GOOD.replace("round_cake", "wedding_cake"), "tiny.yaml:5:13: cases[0].object: "),
        (GOOD.replace("parts: 4", "parts: 1"), "tiny.yaml:9:38: cases[0].ground_truth.cuts.parts"),
        (GOOD.replace("radial", "zigzag"), "tiny.yaml:9:13: cases[0].ground_truth.cuts"),
        (GOOD + "    colour: red\n", "tiny.yaml:10:5: cases[0].colour: unknown key"),
        (GOOD.replace("name: tiny", "name: [tiny"), "tiny.yaml:"),
        (GOOD + "task: {height: {mode: sideways}}\n", "tiny.yaml:10:23: case a: task.height.mode"),
        (GOOD.replace("{pattern: radial, parts: 4}", "{pattern: parallel, along: x}"),
         "give exactly one of parts, fractions, spacing"),
    ],
)  # fmt: skip
def test_bad_suites_name_file_line_column_and_field(text: str, expected: str) -> None:
    with pytest.raises(SuiteError) as raised:
        parse_suite(text, "tiny.yaml")
    message = str(raised.value)
    assert expected in message, message
    assert "Traceback" not in message


def test_unknown_suite_lists_the_shipped_ones(tmp_path: Path) -> None:
    with pytest.raises(SuiteError, match="shipped suites: cake_six, cutting_sim, icing"):
        load_suite(tmp_path / "nope.yaml")


# --------------------------------------------------------------------------- equal parts


def _circle(radius: float = 0.06, n: int = 720) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return radius * np.column_stack([np.cos(a), np.sin(a)])


def _diameters(angles_deg: list[float], radius: float = 0.065) -> np.ndarray:
    cuts = []
    for angle in np.radians(angles_deg):
        d = radius * np.array([np.cos(angle), np.sin(angle)])
        cuts.append([-d, d])
    return np.array(cuts)


def test_three_diameters_make_six_equal_pieces_of_a_round_cake() -> None:
    check = check_equal_parts(_circle(), _diameters([90, 30, -30]), parts=6)
    assert check.ok, check.describe()
    assert len(check.areas_m2) == 6
    assert sum(check.areas_m2) == pytest.approx(np.pi * 0.06**2, rel=0.01)
    assert check.worst_deviation < 0.01


def test_wrong_cut_sets_fail() -> None:
    circle = _circle()
    assert not check_equal_parts(circle, _diameters([90, 0]), 6).ok  # 4 pieces
    uneven = check_equal_parts(circle, _diameters([90, 20, -30]), 6)  # 6 pieces, unequal
    assert len(uneven.areas_m2) == 6 and not uneven.ok
    assert uneven.worst_deviation == pytest.approx(10 / 60, abs=0.01)
    short = _diameters([90, 30, -30])
    short[0] = short[0] * 0.9  # a cut that stops 6 mm inside the edge leaves pieces joined
    assert not check_equal_parts(circle, short, 6).ok


def test_square_cake_grid_and_wedges() -> None:
    square = np.array([[-0.06, -0.06], [0.06, -0.06], [0.06, 0.06], [-0.06, 0.06]])
    grid = np.array(
        [[[-0.02, -0.07], [-0.02, 0.07]], [[0.02, -0.07], [0.02, 0.07]],
         [[-0.07, 0.0], [0.07, 0.0]]]
    )  # fmt: skip
    assert check_equal_parts(square, grid, 6).ok  # a 2 x 3 grid
    rays = np.array([[[0, 0], [0.09 * np.cos(a), 0.09 * np.sin(a)]]
                     for a in np.radians(90 + 60 * np.arange(6))])  # fmt: skip
    wedges = check_equal_parts(square, rays, 6)
    assert len(wedges.areas_m2) == 6 and not wedges.ok  # equal angles are not equal areas


def test_ring_cake_hole_is_not_area() -> None:
    areas, total = split_areas(_circle(0.06), _diameters([90]), hole_m=_circle(0.02))
    assert total == pytest.approx(np.pi * (0.06**2 - 0.02**2), rel=0.01)
    assert len(areas) == 2 and areas[0] == pytest.approx(areas[1], rel=0.01)


def test_jobs_start_heaviest_first_by_their_ground_truths_work() -> None:
    """Sawing cuts weigh about three straight ones (the primitive's path for a straight stroke):
    the sawn baguettes and the banana bread start first, a single straight cut's case last."""
    from keymps.eval.runner import EvalOptions, expected_work, heaviest_first, plan_jobs

    suite = load_suite("cutting_sim")
    work = {case.id: expected_work(suite, case) for case in suite.cases}
    assert 2.5 < (work["15"] - work["14"]) / (work["13"] - work["12"]) < 3.5
    options = EvalOptions(out=Path("unused"), repeats=2, methods=("keymps", "vlm-keypoint"))
    order = heaviest_first(suite, plan_jobs(suite, options))
    assert [job.case_id for job in order[:4]] == ["15"] * 4
    assert {job.case_id for job in order[-4:]} == {"5"}
    assert sorted(order, key=lambda job: job.label) == sorted(
        plan_jobs(suite, options), key=lambda job: job.label
    )
    # one scene's methods stay next to each other (they share its rendering)
    assert [job.method for job in order[:2]] == ["keymps", "vlm-keypoint"]


def test_offline_workers_are_forked_only_from_a_process_without_threads() -> None:
    import subprocess
    import threading

    from keymps.eval.pool import fork_here

    alone = "from keymps.eval.pool import fork_here; print(fork_here('offline'))"
    answer = subprocess.run([sys.executable, "-c", alone], capture_output=True, text=True)
    assert answer.stdout.strip() == str(sys.platform.startswith("linux"))
    assert not fork_here("litellm")
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:
        assert not fork_here("offline")
    finally:
        release.set()
        other.join()


@pytest.mark.parametrize(
    "name", ["cutting_sim", "icing", "cake_six", "real_cutting", "multi_object"]
)
def test_every_suite_detects_with_the_board_detector_like_keymps_run(name: str) -> None:
    """Issue 39: the paper's suites used the threshold detector while keymps run uses board."""
    default = Task(
        name="x", instruction="x", scene={"source": "synthetic"}, primitives=["straight"]
    ).detector.name
    suite = load_suite(name)
    for case in suite.cases:
        assert case_task_data(suite, case, case.scene.seed)["detector"]["name"] == default


def test_table_one_case_5_scores_under_3_mm_in_every_repeat(tmp_path: Path) -> None:
    """Issue 39: case 5 (a 10 cm eggplant, 5 cm slices) scored D 3.2 mm in 2 of 3 repeats (its
    stem and cap counted in the length); every other case was under 2.7 mm."""
    from keymps.eval.runner import EvalOptions, run_suite

    suite = load_suite("cutting_sim")
    records = run_suite(suite, EvalOptions(out=tmp_path, cases=("5", "11"), repeats=3))
    scores = [(r["case"], r["d_mm"]) for r in records]
    assert len(scores) == 6 and all(d is not None and d < 3.0 for _, d in scores), scores
