"""`keymps calibrate`: ArUco markers at the board's corners -> the scene.camera block."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from keymps.cli.app import cli
from keymps.config.task import Task
from keymps.perception.markers import CORNER_NAMES, find_board_corners
from keymps.scenes.perception_cases import photo_case


@pytest.fixture(scope="module")
def photo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    case = photo_case(4, markers=True)
    path = tmp_path_factory.mktemp("calibrate") / "photo.png"
    cv2.imwrite(str(path), case.photo)
    return path, case


def calibrate(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(cli, ["calibrate", *args])
    return result.exit_code, result.stdout, result.stderr


def test_the_markers_give_the_board_corners_and_a_task_accepts_the_block(
    photo: tuple[Path, object], tmp_path: Path
) -> None:
    path, case = photo
    out = tmp_path / "camera.yaml"
    code, stdout, stderr = calibrate(
        str(path), "--board", "0.30,0.18", "--marker-size", "40", "--out", str(out)
    )
    assert code == 0, stderr
    assert stdout.strip() == f"wrote {out}" and stderr == ""
    block = yaml.safe_load(out.read_text())
    corners = np.array(block["scene"]["camera"]["board_corners_px"])
    assert np.abs(corners - case.corners_px).max() < 0.6  # type: ignore[attr-defined]
    task = Task.model_validate(
        {
            "name": "t",
            "instruction": "x",
            "primitives": ["line"],
            "scene": {"image": "p.png", **block["scene"]},
        }
    )
    assert task.scene.workspace.size == (0.30, 0.18) and task.scene.camera.mm_per_px == 0.5
    assert "(40 mm printed)" in out.read_text()


def test_intrinsics_add_the_camera_pose(photo: tuple[Path, object]) -> None:
    path, case = photo
    given = case.intrinsics  # type: ignore[attr-defined]
    camera = f"{given['fx']},{given['fy']},{given['cx']},{given['cy']}"
    distortion = ",".join(str(v) for v in given["distortion"])
    code, stdout, stderr = calibrate(
        str(path), "--board", "0.30,0.18", "--marker-size", "40",
        "--intrinsics", camera, "--distortion", distortion,
    )  # fmt: skip
    assert code == 0, stderr
    assert "# camera at (" in stdout and "degrees from straight down" in stdout
    tilt = float(stdout.split("degrees from straight down")[0].split()[-1])
    assert tilt == pytest.approx(case.tilt_deg, abs=1.5)  # type: ignore[attr-defined]
    block = yaml.safe_load(stdout)
    assert block["scene"]["camera"]["intrinsics"]["fx"] == pytest.approx(given["fx"], rel=1e-5)


def test_a_wrong_board_size_is_noticed_from_the_markers(photo: tuple[Path, object]) -> None:
    path, _ = photo
    code, _, stderr = calibrate(str(path), "--board", "0.38,0.24", "--marker-size", "40")
    assert code == 0
    assert "warning: the markers measure" in stderr and "check --board" in stderr


def test_missing_and_doubled_markers_are_named(photo: tuple[Path, object], tmp_path: Path) -> None:
    path, case = photo
    image = cv2.imread(str(path))
    found = find_board_corners(image)
    covered = image.copy()
    top_right = found.marker_corners_px[2]
    x0, y0 = np.floor(top_right.min(axis=0)).astype(int) - 4
    x1, y1 = np.ceil(top_right.max(axis=0)).astype(int) + 4
    covered[y0:y1, x0:x1] = 200
    cv2.imwrite(str(tmp_path / "covered.png"), covered)
    code, _, stderr = calibrate(str(tmp_path / "covered.png"), "--board", "0.30,0.18")
    assert code == 1
    assert stderr.startswith(
        f"error: {tmp_path / 'covered.png'}: marker 2 (top-right) not found (found: 0, 1, 3)"
    )
    doubled = image.copy()
    bottom_right = found.marker_corners_px[1]
    x0, y0 = np.floor(bottom_right.min(axis=0)).astype(int) - 6
    x1, y1 = np.ceil(bottom_right.max(axis=0)).astype(int) + 6
    patch = image[y0:y1, x0:x1].copy()
    doubled[20 : 20 + patch.shape[0], 20 : 20 + patch.shape[1]] = patch
    cv2.imwrite(str(tmp_path / "doubled.png"), doubled)
    code, _, stderr = calibrate(str(tmp_path / "doubled.png"), "--board", "0.30,0.18")
    assert code == 1
    assert "marker 1 (bottom-right) at (" in stderr and "must appear once" in stderr
    assert "Traceback" not in stderr


def test_the_printed_sheet_holds_the_four_markers_at_their_size(tmp_path: Path) -> None:
    sheet = tmp_path / "markers.png"
    code, stdout, _ = calibrate("--print-markers", str(sheet), "--marker-size", "50")
    assert code == 0 and "50 mm squares" in stdout
    page = cv2.imread(str(sheet), cv2.IMREAD_GRAYSCALE)
    assert page.shape == (round(297 * 300 / 25.4), round(210 * 300 / 25.4))
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _ = detector.detectMarkers(page)
    assert sorted(ids.ravel().tolist()) == [0, 1, 2, 3]
    side_px = np.linalg.norm(np.diff(corners[0][0], axis=0), axis=1).mean()
    assert side_px * 25.4 / 300 == pytest.approx(50, abs=0.3)


def test_usage_errors_are_one_line(tmp_path: Path) -> None:
    code, _, stderr = calibrate(str(tmp_path / "none.png"), "--board", "0.3,0.18")
    assert code == 1 and "none.png" in stderr and "Traceback" not in stderr
    code, _, stderr = calibrate(str(tmp_path / "none.png"))
    assert code == 2 and "--board" in stderr
    code, _, stderr = calibrate(str(tmp_path / "x.png"), "--board", "0.3")
    assert code == 2 and "--board: 2 numbers" in stderr
    code, _, stderr = calibrate(
        str(tmp_path / "x.png"), "--board", "0.3,0.2", "--distortion", "0,0,0,0"
    )
    assert code == 2 and "--distortion needs --intrinsics" in stderr
    code, _, stderr = calibrate("--print-markers", str(tmp_path / "sheet.jpg"))
    assert code == 1 and "written as PNG" in stderr


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--mm-per-px", "0"], "0.05<=x<=10"),
        (["--mm-per-px", "1e-9"], "0.05<=x<=10"),
        (["--mm-per-px", "nan"], "'nan' is not a finite number"),
        (["--mm-per-px", "inf"], "0.05<=x<=10"),
        (["--intrinsics", "nan,1,1,1"], "--intrinsics: every number must be finite"),
        (["--intrinsics", "0,0,0,0"], "--intrinsics: fx and fy are positive pixels"),
        (["--intrinsics", "-500,500,300,200"], "--intrinsics: fx and fy are positive pixels"),
        (["--distortion", "inf,0,0,0", "--intrinsics", "500,500,300,200"], "must be finite"),
    ],
)
def test_settings_a_task_would_refuse_are_refused_before_the_photo_is_read(
    arguments: list[str], message: str, tmp_path: Path
) -> None:
    """Once printed as a scene.camera block (mm_per_px: nan) with exit status 0."""
    code, stdout, stderr = calibrate(str(tmp_path / "none.png"), "--board", "0.3,0.2", *arguments)
    assert code == 2 and message in stderr, stderr
    assert stdout == "" and "Traceback" not in stderr


def test_a_board_of_no_size_is_refused(tmp_path: Path) -> None:
    for board in ("0,0.2", "0.3,-0.2", "nan,0.2"):
        code, _, stderr = calibrate(str(tmp_path / "none.png"), "--board", board)
        assert code == 2 and "--board" in stderr, stderr


def _board_with_markers(order: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """A board seen at an angle with markers `order` at its bottom-left, bottom-right,
    top-right and top-left corners (as in the photo)."""
    from keymps.perception.markers import marker_image

    image = np.full((900, 1200), 235, np.uint8)
    x0, y0, x1, y1 = 250, 200, 950, 700
    image[y0:y1, x0:x1] = 150
    side = 90
    places = [(x0 - side, y1), (x1, y1), (x1, y0 - side), (x0 - side, y0 - side)]
    for marker_id, (x, y) in zip(order, places, strict=True):
        image[y : y + side, x : x + side] = marker_image(marker_id, side)
    frame = np.float32([[0, 0], [1200, 0], [1200, 900], [0, 900]])
    seen = frame + rng.uniform(-60, 60, size=(4, 2)).astype(np.float32)
    return cv2.warpPerspective(
        image, cv2.getPerspectiveTransform(frame, seen), (1200, 900), borderValue=235
    )


def test_markers_out_of_order_are_named_for_every_placement(tmp_path: Path) -> None:
    """Was: the printed sheet, or two markers swapped, gave 'the four corners must be ... of a
    convex quadrilateral' naming no marker. Every placement of markers 0-3 at the corners,
    seen at a random angle: the four that go round the board in order (a camera turned by a
    multiple of 90 degrees) are accepted, the other twenty are refused naming each marker."""
    import itertools

    from keymps.errors import KeympsError

    rng = np.random.default_rng(7)
    accepted = []
    for order in itertools.permutations(range(4)):
        image = _board_with_markers(order, rng)
        try:
            find_board_corners(image, "photo.png")
        except KeympsError as error:
            message = str(error)
            assert message.startswith("photo.png: markers 0-3 are out of order: 0 (bottom-left)")
            assert "\n" not in message and "convex" not in message
            assert all(f"{i} ({name})" in message for i, name in enumerate(CORNER_NAMES))
        else:
            accepted.append(order)
    assert sorted(accepted) == [(0, 1, 2, 3), (1, 2, 3, 0), (2, 3, 0, 1), (3, 0, 1, 2)]


def test_a_photo_of_the_printed_sheet_is_refused_as_markers_out_of_order(tmp_path: Path) -> None:
    sheet = tmp_path / "markers.png"
    assert calibrate("--print-markers", str(sheet))[0] == 0
    code, _, stderr = calibrate(str(sheet), "--board", "0.38,0.24")
    assert code == 1 and stderr.count("\n") == 1
    assert "markers 0-3 are out of order" in stderr and "cut the markers out" in stderr
