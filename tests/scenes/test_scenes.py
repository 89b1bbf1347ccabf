"""Synthetic scenes: determinism, true geometry in the sidecar, the CLI, the shipped scenes."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from keymps.cli.scene import scene as scene_cli
from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.perception.frames import ImageFrame, polygon_area
from keymps.scenes.render import KINDS, SceneSpec, render_scene

TASKS = Path(__file__).resolve().parents[2] / "tasks"

SHIPPED = {
    # file name -> the documented `keymps scene render` arguments (docs/perception.md)
    "round_cake": ["round_cake", "--length", "0.12", "--height", "0.06", "--seed", "0"],
    "pizza": ["round_pizza", "--length", "0.15", "--height", "0.02", "--seed", "1"],
    "banana_bread": [
        "banana_bread", "--length", "0.18", "--width", "0.09", "--height", "0.08", "--seed", "0",
    ],
}  # fmt: skip


def task_for(board: tuple[float, float]) -> Task:
    return Task.model_validate(
        {
            "name": "t",
            "instruction": "x",
            "scene": {"image": "x.png", "workspace": {"size": list(board)}},
            "primitives": ["a"],
        }
    )


def test_same_spec_same_pixels_other_seed_other_scene() -> None:
    spec = SceneSpec.from_kinds(["eggplant"], seed=5, px_per_m=800)
    first, again = render_scene(spec), render_scene(spec)
    np.testing.assert_array_equal(first.image, again.image)
    assert first.truth == again.truth
    other = render_scene(SceneSpec.from_kinds(["eggplant"], seed=6, px_per_m=800))
    assert np.abs(other.image.astype(int) - first.image).mean() > 5


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_sidecar_outline_grounds_within_a_millimetre(kind: str) -> None:
    """The sidecar's outline in pixels, through the Appendix B frame, is its outline in metres."""
    scene = render_scene(SceneSpec.from_kinds([kind], seed=3, px_per_m=2000))
    truth = scene.truth
    (obj,) = truth["objects"]
    assert truth["image_size_px"] == [600, 360]
    assert truth["px_per_m"] == [2000.0, 2000.0]
    frame = ImageFrame.from_task(task_for((0.30, 0.18)), (600, 360))
    grounded = frame.to_board(np.array(obj["outline_px"]))
    outline = np.array(obj["outline_m"])
    assert np.abs(grounded - outline).max() < 0.001
    # The metric geometry is what the object's dimensions say.
    extent = outline.max(axis=0) - outline.min(axis=0)
    angle = np.radians(obj["rotation_deg"])
    local = (outline - obj["centre_m"]) @ np.array(
        [[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]
    )
    local_extent = local.max(axis=0) - local.min(axis=0)
    assert local_extent[0] == pytest.approx(obj["length_m"], rel=0.05)
    if KINDS[kind].shape.bend == 0:
        assert local_extent[1] == pytest.approx(obj["width_m"], rel=0.08)
    assert np.all(outline.min(axis=0) > 0) and np.all(outline.max(axis=0) < (0.30, 0.18))
    assert obj["bbox_m"] == pytest.approx([*outline.min(axis=0), *outline.max(axis=0)], abs=1e-6)
    assert extent.max() < 0.30
    # The true box holds the pixels at least half inside the outline.
    x0, y0, x1, y1 = obj["bbox_px"]
    px = np.array(obj["outline_px"])
    assert np.all(np.abs([x0, y0] - px.min(axis=0)) <= 1.0)
    assert np.all(np.abs([x1, y1] - px.max(axis=0)) <= 1.0)
    assert abs(polygon_area(outline)) > 0


def test_round_cake_has_the_requested_size() -> None:
    spec = SceneSpec.from_kinds(["round_cake"], length=0.12, height=0.06, seed=0)
    (obj,) = render_scene(spec).truth["objects"]
    outline = np.array(obj["outline_m"])
    radii = np.linalg.norm(outline - obj["centre_m"], axis=1)
    np.testing.assert_allclose(radii, 0.06, atol=1e-6)
    assert obj["height_m"] == 0.06
    assert obj["area_m2"] == pytest.approx(np.pi * 0.06**2, rel=1e-3)


def test_the_board_is_the_most_common_intensity_and_objects_stand_out() -> None:
    for kind in KINDS:
        scene = render_scene(SceneSpec.from_kinds([kind], seed=11, px_per_m=800))
        gray = cv2.GaussianBlur(cv2.cvtColor(scene.image, cv2.COLOR_BGR2GRAY), (5, 5), 0)
        mode = int(np.bincount(gray.ravel(), minlength=256).argmax())
        assert 115 <= mode <= 137, kind


def test_several_objects_are_placed_apart() -> None:
    kinds = ["potato", "baumkuchen", "potato"]
    scene = render_scene(SceneSpec.from_kinds(kinds, seed=1, board_size=(0.40, 0.18)))
    boxes = [obj["bbox_m"] for obj in scene.truth["objects"]]
    assert [obj["kind"] for obj in scene.truth["objects"]] == kinds
    for left, right in zip(boxes, boxes[1:], strict=False):
        assert left[2] < right[0]  # left to right, no overlap


def test_errors_name_the_problem() -> None:
    with pytest.raises(KeympsError, match=r"unknown object 'dragonfruit' \(available: baguette"):
        SceneSpec.from_kinds(["dragonfruit"])
    with pytest.raises(KeympsError, match=r"eggplant .* does not fit on the 0.3 x 0.18 m board"):
        render_scene(SceneSpec.from_kinds(["eggplant"], length=0.40))
    long_board = SceneSpec.from_kinds(["eggplant"], length=0.40, board_size=(0.50, 0.20))
    assert render_scene(long_board).image.shape == (400, 1000, 3)
    with pytest.raises(KeympsError, match="between 32 and 8000 px"):
        render_scene(SceneSpec.from_kinds(["potato"], px_per_m=100))
    assert SceneSpec.from_kinds(["Round-Cake"]).objects[0].kind == "round_cake"


def test_cli_render_writes_png_and_sidecar(tmp_path: Path) -> None:
    out = tmp_path / "egg.png"
    result = CliRunner().invoke(
        scene_cli,
        ["render", "eggplant", "--length", "0.25", "--seed", "3", "--board", "0.36,0.2",
         "--px-per-m", "1000", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(out))
    assert image.shape == (200, 360, 3)
    truth = json.loads(out.with_suffix(".json").read_text())
    assert truth["board_size_m"] == [0.36, 0.2]
    assert truth["objects"][0]["length_m"] == 0.25
    assert "eggplant: 25.0 x" in result.output

    bad = CliRunner().invoke(scene_cli, ["render", "durian", "--out", str(out)])
    assert bad.exit_code == 1 and "unknown object 'durian'" in bad.output
    too_big = CliRunner().invoke(
        scene_cli, ["render", "baguette", "--length", "0.45", "--out", str(out)]
    )
    assert too_big.exit_code == 1 and "does not fit" in too_big.output
    listing = CliRunner().invoke(scene_cli, ["list"])
    assert listing.exit_code == 0 and listing.output.count("\n") == len(KINDS)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_scenes_are_reproduced_by_their_documented_command(
    name: str, tmp_path: Path
) -> None:
    out = tmp_path / f"{name}.png"
    result = CliRunner().invoke(scene_cli, ["render", *SHIPPED[name], "--out", str(out)])
    assert result.exit_code == 0, result.output
    shipped = cv2.imread(str(TASKS / "scenes" / f"{name}.png"))
    rendered = cv2.imread(str(out))
    difference = np.abs(shipped.astype(int) - rendered)
    # Bit-identical on the machine that made them; allow last-bit float differences elsewhere.
    assert difference.max() <= 1 and (difference > 0).mean() < 0.001
    shipped_truth = json.loads((TASKS / "scenes" / f"{name}.json").read_text())
    rendered_truth = json.loads(out.with_suffix(".json").read_text())
    assert shipped_truth["objects"][0]["bbox_px"] == rendered_truth["objects"][0]["bbox_px"]
    np.testing.assert_allclose(
        shipped_truth["objects"][0]["outline_m"],
        rendered_truth["objects"][0]["outline_m"],
        atol=1e-6,
    )


def test_the_render_cache_returns_the_same_scene_as_a_private_copy() -> None:
    from keymps.scenes.render import render_scene_cached

    spec = SceneSpec.from_kinds(["eggplant"], seed=31)
    fresh = render_scene(spec)
    first = render_scene_cached(spec)
    again = render_scene_cached(spec)
    assert np.array_equal(first.image, fresh.image) and first.truth == fresh.truth
    assert np.array_equal(again.image, fresh.image) and again.truth == fresh.truth
    first.image[:] = 0  # a caller drawing on its image changes nobody else's
    first.truth["objects"][0]["kind"] = "changed"
    third = render_scene_cached(spec)
    assert np.array_equal(third.image, fresh.image) and third.truth == fresh.truth
    other = render_scene_cached(SceneSpec.from_kinds(["eggplant"], seed=32))
    assert not np.array_equal(other.image, fresh.image)


@pytest.mark.parametrize(
    ("option", "value"),
    [
        (option, value)
        for option in ("--length", "--width", "--height", "--rotation")
        for value in ("nan", "inf", "-inf")
    ]  # fmt: skip
    + [("--board", "nan,0.2"), ("--board", "0.3,inf")],
)
def test_render_refuses_numbers_that_are_not_finite(
    option: str, value: str, tmp_path: Path
) -> None:
    """click's FloatRange lets nan through its bounds: it reached numpy as a 0 x 0 mask."""
    out = tmp_path / "x.png"
    result = CliRunner().invoke(
        scene_cli, ["render", "round_cake", option, value, "--out", str(out)]
    )
    assert result.exit_code == 2, result.output
    assert f"Invalid value for '{option}'" in result.output or "two positive" in result.output
    assert any(words in result.output for words in ("finite", "range", "positive")), result.output
    assert not isinstance(result.exception, Exception) or isinstance(result.exception, SystemExit)
    assert not out.exists()
