"""The offline planner's designs for the KeyMPs paper's cases, checked geometrically."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.synthetic_crops import (
    BOARD_BGR,
    CUTTING,
    ICING,
    MM_PER_PX,
    distance_point_to_line,
    make_scene,
    piece_areas,
    plan_for,
    segment_angle,
)

from keymps.errors import KeympsError


def _sorted_x(plan) -> np.ndarray:
    return np.sort(plan.pairs_px[:, :, 0].mean(axis=1))


def _assert_spans(plan, scene, axis: int | None = None) -> None:
    """Every cut crosses the whole object: each end lies just beyond the object's edge."""
    board = np.array(BOARD_BGR)
    on_object = np.abs(scene.scene.image.astype(int) - board).max(axis=2) > 30

    def inside(point) -> bool:
        x, y = (int(round(v)) for v in point)
        return bool(on_object[y, x])

    for start, end in plan.pairs_px:
        direction = (end - start) / np.linalg.norm(end - start)
        for tip, outwards in ((start, -direction), (end, direction)):
            assert not inside(tip + outwards), "the cut stops inside the object"
            assert inside(tip - 4 * outwards), "the cut ends far outside the object"


# --- Table I (cutting) -----------------------------------------------------------------------


def test_case1_single_horizontal_slice_in_the_middle():
    scene = make_scene("disk", (160, 160))
    plan, _ = plan_for("A single horizontal slice in the middle", scene, name="cabbage")
    assert plan.num_pairs == 1
    ((start, end),) = plan.pairs_px
    assert abs(start[1] - end[1]) < 1e-6  # horizontal
    assert abs(start[1] - scene.centre_px[1]) * MM_PER_PX < 1.0
    _assert_spans(plan, scene, axis=0)
    assert plan.keyword == "sawing"  # cabbage is hard


def test_case2_one_slice_for_each_day_of_the_week_vertically():
    scene = make_scene("rect", (210, 90))
    plan, _ = plan_for(
        "I want to eat 1 slice for each day of this week, cut it vertically",
        scene,
        name="banana-bread",
    )
    assert plan.num_pairs == 6
    xs = _sorted_x(plan) * MM_PER_PX
    assert np.allclose(np.diff(xs), 30.0, atol=1.0)
    for pair in plan.pairs_px:
        assert segment_angle(pair) == pytest.approx(90.0, abs=1e-6)
    _assert_spans(plan, scene, axis=1)
    assert plan.keyword == "sawing"  # bread


@pytest.mark.parametrize(
    ("sentence", "parts"),
    [
        ("I'm having a party for 10 people, cut 1 slice for each", 10),
        ("Cut it into 8 equal slices", 8),
        ("cut the cake into six equal parts", 6),
        ("Split it into 4", 4),
        ("I want to eat this chiffon cake for each day this week", 7),
    ],
)
def test_round_objects_are_cut_into_equal_wedges(sentence, parts):
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for(sentence, scene)
    centre = np.array(scene.centre_px)
    cuts = parts // 2 if parts % 2 == 0 else parts
    assert plan.num_pairs == cuts
    for pair in plan.pairs_px:
        assert distance_point_to_line(centre, pair) * MM_PER_PX < 1.0
    if parts % 2 == 0:
        _assert_spans(plan, scene)
        angles = sorted(segment_angle(p) for p in plan.pairs_px)
        gaps = np.diff(angles + [angles[0] + 180.0])
        assert np.allclose(gaps, 360.0 / parts, atol=0.01)
    else:
        directions = [math.degrees(math.atan2(*(p[1] - p[0])[::-1])) % 360 for p in plan.pairs_px]
        gaps = np.diff(sorted(directions) + [sorted(directions)[0] + 360])
        assert np.allclose(gaps, 360.0 / parts, atol=0.01)
    areas = piece_areas(scene, plan)
    assert len(areas) == parts
    assert max(areas) / min(areas) < 1.03
    assert plan.keyword == "straight"


@pytest.mark.parametrize(
    ("length_cm", "name"),
    [
        (10, "eggplant"),
        (15, "eggplant"),
        (20, "eggplant"),
        (25, "eggplant"),
        (30, "eggplant"),
        (35, "eggplant"),
        (40, "eggplant"),
        (40, "baguette"),
        (45, "baguette"),
    ],
)
def test_cases_5_to_15_fixed_width_slices(length_cm, name):
    scene = make_scene("ellipse", (length_cm * 10, 60 if name == "eggplant" else 70))
    plan, _ = plan_for(
        f"The object is {length_cm} cm long, cut it vertically into 5 cm slices", scene, name=name
    )
    assert plan.num_pairs == length_cm // 5 - 1
    xs = _sorted_x(plan) * MM_PER_PX
    left_tip = scene.detection.bbox_px[0] * MM_PER_PX
    expected = left_tip + 50.0 * np.arange(1, length_cm // 5)
    assert np.allclose(xs, expected, atol=1.0)
    _assert_spans(plan, scene, axis=1)
    assert plan.keyword == ("sawing" if name == "baguette" else "straight")


def test_case10_three_parts_horizontally():
    scene = make_scene("disk", (150, 150))
    plan, _ = plan_for("Slice the object into 3 parts horizontally", scene)
    assert plan.num_pairs == 2
    ys = np.sort(plan.pairs_px[:, :, 1].mean(axis=1)) * MM_PER_PX
    top = scene.detection.bbox_px[1] * MM_PER_PX
    assert np.allclose(ys, top + np.array([50.0, 100.0]), atol=1.0)
    _assert_spans(plan, scene, axis=0)


def test_case11_both_tips():
    scene = make_scene("ellipse", (250, 60))
    plan, _ = plan_for("Slice both tips of the object", scene)
    assert plan.num_pairs == 2
    x0, _, x1, _ = scene.detection.bbox_px
    xs = _sorted_x(plan)
    inset_left, inset_right = (xs[0] - x0) * MM_PER_PX, (x1 - xs[1]) * MM_PER_PX
    assert inset_left == pytest.approx(inset_right, abs=1.0)
    assert 5.0 <= inset_left <= 30.0


# --- Appendix F and Table V ------------------------------------------------------------------


def test_square_cake_six_equal_parts():
    scene = make_scene("rect", (180, 180))
    plan, _ = plan_for("Cut the cake into six equal parts", scene)
    areas = piece_areas(scene, plan)
    assert len(areas) == 6
    assert max(areas) / min(areas) < 1.03


def test_split_into_4_elongated_gives_three_parallel_cuts():
    scene = make_scene("ellipse", (240, 100))
    plan, _ = plan_for("Split it into 4", scene, name="baumkuchen")
    assert plan.num_pairs == 3
    assert np.allclose(np.diff(_sorted_x(plan)) * MM_PER_PX, 60.0, atol=1.0)


def test_meat_loaf_four_2cm_slices():
    scene = make_scene("rect", (160, 80))
    plan, _ = plan_for("(length 16cm, width 8cm). Cut me 4 2cm slices", scene, name="meat-loaf")
    assert plan.num_pairs == 4
    left = scene.detection.bbox_px[0] * MM_PER_PX
    assert np.allclose(_sorted_x(plan) * MM_PER_PX, left + np.array([20, 40, 60, 80]), atol=1.0)


def test_a_rotated_loaf_is_sliced_across_its_long_axis():
    scene = make_scene("rect", (200, 70), angle_deg=30)
    plan, _ = plan_for("Cut it into 5 equal slices", scene)
    assert plan.num_pairs == 4
    for pair in plan.pairs_px:
        assert segment_angle(pair) == pytest.approx(120.0, abs=2.0)


# --- Table IV (icing) ------------------------------------------------------------------------


def _radii(points: np.ndarray, centre) -> np.ndarray:
    return np.linalg.norm(points - np.asarray(centre), axis=1) * MM_PER_PX


@pytest.mark.parametrize(
    "sentence",
    [
        "Put 15 icing dots around the cake, leave space from the edge and between dots.",
        "Put 15 icings around the cake, provide some space from the cake edge and between each icing",
        "pipe fifteen dots of icing around the edge of the cake",
    ],
)
def test_case1_fifteen_dots_around(sentence):
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for(sentence, scene, primitives=ICING)
    assert plan.keyword == "line" and plan.num_pairs == 15
    assert np.allclose(plan.pairs_px[:, 0], plan.pairs_px[:, 1])  # dots
    points = plan.pairs_px[:, 0]
    radii = _radii(points, scene.centre_px)
    assert np.ptp(radii) < 1.0  # one ring
    assert 100.0 - radii.mean() >= 10.0  # space from the edge
    angles = np.sort(np.degrees(np.arctan2(*(points - scene.centre_px).T[::-1])) % 360)
    assert np.allclose(np.diff(np.append(angles, angles[0] + 360)), 24.0, atol=0.2)


def test_case2_two_layers():
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for(
        "Make 2 layers of icing around the cake, provide some space from the edges and between "
        "layers",
        scene,
        primitives=ICING,
    )
    radii = np.round(_radii(plan.pairs_px.reshape(-1, 2), scene.centre_px))
    levels = sorted(set(radii.tolist()))
    assert len(levels) == 2 and levels[1] <= 90 and levels[1] - levels[0] >= 10
    # each layer is a closed chain of segments
    for layer in np.split(plan.pairs_px, 2):
        assert np.allclose(layer[1:, 0], layer[:-1, 1])
        assert np.allclose(layer[-1, 1], layer[0, 0])


def test_case3_dots_and_a_spiral():
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for(
        "Combine 2 types of designs, icing dots around the cake and a spiral icing line design",
        scene,
        primitives=ICING,
    )
    is_dot = np.all(np.isclose(plan.pairs_px[:, 0], plan.pairs_px[:, 1]), axis=1)
    dots, lines = plan.pairs_px[is_dot], plan.pairs_px[~is_dot]
    assert len(dots) >= 6 and len(lines) >= 8
    assert np.allclose(lines[1:, 0], lines[:-1, 1])  # one continuous spiral
    radii = _radii(lines[:, 1], scene.centre_px)
    assert np.all(np.diff(radii) > 0)  # winding outwards
    assert radii.max() < _radii(dots[:, 0], scene.centre_px).min()


def test_case4_birthday_digits_in_seven_segments():
    scene = make_scene("disk", (220, 220))
    plan, _ = plan_for(
        "I'm having my 27th birthday, put the digits on the cake using seven-segment characters "
        "as icing lines",
        scene,
        primitives=ICING,
    )
    assert plan.num_pairs == 5 + 3  # '2' lights 5 segments, '7' lights 3
    for pair in plan.pairs_px:
        assert segment_angle(pair) in (pytest.approx(0.0, abs=1e-6), pytest.approx(90.0, abs=1e-6))
    assert _radii(plan.pairs_px.reshape(-1, 2), scene.centre_px).max() < 100.0


def test_case5_five_pointed_star_on_a_square_cake():
    scene = make_scene("rect", (180, 180))
    plan, _ = plan_for(
        "Draw a 5-pointed star using lines in the middle of the cake", scene, primitives=ICING
    )
    assert plan.num_pairs == 5
    tips = plan.pairs_px[:, 0]
    radii = _radii(tips, scene.centre_px)
    assert np.ptp(radii) < 1.0 and radii.mean() < 90.0
    centroid = tips.mean(axis=0)
    assert np.linalg.norm(centroid - scene.centre_px) * MM_PER_PX < 1.0
    lengths = np.linalg.norm(plan.pairs_px[:, 1] - plan.pairs_px[:, 0], axis=1)
    assert np.ptp(lengths) * MM_PER_PX < 1.0


@pytest.mark.parametrize("shape", ["disk", "rect"])
def test_cases6_7_simple_interesting_design_stays_on_the_cake(shape):
    scene = make_scene(shape, (180, 180))
    plan, _ = plan_for("Create a simple interesting design", scene, primitives=ICING)
    assert plan.num_pairs >= 5
    offsets = (plan.pairs_px.reshape(-1, 2) - scene.centre_px) * MM_PER_PX
    if shape == "disk":
        assert np.linalg.norm(offsets, axis=1).max() < 90.0
    else:
        assert np.abs(offsets).max() < 90.0


def test_case8_a_dot_in_the_middle_of_each_of_ten_slices_on_a_square_cake():
    scene = make_scene("rect", (200, 200))
    plan, _ = plan_for(
        "I want to put 1 dot of icing on the middle of each of the 10 slices",
        scene,
        primitives=ICING,
    )
    assert plan.num_pairs == 10
    dots = plan.pairs_px[:, 0] * MM_PER_PX
    xs, ys = np.unique(np.round(dots[:, 0], 1)), np.unique(np.round(dots[:, 1], 1))
    assert {len(xs), len(ys)} == {2, 5}  # a 2 x 5 grid of equal pieces
    for values, count in ((xs, len(xs)), (ys, len(ys))):
        assert np.allclose(np.diff(values), 200.0 / count, atol=1.0)


def test_a_dot_per_wedge_on_a_round_cake():
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for("one rosette on each of the 8 slices", scene, primitives=ICING)
    assert plan.num_pairs == 8
    radii = _radii(plan.pairs_px[:, 0], scene.centre_px)
    assert np.ptp(radii) < 0.5 and 50 < radii.mean() < 80


# --- sentences it cannot read ----------------------------------------------------------------


@pytest.mark.parametrize(
    "sentence", ["Make it look nice", "I have 3 guests, cut a few thin slices"]
)
def test_unreadable_sentences_fail_clearly(sentence):
    scene = make_scene("disk", (150, 150))
    with pytest.raises(KeympsError) as error:
        plan_for(sentence, scene)
    message = str(error.value)
    assert "offline planner" in message and "--model" in message and "\n" not in message


def test_slices_wider_than_the_object_fail_clearly():
    scene = make_scene("ellipse", (80, 40))
    with pytest.raises(KeympsError, match="do not fit"):
        plan_for("cut it into 10 cm slices", scene)


def test_the_offline_planner_is_deterministic():
    scene = make_scene("disk", (200, 200))
    first, _ = plan_for("Cut it into 8 equal slices", scene, primitives=CUTTING)
    second, _ = plan_for("Cut it into 8 equal slices", scene, primitives=CUTTING)
    assert np.array_equal(first.pairs_px, second.pairs_px)


# --- paraphrases read the same -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("canonical", "paraphrase"),
    [
        ("Cut it into 8 equal slices", "Please cut this pizza into eight even pieces"),
        ("Cut it into 8 equal slices", "Divide it into 8 portions"),
        (
            "I'm having a party for 10 people, cut 1 slice for each",
            "We are ten guests, one slice each",
        ),
        ("Slice the object into 3 parts horizontally", "cut it horizontally into three pieces"),
        ("Slice both tips of the object", "Cut off both ends"),
        ("A single horizontal slice in the middle", "Make one horizontal cut through the middle"),
        (
            "The object is 30 cm long, cut it vertically into 5 cm slices",
            "This eggplant is thirty centimetres long; slice it vertically into 50 mm slices",
        ),
        (
            "I want to eat 1 slice for each day of this week, cut it vertically",
            "one slice for every day of the week, cut vertically",
        ),
        ("Split it into 4", "Quarter it"),
        ("Cut me 4 2cm slices", "cut 4 slices 2 cm thick"),
        (
            "Put 15 icing dots around the cake, leave space from the edge and between dots.",
            "Pipe fifteen rosettes around the cake, away from the edge",
        ),
        ("Make 2 layers of icing around the cake", "Draw two rings of icing around the cake"),
        ("Draw a 5-pointed star using lines in the middle of the cake", "pipe a star on the cake"),
        (
            "I'm having my 27th birthday, put the digits on the cake using seven-segment characters",
            "Write 27 on the cake in seven-segment digits",
        ),
        (
            "I want to put 1 dot of icing on the middle of each of the 10 slices",
            "Put a dot of icing in the middle of each of the ten slices",
        ),
    ],
)
def test_paraphrases_read_the_same(canonical, paraphrase):
    from keymps.designs.grammar import read_instruction

    first, second = read_instruction(canonical), read_instruction(paraphrase)
    assert first.describe() == second.describe()


@pytest.mark.parametrize(
    "sentence",
    [
        "I want to make tsukemono",
        "I want to make wide chips out of this",
        "Cut it into french fries",
        "For banana pancake",
        "Prepare it for fondant potato",
    ],
)
def test_table_v_sentences_that_need_kitchen_knowledge_are_left_to_a_vlm(sentence):
    from keymps.designs.grammar import UnreadableInstruction, read_instruction

    with pytest.raises(UnreadableInstruction, match="--model"):
        read_instruction(sentence)


def test_designs_are_metric_when_pixels_are_not_square(tmp_path):
    """0.30 x 0.18 m spanned by a 400 x 400 image: x pixels 0.75 mm, y pixels 0.45 mm."""
    import cv2

    from keymps.config.task import Task
    from keymps.planning.planner import make_plan
    from keymps.run import Run
    from keymps.types import Detection, SceneImage

    image = np.full((400, 400, 3), 205, np.uint8)
    # a 120 mm disk on the board is an ellipse in this image
    cv2.ellipse(image, ((200, 200), (120 / 0.75, 120 / 0.45), 0), (40, 110, 200), -1)
    detection = Detection((120, 66, 281, 335), image[56:345, 110:291].copy(), (110, 56))
    task = Task(
        name="stretched",
        instruction="Cut it into 6 equal slices",
        scene={"source": "synthetic", "workspace": {"size": [0.30, 0.18]}},
        primitives=list(CUTTING),
    )
    run = Run(task=task, folder=tmp_path)
    plan = make_plan(task, detection, SceneImage(image, "synthetic"), CUTTING, run, "offline")
    metric = plan.pairs_px * np.array([0.75, 0.45])
    angles = sorted(segment_angle(p) for p in metric)
    assert np.allclose(np.diff(angles + [angles[0] + 180]), 60.0, atol=0.5)
    half_lengths = np.linalg.norm(metric[:, 1] - metric[:, 0], axis=1) / 2
    assert np.all(half_lengths > 59.5) and np.ptp(half_lengths) < 1.5


# --- any sentence: a plan inside the crop or one clear line, never a crash --------------------

_WORDS = [
    "cut",
    "slice",
    "into",
    "equal",
    "slices",
    "pieces",
    "vertically",
    "horizontally",
    "both",
    "tips",
    "middle",
    "dots",
    "icing",
    "around",
    "layers",
    "spiral",
    "star",
    "pointed",
    "birthday",
    "digits",
    "each",
    "of",
    "the",
    "people",
    "cm",
    "mm",
    "long",
    "thick",
    "a",
    "single",
    "week",
    "day",
    "rings",
    "write",
    "seven-segment",
    "half",
]


@pytest.mark.parametrize("shape", ["disk", "ellipse"])
def test_any_sentence_gives_a_valid_plan_or_one_clear_line(shape):
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    scene = make_scene(shape, (120, 120) if shape == "disk" else (200, 70))
    numbers = st.one_of(st.integers(-5, 2000).map(str), st.sampled_from(["0.0001", "1e9", "0"]))
    tokens = st.lists(st.one_of(st.sampled_from(_WORDS), numbers), min_size=1, max_size=9)

    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
    @given(tokens)
    def check(words):
        sentence = " ".join(words)
        try:
            plan, _ = plan_for(sentence, scene, ICING if "icing" in words else CUTTING)
        except KeympsError as error:
            assert "\n" not in str(error)
            return
        width, height = scene.detection.crop_size_px
        crop = plan.pairs_crop_px.reshape(-1, 2)
        assert 1 <= plan.num_pairs <= 64 and np.isfinite(crop).all()
        assert (crop >= 0).all() and (crop[:, 0] <= width).all() and (crop[:, 1] <= height).all()

    check()


def test_layers_on_a_square_cake_follow_its_edge():
    scene = make_scene("rect", (180, 180))
    plan, _ = plan_for("Make 2 layers of icing around the cake", scene, primitives=ICING)
    assert plan.num_pairs == 8  # two nested squares
    offsets = np.abs(plan.pairs_px.reshape(-1, 2) - scene.centre_px) * MM_PER_PX
    sizes = sorted({round(float(v), 1) for v in offsets.max(axis=1)})
    assert len(sizes) == 2 and sizes[1] < 90.0 and sizes[1] - sizes[0] >= 10.0
    for square in np.split(plan.pairs_px, 2):
        assert np.allclose(square[1:, 0], square[:-1, 1]) and np.allclose(
            square[-1, 1], square[0, 0]
        )


# --- the primitive, from the shipped primitives' descriptions ----------------------------------


@pytest.mark.parametrize(
    ("names", "context", "expected"),
    [
        (
            ["straight", "sawing"],
            "The object is 40 cm long, cut it into 5 cm slices baguette-40cm",
            "sawing",
        ),
        (["straight", "sawing"], "Cut it into 8 equal slices pizza", "straight"),
        (["straight", "sawing"], "A single horizontal slice in the middle cabbage", "sawing"),
        (["straight", "sawing"], "Slice both tips of the object eggplant", "straight"),
        (["straight", "sawing"], "1 slice for each day of this week banana bread", "sawing"),
        (["downward", "forward"], "Cut it into french fries potato", "forward"),
        (["downward", "forward"], "Split it into 4 baumkuchen", "downward"),
        (["downward", "forward"], "cut 4 slices tomato", "downward"),
        (
            ["downward", "forward"],
            "This is a block of meat. Cut me 4 2cm slices meat_loaf",
            "downward",
        ),
        (["straight", "sawing", "line"], "Put 15 icing dots around the cake", "line"),
    ],
)
def test_primitive_choice_reads_the_shipped_descriptions(names, context, expected):
    from keymps.default_plugins.offline import choose_primitive
    from keymps.primitives.dictionary import default_search_dirs, load_primitives

    repo = __import__("pathlib").Path(__file__).resolve().parents[2]
    loaded = load_primitives(names, default_search_dirs(repo / "tasks"))
    descriptions = {name: p.description for name, p in loaded.items()}
    family = "icing" if "icing" in context else "cut"
    chosen, why = choose_primitive(family, descriptions, context)
    assert chosen == expected, why


def test_a_primitive_the_sentence_names_is_taken_first():
    """A user's own primitive, asked for by name, beats the object rules; two names asked for
    at once decide nothing, and the usual rules apply."""
    from keymps.default_plugins.offline import choose_primitive

    cutting = {
        "straight": "Straight cut down through the object. For soft objects (cake, banana).",
        "sawing": "Sawing cut. For hard or crusty objects (crusty bread, baguette).",
        "rocking": "Rocking cut: rock the blade forward and back while descending.",
    }
    sentence = "Cut the baguette into 4 slices with a rocking cut"
    assert choose_primitive("cut", cutting, sentence) == ("rocking", "the sentence names it")
    assert choose_primitive("cut", cutting, "Cut the baguette into 4 slices")[0] == "sawing"
    either = "Cut the baguette into 4 slices, rocking or straight"
    assert choose_primitive("cut", cutting, either)[0] == "sawing"
    icing = {"line": "Icing line with a piping bag.", "rosette": "Icing rosette: pipe a swirl."}
    assert choose_primitive("icing", icing, "Pipe 6 rosettes around the cake")[0] == "rosette"
    assert choose_primitive("icing", icing, "Put 6 icing dots around the cake")[0] == "line"


def test_a_named_design_answer_refuses_what_it_cannot_carry():
    """planner.answer: design: a distance from the edge, the tips' inset or strips are no
    named design's parameters; the offline planner says so rather than answer without them."""
    scene = make_scene("disk", (150, 150))
    sentence = "Put 12 dots around the cake half an inch from the edge"
    with pytest.raises(KeympsError, match="a named design cannot carry 1.27 cm from the edge"):
        plan_for(sentence, scene, ICING, answer="design")
    plan, _ = plan_for("Put 12 dots around the cake", scene, ICING, answer="design")
    assert plan.num_pairs == 12
    loaf = make_scene("rect", (200, 60))
    with pytest.raises(KeympsError, match="cannot carry strip pieces"):
        plan_for("Cut it into 3 strips", loaf, answer="design")
