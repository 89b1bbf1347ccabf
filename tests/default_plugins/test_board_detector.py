"""The board detector (the default): scenes the paper's threshold detector gets wrong, refusals."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from keymps.default_plugins.board_detector import BoardDetector, BoardOptions
from keymps.default_plugins.threshold_detector import ThresholdDetector
from keymps.errors import KeympsError
from keymps.plugin.manager import create_component
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.perception_cases import BOARDS, flat_case, lab_to_bgr
from keymps.scenes.render import KINDS, SceneSpec, render_scene

ROOT = Path(__file__).resolve().parents[2]


def board(lab: tuple[float, float, float], size: tuple[int, int] = (600, 360)) -> np.ndarray:
    """A plain board of this Lab colour with camera noise (float BGR)."""
    colour = lab_to_bgr(np.array(lab))[0]
    noise = np.random.default_rng(1).normal(0, 2, (size[1], size[0], 3))
    return np.broadcast_to(colour, (size[1], size[0], 3)) + noise


def finish(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def gradient(size: tuple[int, int], amount: float) -> np.ndarray:
    x = np.linspace(-1, 1, size[0])[None, :, None]
    return 1 + amount * x


def paint(
    image: np.ndarray, box: tuple[int, int, int, int], lab: tuple[float, float, float]
) -> None:
    x0, y0, x1, y1 = box
    image[y0:y1, x0:x1] = lab_to_bgr(np.array(lab))[0]


def box_error(found: tuple[int, ...], truth: tuple[int, ...]) -> int:
    return int(np.abs(np.subtract(found, truth)).max())


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kitchen_object_is_found_within_2px(kind: str) -> None:
    detector = BoardDetector()
    for seed in range(2):
        scene = render_scene(SceneSpec.from_kinds([kind], seed=seed, px_per_m=1000))
        detection = detector.detect(scene.image)
        assert box_error(detection.bbox_px, scene.truth["objects"][0]["bbox_px"]) <= 2, seed
        assert detection.warnings == ()


def issue_scenes() -> dict[str, tuple[np.ndarray, tuple[int, int, int, int]]]:
    """The scenes of issue 17 on which the paper's rule takes the board for the object."""
    scenes = {}
    wood = board(BOARDS["light wood"])
    wood *= 1 + 0.04 * np.sin(np.arange(360) / 3.0)[:, None, None]  # grain
    third = (150, 60, 450, 300)  # a uniform cake covering a third of the board
    paint(wood, third, (82.0, 2.0, 12.0))
    scenes["uniform third"] = (finish(wood), third)
    lit = board(BOARDS["light wood"])
    chocolate = (200, 90, 380, 270)
    paint(lit, chocolate, (30.0, 12.0, 18.0))
    scenes["chocolate, 6 % gradient"] = (finish(lit * gradient((600, 360), 0.06)), chocolate)
    square = board(BOARDS["bamboo"])
    square *= 1 + 0.05 * np.sin(np.arange(360) / 2.5)[:, None, None]  # grain
    white = (180, 90, 420, 270)  # uniform: the histogram's peak
    paint(square, white, (95.0, 0.0, 2.0))
    scenes["white square on wood"] = (finish(square * gradient((600, 360), 0.1)), white)
    tall = board(BOARDS["light wood"])
    filling = (60, 18, 540, 342)  # 90 % of the board's height
    paint(tall, filling, (75.0, 8.0, 35.0))
    scenes["90 % of the height"] = (finish(tall), filling)
    green = board((50.0, -35.0, 25.0))
    red = (220, 110, 400, 250)
    paint(green, red, (50.0, 55.0, 35.0))  # the same lightness: grey cannot tell them apart
    scenes["red on green, same grey"] = (finish(green), red)
    return scenes


@pytest.mark.parametrize("name", list(issue_scenes()))
def test_the_issues_scenes_are_found_where_the_threshold_detector_fails(name: str) -> None:
    image, truth = issue_scenes()[name]
    assert box_error(BoardDetector().detect(image).bbox_px, truth) <= 1
    try:
        old = ThresholdDetector().detect(image).bbox_px
    except KeympsError:
        old = None
    if name != "white square on wood":  # Appendix A finds this one on our wood, not the issue's
        assert old is None or box_error(old, truth) > 3, "the scene is not hard for Appendix A"


def test_shadow_crumbs_jpeg_and_a_second_object_do_not_move_the_box() -> None:
    varied = {"shadow": 0, "crumbs": 0, "jpeg_quality": 0, "second_object": 0}
    detector = BoardDetector()
    for seed in range(30):
        case = flat_case(seed)
        detection = detector.detect(case.image)
        assert case.truth_bbox is not None
        assert box_error(detection.bbox_px, case.truth_bbox) <= 3, (seed, case.variation)
        for key in varied:
            varied[key] += key in case.variation
    assert min(varied.values()) >= 3, varied  # each variation was exercised


def test_objects_are_numbered_left_to_right_and_the_report_says_why() -> None:
    image = finish(board(BOARDS["white plastic"]))
    paint_float = image.astype(float)
    paint(paint_float, (400, 100, 560, 260), (40.0, 20.0, 30.0))  # the largest, on the right
    paint(paint_float, (40, 200, 140, 300), (40.0, 20.0, 30.0))
    paint(paint_float, (60, 30, 120, 90), (40.0, 20.0, 30.0))  # a third, above the second
    detection = BoardDetector().detect(finish(paint_float))
    assert detection.bbox_px == (400, 100, 560, 260)
    assert [o.bbox_px for o in detection.objects] == [
        (60, 30, 120, 90),  # the same centre x as the next: top to bottom
        (40, 200, 140, 300),
        (400, 100, 560, 260),
    ]
    assert [o.id for o in detection.objects] == [1, 2, 3]
    first = detection.objects[1]
    assert first.mask is not None and first.mask.sum() == pytest.approx(100 * 100, rel=0.01)
    assert first.area_px == pytest.approx(99 * 99, rel=0.01) and first.contour_px.shape[1] == 2
    report = detection.report
    assert report["detector"] == "board" and report["threshold"]["how"].startswith("automatic")
    assert report["board_model"]["mean_lab"][0] == pytest.approx(88, abs=2)
    assert [r["verdict"] for r in report["regions"]] == ["object"] * 3
    assert report["chosen"]["why"] == "the largest object"
    json.dumps(report)  # run.json holds it as it is
    assert detection.others_px == ((40, 200, 140, 300), (60, 30, 120, 90))  # largest first


def test_every_object_is_kept_without_a_warning_and_pick_keeps_one() -> None:
    """Issue 39: every run with two objects warned 'the one in box [...] is used, not the one in
    box [...]', even when the sentence had both cut. Without detector.pick both are objects and
    nothing is warned; with it one is kept and the other named by box, area and place."""
    image = finish(board(BOARDS["white plastic"]))
    paint_float = image.astype(float)
    paint(paint_float, (60, 60, 220, 220), (40.0, 20.0, 30.0))
    paint(paint_float, (380, 70, 530, 220), (40.0, 20.0, 30.0))  # a little smaller, right
    both = BoardDetector().detect(finish(paint_float))
    assert both.warnings == () and len(both.objects) == 2
    picked = BoardDetector(BoardOptions(pick=0)).detect(finish(paint_float))
    (warning,) = picked.warnings
    assert [o.bbox_px for o in picked.objects] == [(60, 60, 220, 220)]
    assert "detector.pick keeps the object in box [60, 60, 220, 220]" in warning
    assert "in box [380, 70, 530, 220]" in warning and "to its right), is left out" in warning
    assert "#" not in warning  # no number that plan.png would give another object
    with pytest.raises(KeympsError, match=r"\(by decreasing area: pick 0: box \[60, 60"):
        BoardDetector(BoardOptions(pick=2)).detect(finish(paint_float))


def test_a_task_can_set_the_threshold_and_options_are_checked() -> None:
    image, truth = issue_scenes()["red on green, same grey"]
    fixed = create_component("detector", "board", {"threshold": 20, "blur": 3}).detect(image)
    assert fixed.report["threshold"] == {"value": 20.0, "how": "detector.threshold"}
    assert box_error(fixed.bbox_px, truth) <= 1
    with pytest.raises(KeympsError, match=r"board detector: option 'threshold': Input should be"):
        create_component("detector", "board", {"threshold": -1})
    with pytest.raises(KeympsError, match=r"option 'blur': must be odd"):
        create_component("detector", "board", {"blur": 4})
    with pytest.raises(KeympsError, match=r"option 'thresh': unknown option \(options: threshold"):
        create_component("detector", "board", {"thresh": 20})


def test_an_empty_board_says_no_object_found() -> None:
    for seed in (9, 19, 29, 39):
        case = flat_case(seed, empty=True)
        with pytest.raises(KeympsError, match=r"^detect: no object found: nothing of at least"):
            BoardDetector().detect(case.image)
    with pytest.raises(KeympsError, match="detect: the scene image is empty"):
        BoardDetector().detect(np.zeros((0, 0, 3), np.uint8))


def test_the_board_or_the_table_is_never_the_object() -> None:
    # a photo that shows the table along three sides of the board
    framed = board(BOARDS["light wood"])
    table = (20.0, 2.0, 4.0)
    paint(framed, (0, 0, 600, 40), table)
    paint(framed, (0, 0, 40, 360), table)
    paint(framed, (0, 320, 600, 360), table)
    paint(framed, (250, 120, 400, 240), (80.0, 0.0, 5.0))
    with pytest.raises(KeympsError) as error:
        BoardDetector().detect(finish(framed))
    message = str(error.value)
    assert message.startswith("detect: the region found (box [")
    assert "runs along" in message or "touches 3 sides" in message
    assert "scene.camera.board_corners_px" in message and "nothing is planned on it" in message
    # an object (or a second board) covering most of the searched area
    covered = board(BOARDS["light wood"])
    paint(covered, (8, 8, 592, 352), (40.0, 30.0, 30.0))
    with pytest.raises(KeympsError, match=r"covers 9\d % of the searched area \(more than"):
        BoardDetector().detect(finish(covered))
    # more than max_coverage is allowed when the task says so
    allowed = BoardDetector(BoardOptions(max_coverage=1.0)).detect(finish(covered))
    assert allowed.bbox_px == (8, 8, 592, 352)


def test_a_board_detection_stops_the_run_before_planning(tmp_path: Path) -> None:
    from keymps.pipeline.engine import run_task

    framed = board(BOARDS["light wood"])
    paint(framed, (0, 0, 600, 40), (20.0, 2.0, 4.0))
    paint(framed, (0, 0, 40, 360), (20.0, 2.0, 4.0))
    paint(framed, (0, 320, 600, 360), (20.0, 2.0, 4.0))
    image = tmp_path / "framed.png"
    cv2.imwrite(str(image), finish(framed))
    text = (
        (ROOT / "tasks" / "object_cutting.yaml").read_text().replace("scenes/pizza.png", str(image))
    )
    text = text.replace("../prompts/", str(ROOT / "prompts") + "/")
    task = tmp_path / "task.yaml"
    task.write_text(text)
    for detector in ("board", "threshold"):
        task.write_text(text.replace("detector: {name: board}", f"detector: {{name: {detector}}}"))
        out = tmp_path / detector
        with pytest.raises(KeympsError, match=r"^detect: the (region|object) found \(box"):
            run_task(
                task,
                options=RunOptions(rerun="off"),
                overrides=RunOverrides(out=out, backend="offline"),
            )
        record = json.loads((out / "run.json").read_text())
        assert record["ok"] is False and record["detection"] is None and record["pairs_px"] is None
        assert not (out / "trajectory.csv").exists() and not list(out.glob("plan.*"))


def test_every_object_of_a_pair_is_found_whatever_their_contrasts() -> None:
    """Each of the 78 pairs of scene kinds, two seeds: a faint object beside a bright one (a
    potato beside a banana) keeps its own edge. One threshold from the largest object's contrast
    found 132 of these 156 scenes; each object at half its own contrast finds all."""
    import itertools

    from keymps.plugin.manager import create_component
    from keymps.scenes.render import KINDS, SceneSpec, render_scene
    from keymps.types import SceneImage

    detector = create_component("detector", "board", {})
    missed = []
    for first, second in itertools.combinations(sorted(KINDS), 2):
        for seed in range(2):
            spec = SceneSpec.from_kinds(
                [first, second], seed=seed, board_size=(0.6, 0.3), px_per_m=1000
            )
            scene = render_scene(spec)
            truth = [tuple(o["bbox_px"]) for o in scene.truth["objects"]]
            found = [
                o.bbox_px for o in detector.detect(SceneImage(scene.image, "synthetic")).objects
            ]
            within = [
                any(max(abs(a - b) for a, b in zip(box, seen, strict=True)) <= 3 for seen in found)
                for box in truth
            ]
            if len(found) != len(truth) or not all(within):
                missed.append(f"{first}+{second} seed {seed}: true {truth}, found {found}")
    assert not missed, f"{len(missed)} of 156 scenes: " + "; ".join(missed[:5])


LAB_OF_A_RANDOM_IMAGE = """
import hashlib, sys, threading
import numpy as np
image = np.random.default_rng(7).integers(0, 256, (240, 320, 3), dtype=np.uint8)
if sys.argv[1] == "thread":
    from keymps.plugin.manager import create_component
    create_component("detector", "board", {})  # starts OpenCV's Lab tables on another thread
    print(any(t.name == "keymps-lab-tables" for t in threading.enumerate()))
    from keymps.perception.board_model import to_lab
    lab = to_lab(image)
else:
    import cv2
    print(True)
    lab = cv2.cvtColor(image.astype(np.float32) / 255.0, cv2.COLOR_BGR2Lab)
print(hashlib.sha256(np.ascontiguousarray(lab).tobytes()).hexdigest())
"""


def test_lab_tables_built_on_another_thread_give_opencvs_conversion() -> None:
    import subprocess
    import sys

    def lab(how: str) -> list[str]:
        done = subprocess.run(
            [sys.executable, "-c", LAB_OF_A_RANDOM_IMAGE, how],
            capture_output=True,
            text=True,
            check=True,
            timeout=60,
        )
        return done.stdout.split()

    threaded, direct = lab("thread"), lab("direct")
    assert threaded[0] == "True"  # the thread was running when the detector was made
    assert threaded[1] == direct[1]  # the same float32 Lab, bit for bit


def test_keymps_run_starts_the_lab_tables_before_it_reads_the_task(tmp_path: Path) -> None:
    import subprocess
    import sys

    # the task file does not exist: the run stops at loading it, the thread must be running
    check = (
        "import sys; from keymps.cli.app import cli; from keymps.perception import board_model\n"
        "try:\n    cli(['run', sys.argv[1], '--rerun', 'off'])\nexcept SystemExit:\n    pass\n"
        "print(board_model._lab_tables is not None)"
    )
    done = subprocess.run(
        [sys.executable, "-c", check, str(tmp_path / "missing.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert done.stdout.split()[-1] == "True", done.stderr
    assert "missing.yaml" in done.stderr  # it did stop at the task


def test_a_process_ending_while_the_lab_tables_are_built_exits_cleanly() -> None:
    """The build was a daemon thread: a process done before it (`keymps validate`, which makes
    a detector) aborted in OpenCV's exit-time destructors, 5 times in 6 here, exit code 134."""
    import subprocess
    import sys

    end_at_once = (
        "import cv2\n"
        "from keymps.perception.board_model import prepare_lab_tables\n"
        "prepare_lab_tables()\n"
    )
    validate = (
        "import sys\nfrom keymps.cli.app import main\n"
        "sys.argv = ['keymps', 'validate', sys.argv[1]]\nmain()\n"
    )
    task = str(Path(__file__).parents[2] / "tasks" / "cake_icing.yaml")
    for code, arguments in [(end_at_once, [])] * 6 + [(validate, [task])] * 2:
        done = subprocess.run(
            [sys.executable, "-c", code, *arguments], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        assert "terminate" not in done.stderr


def _shadowed_scene(seed: int, with_object: bool) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """A board of a random colour and lighting gradient, and a shadow of random shape, softness
    and darkness (a band, a blob, or the object's own shadow cast aside); with an object of a
    random colour on top when `with_object`. Returns the image and the object's box."""
    rng = np.random.default_rng(seed)
    width, height = 600, 360
    lab = np.array(list(BOARDS.values())[seed % len(BOARDS)]) + rng.normal(0, 3, 3)
    image = board(tuple(lab)) * np.linspace(1 - 0.15 * rng.random(), 1, width)[None, :, None]
    centre = (int(rng.integers(180, 420)), int(rng.integers(130, 230)))
    radius = int(rng.integers(50, 100))
    shape = np.zeros((height, width), np.float32)
    cv2.circle(shape, centre, radius, 1.0, -1)
    kind = rng.integers(3) if not with_object else 2
    shade = np.zeros((height, width), np.float32)
    if kind == 0:  # a band across the whole board (a shelf's shadow)
        x = int(rng.integers(80, 400))
        shade[:, x : x + int(rng.integers(60, 180))] = 1.0
    elif kind == 1:  # a blob (a hand, a jug out of the picture)
        shade = shape.copy()
    else:  # the object's own shadow, cast aside
        shift = rng.uniform(10, 40) * np.array([np.cos(a := rng.uniform(0, 6.3)), np.sin(a)])
        shade = cv2.warpAffine(
            shape, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (width, height)
        )
    shade = cv2.GaussianBlur(shade, (0, 0), rng.uniform(2, 20))
    image = image * (1 - rng.uniform(0.2, 0.6) * shade)[..., None]
    box = (0, 0, 0, 0)
    if with_object:
        while True:
            colour = np.array([rng.uniform(15, 95), rng.uniform(-40, 60), rng.uniform(-40, 70)])
            if np.linalg.norm(colour - lab) >= 25:
                break
        drawn = np.zeros((height, width), np.uint8)
        cv2.circle(drawn, centre, radius, 255, -1)
        image = np.where(drawn[..., None] > 0, lab_to_bgr(colour)[0], image)
        ys, xs = np.nonzero(drawn)
        box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
    return finish(image), box


def test_a_shadow_is_never_an_object() -> None:
    """An empty board with a shadow was planned on (a band across it: 7 cuts; a soft blob: 4),
    and an object's cast shadow widened its box by the shadow (an off-centre plan). A shadow
    darkens the board and keeps its colour: 60 empty boards with a random shadow are refused,
    saying so, and 60 objects with their cast shadow are found to 3 px of their own box."""
    refused = found = 0
    for seed in range(60):
        image, _ = _shadowed_scene(seed, with_object=False)
        with pytest.raises(KeympsError, match="taken for shadow"):
            BoardDetector().detect(image)
        refused += 1
    misses = []
    for seed in range(60):
        image, box = _shadowed_scene(1000 + seed, with_object=True)
        detected = BoardDetector().detect(image)
        error = max(abs(a - b) for a, b in zip(detected.bbox_px, box, strict=True))
        if error <= 3:
            found += 1
        else:
            misses.append((seed, detected.bbox_px, box))
    assert refused == 60
    assert found == 60, misses


@pytest.mark.parametrize("markers", [False, True])
def test_a_board_photographed_on_a_darker_table_is_refused(markers: bool) -> None:
    """Issue 39: a photo showing the table around the board (no board corners given) made the
    board the object: the table is what the detector models then, and the whole board differs
    from it. Such a region is four-sided and holds another object: refused, with what to do."""
    from keymps.scenes.perception_cases import photo_case

    for seed in range(20):
        photo = photo_case(seed, markers=markers).photo
        with pytest.raises(KeympsError, match="a board on a darker table") as error:
            BoardDetector().detect(photo)
        assert "scene.camera.board_corners_px" in str(error.value)
    kept = BoardDetector(BoardOptions(board_on_table=False)).detect(photo)
    assert kept.report["regions"][0]["verdict"] == "object"


def test_no_object_of_the_synthetic_kinds_is_taken_for_a_board_on_a_table() -> None:
    """Square cakes, loaves and meat loaves are four-sided too: none holds another colour."""
    for kind in KINDS:
        for seed, rotation in ((0, 0.0), (1, 25.0), (2, -35.0)):
            scene = render_scene(SceneSpec.from_kinds([kind], seed=seed, rotation=rotation))
            detection = BoardDetector().detect(scene.image)
            truth = scene.truth["objects"][0]["bbox_px"]
            assert box_error(detection.bbox_px, truth) <= 2, (kind, seed)


def test_a_dark_rim_all_round_a_cake_is_the_cakes_not_its_shadow() -> None:
    """A chocolate cake's rim is the wood board's colour, darker: it was taken for shadow, the
    mask lost up to 3.7 px of the edge and a turned cake's corner piece stayed attached in 6 of
    50 Appendix F runs. Shadow-coloured pixels all round an object are now its own."""
    from keymps.eval.suites import load_suite
    from keymps.eval.tasks import case_scene

    suite = load_suite("cake_six")
    case = suite.case("square")
    for seed in range(0, 50, 5):
        scene = render_scene(case_scene(suite, case, seed).spec())
        outline = np.asarray(scene.truth["objects"][0]["outline_px"], np.float32)
        truth = np.zeros(scene.image.shape[:2], np.uint8)
        points = np.round(outline * 16).astype(np.int32).reshape(-1, 1, 2)
        cv2.fillPoly(truth, [points], 1, cv2.LINE_8, 4)
        detection = BoardDetector().detect(scene.image)
        mask = detection.mask.astype(np.uint8)
        missing = int((truth & (1 - mask)).sum())  # before: 687 to 1007 px of these cakes
        assert detection.report["shadow_px"] < 100 and missing < 650, (seed, missing)
