"""Several objects in one scene (issue 20): detected, described, addressed, grounded, travelled
over, checked and executed each on its own object, for the offline planner and a VLM over HTTP."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.multi_scenes import BOARD, ICING, KNIFE, loaves, scene_file, task_text

from keymps.config.task import parse_task
from keymps.default_plugins.threshold_detector import ThresholdDetector
from keymps.designs.addressing import AddressingError, Target, split_by_object
from keymps.designs.grammar import read_instruction
from keymps.errors import StageError
from keymps.perception.frames import ImageFrame
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene


def run_offline(tmp_path: Path, text: str):
    from keymps import run_task

    path = tmp_path / "task.yaml"
    path.write_text(text)
    from keymps.config.task import load_task

    return run_task(
        load_task(path),
        options=RunOptions(rerun="off", no_cache=True),
        overrides=RunOverrides(out=tmp_path / "run"),
    )


def owner_of(point_m: np.ndarray, truth: dict) -> int | None:
    """1-based index (left to right) of the true object whose outline contains the point."""
    import cv2

    ordered = sorted(truth["objects"], key=lambda o: (o["bbox_m"][0] + o["bbox_m"][2]) / 2)
    for number, obj in enumerate(ordered, start=1):
        outline = np.asarray(obj["outline_m"], np.float32).reshape(-1, 1, 2)
        if cv2.pointPolygonTest(outline, (float(point_m[0]), float(point_m[1])), True) >= -0.002:
            return number
    return None


# --- detection -----------------------------------------------------------------------------


def test_objects_are_numbered_left_to_right_then_top_to_bottom() -> None:
    spots = [(0.28, 0.17), (0.09, 0.07), (0.28, 0.06), (0.09, 0.17)]
    objects = [ObjectSpec("potato", 0.08, 0.055, 0.05, 0.0, centre=c) for c in spots]
    image = render_scene(SceneSpec(tuple(objects), seed=4, board_size=BOARD)).image
    found = ThresholdDetector().detect(image).objects
    frame = ImageFrame.linear((image.shape[1], image.shape[0]), BOARD)
    centres = [
        frame.to_board(
            np.array([[(o.bbox_px[0] + o.bbox_px[2]) / 2, (o.bbox_px[1] + o.bbox_px[3]) / 2]])
        )[0]
        for o in found
    ]
    # ids 1, 2 on the left (top first: larger board y), then 3, 4 on the right
    assert [o.id for o in found] == [1, 2, 3, 4]
    expected = [spots[3], spots[1], spots[0], spots[2]]
    assert np.allclose(centres, expected, atol=0.003)


# --- task files ------------------------------------------------------------------------------


def test_declared_objects_match_left_to_right_and_at_pins_one(tmp_path: Path) -> None:
    from keymps.perception.scene_objects import scene_objects

    png, _ = scene_file(tmp_path, [
        ObjectSpec("banana", 0.18, 0.036, 0.035, 90, centre=(0.10, 0.12)),
        ObjectSpec("cucumber", 0.2, 0.032, 0.032, 90, centre=(0.27, 0.12)),
    ])  # fmt: skip
    detection = ThresholdDetector().detect(__import__("cv2").imread(str(png)))
    in_order = parse_task(task_text(png, "x", KNIFE, (
        "  objects: [{name: banana, height: 0.035}, {name: cucumber, height: 0.04}]\n"
    )))  # fmt: skip
    named = scene_objects(detection, in_order, ImageFrame.from_task(in_order, (760, 480)))
    assert [(o.id, o.name, o.height) for o in named] == [
        (1, "banana", 0.035),
        (2, "cucumber", 0.04),
    ]
    pinned = parse_task(task_text(png, "x", KNIFE, (
        "  object_height: 0.03\n  objects: [{name: cucumber, at: [0.27, 0.1]}, {name: banana}]\n"
    )))  # fmt: skip
    named = scene_objects(detection, pinned, ImageFrame.from_task(pinned, (760, 480)))
    assert [(o.id, o.name, o.height) for o in named] == [(1, "banana", 0.03), (2, "cucumber", 0.03)]


def test_a_count_mismatch_names_both_counts_at_the_objects_line(tmp_path: Path) -> None:
    png, _ = scene_file(tmp_path, loaves(1))
    text = task_text(png, "Cut each of them in half", KNIFE, "  objects:\n    - {name: loaf}\n")
    path = tmp_path / "task.yaml"
    path.write_text(text)
    with pytest.raises(StageError) as caught:
        run_offline(tmp_path, text)
    message = str(caught.value)
    assert message.startswith("detect: ") and "task.yaml:7:5: scene.objects:" in message
    assert "describes 1 object(s) but the detector found 2" in message
    assert not (tmp_path / "run" / "trajectory.csv").exists()


def test_declared_objects_are_validated_where_they_are_written(tmp_path: Path) -> None:
    from keymps.errors import TaskFileError

    png, _ = scene_file(tmp_path, loaves(1))
    bad = task_text(png, "x", KNIFE, "  objects:\n    - {name: loaf, height: 40}\n")
    with pytest.raises(TaskFileError, match=r"<task>:7:\d+: scene.objects\[0\].height"):
        parse_task(bad)


# --- addressing ------------------------------------------------------------------------------


def random_targets(
    rng: np.random.Generator, count: int, names: list[str] | None = None
) -> list[Target]:
    """`count` objects in a row, left to right with random gaps, sizes and vertical offsets."""
    x = 20.0
    targets = []
    for index in range(count):
        width, height = rng.uniform(40, 160), rng.uniform(40, 200)
        x += rng.uniform(10, 60) + width / 2
        targets.append(
            Target(
                index + 1,
                names[index] if names else None,
                (x, rng.uniform(150, 250)),
                (width, height),
                width * height * rng.uniform(0.7, 0.95),
            )
        )
        x += width / 2
    return targets


@pytest.mark.parametrize("seed", range(40))
def test_addressing_phrases_pick_the_objects_geometry_says(seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = int(rng.integers(2, 5))
    targets = random_targets(rng, count)
    ids = tuple(t.id for t in targets)
    largest = max(targets, key=lambda t: t.area).id
    smallest = min(targets, key=lambda t: t.area).id
    cases = {
        "Cut each of them into 3 pieces": [ids],
        "cut all of them in half": [ids],
        "Cut every one into four slices": [ids],
        "cut them into 5": [ids],
        "Cut only the left one into 4": [(1,)],
        "cut the rightmost one in half": [(count,)],
        "Cut the one on the right into 6 equal slices": [(count,)],
        f"Cut object {count} in half": [(count,)],
        "cut the left one in half and the right one into 4": [(1,), (count,)],
        "Cut the left one in half, then the other ones into 3": [(1,), ids[1:]],
    }
    areas = sorted(t.area for t in targets)
    if areas[-1] > 1.05 * areas[-2]:
        cases["cut the largest one into 8 slices"] = [(largest,)]
    if areas[1] > 1.05 * areas[0]:
        cases["Cut the smallest one in half"] = [(smallest,)]
    for sentence, expected in cases.items():
        clauses = split_by_object(sentence, targets)
        assert [c.objects for c in clauses] == expected, sentence
        for clause in clauses:
            read_instruction(clause.text)  # every clause is a design the grammar reads


def test_clauses_carry_their_own_design_and_borrow_what_they_leave_out() -> None:
    targets = random_targets(np.random.default_rng(7), 2, ["banana", "cucumber"])
    first, second = split_by_object(
        "Cut the banana in half and the cucumber into 5 pieces", targets
    )
    assert first.objects == (1,) and read_instruction(first.text).count == 2
    assert second.objects == (2,) and read_instruction(second.text).count == 5
    (both,) = split_by_object(
        "Ice both cakes with 9 dots", random_targets(np.random.default_rng(1), 2)
    )
    intent = read_instruction(both.text)
    assert both.objects == (1, 2) and (intent.design, intent.count) == ("dots_ring", 9)
    (tips,) = split_by_object("Cut both tips of each of them", targets)
    assert tips.objects == (1, 2) and read_instruction(tips.text).design == "tips"
    (bananas,) = split_by_object("Cut both tips of each banana", targets)
    assert bananas.objects == (1,)
    (slices,) = split_by_object(
        "Put 1 dot of icing on the middle of each of the 10 slices of the left one", targets
    )
    assert slices.objects == (1,) and read_instruction(slices.text).design == "dot_per_slice"


@pytest.mark.parametrize(
    ("sentence", "words"),
    [
        ("Cut it into 3 pieces", "does not say which"),
        ("Cut object 5 in half", "there is no object 5"),
        ("Cut the middle one in half", "none in the middle"),
    ],
)
def test_unclear_addressing_is_refused_with_what_to_say(sentence: str, words: str) -> None:
    targets = random_targets(np.random.default_rng(3), 2)
    targets = [Target(t.id, t.name, t.centre, t.size, 1000.0) for t in targets]
    with pytest.raises(AddressingError, match=words):
        split_by_object(sentence, targets)


def test_an_unaddressed_sentence_goes_to_the_one_big_object_beside_crumbs() -> None:
    big = Target(1, None, (100, 100), (120, 120), 12000.0)
    crumb = Target(2, None, (300, 100), (20, 20), 300.0)
    (clause,) = split_by_object("Cut it into 8 equal slices", [big, crumb])
    assert clause.objects == (1,) and clause.text == "Cut it into 8 equal slices"


def test_the_left_one_is_ambiguous_when_the_objects_stand_one_above_the_other() -> None:
    upper = Target(1, None, (100, 50), (120, 60), 7000.0)
    lower = Target(2, None, (104, 200), (120, 60), 7000.0)
    with pytest.raises(AddressingError, match="about as far left"):
        split_by_object("cut the left one in half", [upper, lower])
    (clause,) = split_by_object("cut the top one in half", [upper, lower])
    assert clause.objects == (1,)


def test_two_objects_one_above_the_other_are_the_top_and_the_bottom_one() -> None:
    """Issue 39: two bananas lying one above the other were listed as '#1 (left), #2 (left)'
    and the refusal suggested 'the left one'."""
    upper = Target(1, "banana", (380, 100), (340, 80), 20000.0)
    lower = Target(2, "banana", (380, 300), (340, 80), 19500.0)
    with pytest.raises(AddressingError) as error:
        split_by_object("Cut it in half", [upper, lower])
    message = str(error.value)
    assert "(#1 banana (top), #2 banana (bottom))" in message and "'the top one'" in message
    column = [Target(i, None, (200, 100 * i), (300, 60), 9000.0) for i in (1, 2, 3)]
    with pytest.raises(AddressingError, match=r"#1 \(topmost\), #2 \(2\. from the top\)"):
        split_by_object("Cut it in half", column)


@pytest.mark.parametrize(
    ("names", "sentence", "words"),
    [
        (("banana", "banana bread"), "cut the cucumber in half", "there is no cucumber in the"),
        (("banana", "banana bread"), "cut the banana and the cucumbers", "no cucumber"),
        (("banana",), "Cut the cucumber into 4 pieces", "there is no cucumber in the scene"),
        (("eggplant", "banana"), "cut the aubergine in half", None),
        (("banana bread", "banana"), "cut the bread in half", None),
        ((None, None), "cut the cucumber in half", "or name them in scene.objects"),
    ],
)
def test_a_food_the_scene_has_not_is_named_as_missing(
    names: tuple[str | None, ...], sentence: str, words: str | None
) -> None:
    """Issue 39: 'cut the cucumber' with no cucumber said the sentence 'does not say which'."""
    targets = [
        Target(i, name, (150.0 + 300 * i, 200.0), (200, 80), 12000.0 - i)
        for i, name in enumerate(names, start=1)
    ]
    if words is None:
        assert split_by_object(sentence, targets)[0].objects == (1,)
        return
    with pytest.raises(AddressingError, match=words):
        split_by_object(sentence, targets)


def test_a_run_cutting_both_objects_warns_about_neither(tmp_path: Path) -> None:
    """Issue 39: every run with two objects warned 'the one in box [...] is used, not the one
    in box [...]', even when both were cut. The board detector keeps both (detector.pick keeps
    one); the plan cuts both, and nothing is warned about them."""
    png, _ = scene_file(tmp_path, [
        ObjectSpec("banana", 0.18, 0.036, 0.035, 0.0, centre=(0.19, 0.17)),
        ObjectSpec("banana", 0.17, 0.036, 0.035, 0.0, centre=(0.19, 0.07)),
    ])  # fmt: skip
    text = task_text(png, "Cut each of them in half", KNIFE).replace(
        "planner:", "detector: {name: board}\nplanner:"
    )
    run = run_offline(tmp_path, text)
    record = json.loads((run.folder / "run.json").read_text())
    assert record["ok"] and sorted(set(record["pair_objects"])) == [1, 2]
    assert not [w for w in run.warnings if "comparable" in w or "is used, not" in w], run.warnings


# --- end to end, offline ---------------------------------------------------------------------


SENTENCES = [
    ("Cut each of them into {n} pieces", lambda n, k: {i: n - 1 for i in range(1, k + 1)}),
    ("Cut only the left one into {n}", lambda n, k: {1: n - 1}),
    ("Cut the right one into {n} equal slices", lambda n, k: {k: n - 1}),
    ("Cut the left one in half and the right one into {n}", lambda n, k: {1: 1, k: n - 1}),
]


@pytest.mark.parametrize("seed", range(6))
def test_offline_plans_put_the_right_design_on_the_right_object(tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = 2 + seed % 3
    n = int(rng.integers(2, 6))
    template, expected_of = SENTENCES[seed % len(SENTENCES)]
    png, truth = scene_file(tmp_path, loaves(seed, count), seed=seed)
    run = run_offline(tmp_path, task_text(png, template.format(n=n), KNIFE))
    record = json.loads((run.folder / "run.json").read_text())
    assert record["ok"] and record["validation"]["verdict"] == "pass", record["error"]
    assert [o["id"] for o in record["detection"]["objects"]] == list(range(1, count + 1))
    expected = expected_of(n, count)
    owners = record["pair_objects"]
    assert {i: owners.count(i) for i in set(owners)} == expected
    # every cut crosses the middle of the object the plan says, on the true outline
    for owner, segment in zip(owners, record["segments_m"], strict=True):
        middle = (np.array(segment[0][:2]) + np.array(segment[1][:2])) / 2
        assert owner_of(middle, truth) == owner
    assert run.stages.execute.figures["cuts"] == sum(expected.values())


def test_each_pair_takes_its_objects_height_and_travel_clears_the_tallest(tmp_path: Path) -> None:
    low, tall = 0.03, 0.09
    objects = loaves(2, 3)
    png, _ = scene_file(tmp_path, objects)
    heights = f"  objects: [{{name: a, height: {low}}}, {{name: b, height: {tall}}}, {{name: c, height: {low}}}]\n"
    run = run_offline(
        tmp_path,
        task_text(png, "Cut the left one in half and the right one in half", KNIFE, heights),
    )
    grounding = run.stages.ground
    assert [s.object_id for s in grounding.segments] in ([1, 3], [3, 1])
    assert all(s.start[2] == pytest.approx(low + 0.005) for s in grounding.segments)
    travel = [p for p in run.stages.compose.pieces if p.kind == "travel"]
    between = travel[1]  # from the first loaf over the tall middle one to the last
    assert between.points[:, 2].max() == pytest.approx(tall + 0.03, abs=1e-9)


@pytest.mark.parametrize("in_the_way", [False, True])
def test_a_travel_move_rises_only_for_the_objects_under_it(in_the_way: bool) -> None:
    from keymps.motion.compose import compose_tool_path
    from keymps.primitives.dictionary import BUNDLED_DIR, load_primitives
    from keymps.types import GroundedObject, Segment

    def square(cx: float, cy: float, half: float = 0.02) -> np.ndarray:
        return np.array(
            [
                [cx - half, cy - half],
                [cx + half, cy - half],
                [cx + half, cy + half],
                [cx - half, cy + half],
            ]
        )

    tall_y = 0.10 if in_the_way else 0.20
    objects = (
        GroundedObject(1, None, 0.02, square(0.05, 0.10)),
        GroundedObject(2, None, 0.12, square(0.15, tall_y)),
        GroundedObject(3, None, 0.03, square(0.25, 0.10)),
    )
    segments = [
        Segment(np.array([x, 0.10, 0.025]), np.array([x, 0.10, 0.0]), (0, 0), (0, 0), owner)
        for x, owner in ((0.05, 1), (0.25, 3))
    ]
    primitive = load_primitives(["straight"], [BUNDLED_DIR])["straight"]
    path = compose_tool_path(
        segments, primitive, object_top=0.12, clearance=0.03, work_speed=0.03,
        travel_speed=0.15, yaw_mode="fixed", home=np.array([0.15, 0.0, 0.25]), objects=objects,
    )  # fmt: skip
    between = path.pieces[2]
    assert between.kind == "travel" and between.object_id == 3
    expected = 0.12 + 0.03 if in_the_way else 0.03 + 0.03
    assert between.points[:, 2].max() == pytest.approx(expected)


def test_icing_both_cakes_puts_n_dots_on_each(tmp_path: Path) -> None:
    cakes = [ObjectSpec("round_cake", 0.12, 0.12, 0.06, 0.0, centre=(x, 0.12)) for x in (0.1, 0.28)]
    png, truth = scene_file(tmp_path, cakes, seed=5)
    run = run_offline(tmp_path, task_text(png, "Ice both cakes with 7 dots", ICING))
    plan = run.stages.plan
    assert sorted(plan.pair_objects) == [1] * 7 + [2] * 7
    for owner, segment in zip(plan.pair_objects, run.stages.ground.segments_m, strict=True):
        assert owner_of(segment[0, :2], truth) == owner
    assert run.stages.execute.figures["icing_dots"] == 14
    assert (run.folder / "outcome.png").is_file()


def test_named_objects_take_their_designs(tmp_path: Path) -> None:
    png, truth = scene_file(tmp_path, [
        ObjectSpec("banana", 0.18, 0.036, 0.035, 90, centre=(0.10, 0.12)),
        ObjectSpec("cucumber", 0.2, 0.032, 0.032, 90, centre=(0.27, 0.12)),
    ])  # fmt: skip
    declared = "  objects: [{name: banana, height: 0.035}, {name: cucumber, height: 0.032}]\n"
    run = run_offline(
        tmp_path,
        task_text(png, "Cut the cucumber into 5 pieces and the banana in half", KNIFE, declared),
    )
    plan = run.stages.plan
    assert sorted(plan.pair_objects) == [1, 2, 2, 2, 2]
    heights = {s.object_id: s.start[2] for s in run.stages.ground.segments}
    assert heights == {1: pytest.approx(0.04), 2: pytest.approx(0.037)}


# --- safety ----------------------------------------------------------------------------------


def test_work_on_the_wrong_object_fails_even_inside_the_union(tmp_path: Path) -> None:
    from dataclasses import replace

    from keymps.robot.safety import SafetyError, validate

    png, _ = scene_file(tmp_path, loaves(3))
    run = run_offline(
        tmp_path, task_text(png, "Cut the left one in half and the right one in half", KNIFE)
    )
    tool_path, grounding = run.stages.compose, run.stages.ground
    # the same motion, with the pieces' objects swapped: each cut is now on the other's object
    swapped = replace(
        tool_path,
        pieces=tuple(replace(p, object_id=3 - p.object_id) for p in tool_path.pieces),
    )
    from keymps.robot.model import RobotModel

    robot = RobotModel.from_task(run.task)
    with pytest.raises(SafetyError, match=r"work leaves object #\d's footprint"):
        validate(robot, run.stages.time, swapped, grounding.objects, run.task)
    union = np.concatenate([o.outline_m for o in grounding.objects])
    assert validate(robot, run.stages.time, tool_path, grounding.objects, run.task).report.ok
    assert union.shape[1] == 2


# --- the benchmark suite ---------------------------------------------------------------------


def test_the_multi_object_suite_scores_each_object(tmp_path: Path) -> None:
    from keymps.eval.runner import EvalOptions, run_suite
    from keymps.eval.suites import load_suite

    suite = load_suite("multi_object")
    cases = ("loaves-and-cucumber", "cakes-dots")
    records = run_suite(suite, EvalOptions(out=tmp_path, repeats=1, cases=cases))
    by_case = {r["case"]: r for r in records}
    assert set(by_case) == set(cases) and all(r["ok"] for r in records)
    middle_untouched = by_case["loaves-and-cucumber"]
    assert middle_untouched["truth_pieces_per_object"] == [1, 0, 3]
    assert middle_untouched["pieces_per_object"] == [1, 0, 3] and middle_untouched["right_objects"]
    d_left, d_middle, d_right = middle_untouched["d_objects_mm"]
    assert d_middle is None and 0 < d_left < 3 and 0 < d_right < 3
    dots = by_case["cakes-dots"]
    assert dots["pieces_per_object"] == [8, 8] and all(0 < d < 3 for d in dots["d_objects_mm"])


def test_ground_truths_need_one_entry_per_object() -> None:
    from keymps.eval.suites import SuiteError, parse_suite

    text = (
        "name: s\nprimitives: [straight]\ncases:\n  - id: a\n    object: [banana, cucumber]\n"
        "    instruction: cut each of them in half\n    ground_truths:\n"
        "      - {primitive: straight, cuts: {pattern: parallel, along: long, parts: 2}}\n"
    )
    with pytest.raises(
        SuiteError, match=r"<suite>:4:\d+: cases\[0\].* ground_truths has 1 entries for 2 objects"
    ):
        parse_suite(text)


def test_the_rerun_recording_has_one_entity_per_object(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from keymps import run_task
    from keymps.config.task import load_task

    png, _ = scene_file(tmp_path, loaves(6, 3), seed=6)
    path = tmp_path / "task.yaml"
    path.write_text(task_text(png, "Cut each of them in half", KNIFE))
    run = run_task(
        load_task(path),
        options=RunOptions(rerun="save", no_cache=True),
        overrides=RunOverrides(out=tmp_path / "run"),
    )
    paths = {chunk.entity_path for chunk in RrdReader(run.folder / "run.rrd").stream()}
    assert {"/world/objects/1", "/world/objects/2", "/world/objects/3"} <= paths
    assert "/world/objects/4" not in paths


def test_a_declared_hard_object_gets_the_hard_objects_cut_however_it_is_addressed(
    tmp_path: Path,
) -> None:
    """scene.objects names a potato: "the left one" is a potato's cut (sawing) exactly as
    "the potato" is; it was a soft object's straight cut unless the sentence said potato."""
    import keymps

    png, _ = scene_file(tmp_path, [
        ObjectSpec("potato", 0.09, 0.065, 0.05, 0, centre=(0.09, 0.12)),
        ObjectSpec("banana", 0.18, 0.036, 0.035, 90, centre=(0.27, 0.12)),
    ])  # fmt: skip
    objects = "  objects: [{name: potato, height: 0.05}, {name: banana, height: 0.035}]\n"
    keywords = {}
    for sentence in ("Cut only the left one in half", "Cut the potato in half"):
        path = tmp_path / f"{len(keywords)}.yaml"
        path.write_text(task_text(png, sentence, KNIFE, objects))
        run = keymps.run_task(
            path,
            options=RunOptions(rerun="off", quiet=True),
            overrides=RunOverrides(out=tmp_path / f"run{len(keywords)}"),
        )
        assert run.stages.plan is not None
        keywords[sentence] = run.stages.plan.keyword
    assert set(keywords.values()) == {"sawing"}, keywords
