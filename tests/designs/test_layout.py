"""Plans that mean what the user said: new offline designs, refusals by object shape, the end
piece rule, the tool family for every backend, and the command line's --model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers.synthetic_crops import CUTTING, ICING, MM_PER_PX, make_scene, make_task, plan_for

import keymps
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]


def _radii(points: np.ndarray, centre) -> np.ndarray:
    return np.linalg.norm(points - np.asarray(centre), axis=1) * MM_PER_PX


def test_a_dot_in_the_centre_is_one_dot_at_the_centre():
    scene = make_scene("disk", (200, 200))
    plan, _ = plan_for("a dot in the centre", scene, primitives=ICING)
    assert plan.num_pairs == 1
    ((start, end),) = plan.pairs_px
    assert np.allclose(start, end)
    assert _radii(start[None], scene.centre_px)[0] < 1.0


@pytest.mark.parametrize(
    ("sentence", "rings", "per_ring"),
    [
        ("three neat rings of dots", 3, None),
        ("two rings of 12 dots", 2, 12),
    ],
)
def test_rings_of_dots_are_concentric_rings_of_dots(sentence, rings, per_ring):
    scene = make_scene("disk", (220, 220))
    plan, _ = plan_for(sentence, scene, primitives=ICING)
    assert np.allclose(plan.pairs_px[:, 0], plan.pairs_px[:, 1]), "dots only"
    radii = np.round(_radii(plan.pairs_px[:, 0], scene.centre_px))
    levels = sorted(set(radii.tolist()))
    assert len(levels) == rings and levels[-1] < 110 - 10
    assert min(np.diff(levels)) >= 10
    if per_ring is not None:
        assert all(int((radii == level).sum()) == per_ring for level in levels)


def test_nine_squares_of_a_round_cake_are_refused_with_the_alternative():
    scene = make_scene("disk", (200, 200))
    with pytest.raises(
        KeympsError, match="round object cannot be cut into 9 equal squares.*wedges"
    ):
        plan_for("cut the round cake into 9 squares", scene)


def test_nine_squares_of_a_square_cake_are_a_three_by_three_grid():
    from helpers.synthetic_crops import piece_areas

    scene = make_scene("rect", (180, 180))
    plan, _ = plan_for("cut the cake into 9 squares", scene)
    assert plan.num_pairs == 4
    areas = piece_areas(scene, plan)
    assert len(areas) == 9 and max(areas) / min(areas) < 1.05


def test_squares_that_cannot_be_squares_and_wedges_of_a_loaf_are_refused():
    with pytest.raises(KeympsError, match="not squares"):
        plan_for("cut it into 6 squares", make_scene("rect", (180, 180)))
    with pytest.raises(KeympsError, match="wedges need a round object"):
        plan_for("cut it into 8 wedges", make_scene("rect", (240, 90)))


def test_slices_of_a_width_leave_an_end_piece_of_at_least_half_a_slice():
    """The same rule as the eval's ground truth, over lengths and widths not tuned for."""
    from keymps.designs.crop_shape import measure
    from keymps.designs.grammar import read_instruction
    from keymps.designs.layout import design
    from keymps.eval.suites import ParallelCuts
    from keymps.eval.truth import _parallel_positions

    rng = np.random.default_rng(18)
    for _ in range(60):
        length = float(rng.uniform(60, 300))
        width_cm = float(rng.choice([1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0]))
        scene = make_scene("rect", (length, 60))
        crop = scene.detection.crop
        shape = measure(crop, None, (MM_PER_PX, MM_PER_PX))
        intent = read_instruction(f"cut it into {width_cm:g} cm slices")
        measured = shape.outline.length
        truth = _parallel_positions(
            ParallelCuts(pattern="parallel", along="x", spacing=width_cm * 10), measured
        )
        if len(truth) == 0:
            with pytest.raises(KeympsError, match="do not fit"):
                design(intent, shape, 64)
            continue
        pairs, _ = design(intent, shape, 64)
        xs = np.sort(pairs[:, :, 0].mean(axis=1)) - (shape.outline.centre[0] - measured / 2)
        assert len(xs) == len(truth), (length, width_cm)
        assert np.allclose(xs, truth, atol=0.5)
        assert measured - xs[-1] >= width_cm * 10 / 2 - 0.5


def test_three_cm_slices_of_a_12_cm_loaf_keep_no_sliver():
    scene = make_scene("rect", (121, 60))
    plan, _ = plan_for("Cut 3 cm thick slices", scene)
    assert plan.num_pairs == 3


# --- the tool family, for every backend --------------------------------------------------------


@pytest.mark.parametrize(
    ("task_file", "sentence", "message"),
    [
        ("object_cutting.yaml", "Put 10 icing dots around the bread", "asks for icing.*knife"),
        ("cake_icing.yaml", "cut the cake into 8 slices", "asks for cutting.*piping_bag"),
    ],
)
@pytest.mark.parametrize("backend", ["offline", "scripted"])
def test_a_sentence_of_the_other_family_stops_at_the_plan_stage(
    task_file, sentence, message, backend, tmp_path, keymps_plugins
):
    from helpers.fuzz_support import RecordingExecutor, ScriptedBackend, install

    install(keymps_plugins)
    ScriptedBackend.answers = []
    ScriptedBackend.requests = []
    RecordingExecutor.calls = []
    task = keymps.load_task(REPO / "tasks" / task_file)
    with pytest.raises(KeympsError, match=f"^plan: .*{message}"):
        keymps.run_task(
            task,
            overrides=RunOverrides(
                instruction=sentence, backend=backend, executor="recording", out=tmp_path / "r"
            ),
        )
    assert RecordingExecutor.calls == [] and ScriptedBackend.requests == []


def test_a_vlm_plan_with_a_primitive_of_the_other_family_is_refused(tmp_path, keymps_plugins):
    from helpers.fuzz_support import RecordingExecutor, ScriptedBackend, answer_text, install

    install(keymps_plugins)
    task = keymps.load_task(REPO / "tasks" / "object_cutting.yaml")
    task = task.model_copy(update={"primitives": ["straight", "line"]})
    ScriptedBackend.answers = [lambda request: answer_text("line", [[[10, 10], [40, 40]]])]
    RecordingExecutor.calls = []
    with pytest.raises(
        KeympsError, match=r"primitive 'line' \(icing\), but the task's tool is knife"
    ):
        keymps.run_task(
            task,
            overrides=RunOverrides(
                instruction="Make it nice",
                backend="scripted",
                executor="recording",
                out=tmp_path / "r",
            ),
        )
    assert RecordingExecutor.calls == []


def test_the_offline_planner_refuses_a_family_the_primitives_lack():
    scene = make_scene("disk", (200, 200))
    with pytest.raises(KeympsError, match="asks for icing"):
        plan_for("Put 10 icing dots around the bread", scene, primitives=CUTTING)
    with pytest.raises(KeympsError, match="asks for cutting"):
        plan_for("cut it into 8 slices", scene, primitives=ICING)


# --- the command line wins ---------------------------------------------------------------------


def test_model_on_the_command_line_uses_the_vlm_although_the_task_says_offline(monkeypatch):
    from keymps.planning.planner import choose_backend

    monkeypatch.setenv("OPENAI_API_KEY", "sk-test-value-000")
    scene = make_scene("disk", (100, 100))
    task = make_task("Cut it in half", scene, CUTTING, backend="offline")
    backend, reason = choose_backend(task, None, "openai/gpt-4o", None)
    assert backend == "litellm"
    assert "--model on the command line overrides the task's backend: offline" in reason
    backend, reason = choose_backend(task, None, "openai/x", "http://127.0.0.1:9")
    assert backend == "litellm" and "--model and --api-base" in reason
    assert choose_backend(task, "offline", "openai/gpt-4o", None)[0] == "offline"
    assert choose_backend(task, None, None, None)[0] == "offline"
    with pytest.raises(KeympsError, match="pass --model too"):
        choose_backend(task, None, None, "http://127.0.0.1:9")


# --- cuts that end just outside the object, as the prompts ask ---------------------------------


def _across_the_middle_beyond_the_edges(keyword: str, beyond_mm: float):
    """A scripted VLM: one vertical cut through the loaf's middle, ending `beyond_mm` outside
    its top and bottom edges (what prompts/cutting.md asks for)."""

    def answer(request) -> str:
        import json

        from keymps.designs.crop_shape import measure

        mm = tuple(1000 * m for m in request.metres_per_px)
        shape = measure(request.crop, request.crop_mask, mm)
        outline = shape.to_pixels(shape.outline.polygon)
        x = float(outline[:, 0].mean())
        column = outline[np.abs(outline[:, 0] - x) < 3]
        extra = beyond_mm / mm[1]
        y0, y1 = float(column[:, 1].min()) - extra, float(column[:, 1].max()) + extra
        pairs = [[[x, max(y0, 0.0)], [x, min(y1, request.crop_size_px[1])]]]
        return json.dumps({"keyword": keyword, "pairs": pairs, "design": None, "rationale": ""})

    return answer


@pytest.mark.parametrize("primitive", ["straight", "sawing", "downward", "forward"])
def test_a_cut_ending_5_mm_outside_the_object_runs_with_every_shipped_primitive(
    primitive, tmp_path, keymps_plugins
):
    from helpers.fuzz_support import RecordingExecutor, ScriptedBackend, install

    install(keymps_plugins)
    task = keymps.load_task(REPO / "tasks" / "object_cutting.yaml")
    scene = task.scene.model_copy(update={"image": REPO / "tasks" / "scenes" / "banana_bread.png"})
    task = task.model_copy(update={"primitives": [primitive], "scene": scene})
    ScriptedBackend.answers = [_across_the_middle_beyond_the_edges(primitive, 5.0)]
    run = keymps.run_task(task, options=RunOptions(rerun="off"), overrides=RunOverrides(instruction="Cut it in half", backend="scripted", executor="recording", out=tmp_path / "r"))  # fmt: skip
    assert len(RecordingExecutor.calls) == 1
    outside = run.stages.check.report.figures["max_work_outside_footprint_mm"]
    assert outside <= 20.0


def test_only_strokes_that_would_leave_the_margin_are_shortened():
    """The sawing primitive's strokes overshoot a cut's ends by about 16 mm: a cut ending on
    the edge keeps them, a cut ending 5 mm outside gets shorter strokes near its ends, and the
    whole work stays within the safety check's margin."""
    from keymps.motion.compose import keep_strokes_near
    from keymps.primitives.dictionary import default_search_dirs, load_primitives
    from keymps.robot.safety import FOOTPRINT_MARGIN_M
    from keymps.robot.safety_geometry import outside_distance

    sawing = load_primitives(["sawing"], default_search_dirs(REPO / "tasks"))["sawing"]
    angles = np.linspace(0, 2 * np.pi, 181)[:-1]
    outline = 0.05 * np.stack([np.cos(angles), np.sin(angles)], axis=1)  # a 10 cm object
    for beyond, changed in ((0.0, False), (0.005, True), (0.012, True)):
        start, goal = np.array([-0.05 - beyond, 0.0, 0.02]), np.array([0.05 + beyond, 0.0, 0.0])
        points = sawing.rollout(start, goal, speed=0.02, heading=0.0).y
        raw = outside_distance(points[:, :2], outline).max()
        kept = keep_strokes_near(points, start, goal, outline)
        limited = outside_distance(kept[:, :2], outline).max()
        assert (not np.array_equal(kept, points)) == changed, beyond
        assert limited <= FOOTPRINT_MARGIN_M - 0.002 + 1e-9
        if beyond > 0.01:
            assert raw > FOOTPRINT_MARGIN_M, "the unshortened strokes fail the check"
        assert np.allclose(kept[:, 2], points[:, 2])  # heights unchanged
        middle = np.abs(points[:, 0]) < 0.03
        assert np.array_equal(kept[middle], points[middle])  # strokes inside are untouched
