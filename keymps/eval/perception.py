"""The perception benchmark: detection on varied boards, empty boards, designs on photos.

Three measurements, each for the board detector and the paper's threshold detector:
- found: the chosen box within 3 px of the true box (keymps.scenes.perception_cases.flat_case);
- refused: an empty board stops at the detect stage;
- design error: a photo at 20-45 degrees goes the pipeline's way (its image, detect, plan and
  ground stages, keymps.pipeline.stages, with the offline planner) and each keypoint is
  compared, in board millimetres, with the same design laid out on the true object seen from
  straight above. The threshold detector goes the old way: the photo is not rectified
  (detector.roi = the board corners, the homography for grounding); its detect, plan and
  ground stages are the pipeline's.
`benchmarks/perception.py` runs it and prints the table docs/perception.md shows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.pipeline import stages
from keymps.scenes.perception_cases import BOARD_M, PhotoCase, flat_case, photo_case
from keymps.types import Detection, SceneImage

if TYPE_CHECKING:
    from keymps.plugin.components import Detector

BOX_TOLERANCE_PX = 3
DESIGN_TOLERANCE_MM = 1.5
INSTRUCTION = "Put 15 icing dots around the cake, leave space from the edge and between dots."


@dataclass
class Tally:
    cases: int = 0
    passed: int = 0
    worst: float = 0.0
    failures: list[str] = field(default_factory=list)

    def add(self, ok: bool, value: float, label: str) -> None:
        self.cases += 1
        self.passed += ok
        if np.isfinite(value):
            self.worst = max(self.worst, value)
        if not ok:
            self.failures.append(label)

    @property
    def rate(self) -> float:
        return self.passed / self.cases if self.cases else float("nan")


def _detector(name: str, options: dict[str, Any] | None = None) -> Detector:
    from keymps.plugin.manager import create_detector

    return create_detector(name, options or {})


def _detect(task: Any, detector: Detector, scene: SceneImage) -> stages.Perception | None:
    """The detect stage on `scene`, as a run does it; None when it refuses."""
    try:
        return stages.detected(task, scene, detector.detect(scene))
    except KeympsError:
        return None


def flat_benchmark(
    count: int, detectors: tuple[str, ...] = ("board", "threshold")
) -> dict[str, dict[str, Tally]]:
    """`count` boards: one in ten empty, one in seven with a hue-only object."""
    results = {
        name: {"found": Tally(), "refused": Tally(), "hue_only": Tally()} for name in detectors
    }
    built = {name: _detector(name) for name in detectors}
    task = _flat_task()
    for seed in range(count):
        empty, hue_only = seed % 10 == 9, seed % 7 == 3 and seed % 10 != 9
        case = flat_case(seed, empty=empty, hue_only=hue_only)
        for name, detector in built.items():
            found = _detect(task, detector, SceneImage(case.image, "board"))
            detection = found.detection if found is not None else None
            tallies = results[name]
            if empty:
                tallies["refused"].add(detection is None, 0.0, f"seed {seed}")
                continue
            assert case.truth_bbox is not None
            error = (
                float(np.abs(np.subtract(detection.bbox_px, case.truth_bbox)).max())
                if detection is not None
                else float("inf")
            )
            ok = error <= BOX_TOLERANCE_PX
            tallies["found"].add(ok, error, f"seed {seed}: error {error:g} px {case.variation}")
            if hue_only:
                tallies["hue_only"].add(ok, error, f"seed {seed}")
    return results


def _flat_task() -> Any:
    """A task on a top-down board of the flat cases' size (no camera: nothing rectified)."""
    from keymps.config.task import Task

    return Task.model_validate(
        {
            "name": "perception-benchmark",
            "instruction": INSTRUCTION,
            "scene": {"image": "board.png", "workspace": {"size": list(BOARD_M)}},
            "primitives": ["line"],
        }
    )


def _task(case: PhotoCase, corners: np.ndarray, intrinsics: bool, detector: dict[str, Any]) -> Any:
    from keymps.config.task import Task

    camera: dict[str, Any] = {"board_corners_px": corners.tolist()}
    if intrinsics:
        camera["intrinsics"] = case.intrinsics
    return Task.model_validate(
        {
            "name": "perception-benchmark",
            "instruction": INSTRUCTION,
            "scene": {
                "image": "photo.png",
                "workspace": {"size": list(BOARD_M)},
                "object_height": case.object_height,
                "camera": camera,
            },
            "detector": detector,
            "primitives": ["line"],
        }
    )


def _design_m(task: Any, perception: stages.Perception) -> np.ndarray:
    """The dots of the offline planner's design, planned and grounded the way a run does."""
    import tempfile
    from pathlib import Path

    from keymps.planning.backend_choice import AUTO_OFFLINE
    from keymps.run import Run

    with tempfile.TemporaryDirectory(prefix="keymps-perception-") as folder:
        run = Run(task=task, folder=Path(folder))
        plan = stages.plan(task, perception, _primitives(task), run, AUTO_OFFLINE)
    return stages.ground(task, perception, plan).segments_m[:, 0, :2]


_PRIMITIVES: dict[tuple[str, ...], Any] = {}


def _primitives(task: Any) -> Any:
    """The task's primitives, read once per process (parsing a primitive's YAML is slow)."""
    key = tuple(task.primitives)
    if key not in _PRIMITIVES:
        _PRIMITIVES[key] = stages.load_primitives(task)
    return _PRIMITIVES[key]


def _reference_m(case: PhotoCase) -> np.ndarray:
    """The design on the true object, seen from straight above (its true mask)."""
    flat = case.flat
    assert flat.object_alpha is not None and flat.truth_bbox is not None
    mask = flat.object_alpha >= 0.5
    x0, y0, x1, y1 = flat.truth_bbox
    pad = 10
    image = np.clip(np.rint(flat.image), 0, 255).astype(np.uint8)
    detection = Detection(
        bbox_px=flat.truth_bbox,
        crop=image[max(0, y0 - pad) : y1 + pad, max(0, x0 - pad) : x1 + pad],
        crop_origin_px=(max(0, x0 - pad), max(0, y0 - pad)),
        mask=mask,
    )
    task = _task(case, case.corners_px, False, {"name": "board"})
    camera = task.scene.camera.model_copy(update={"board_corners_px": None})
    task = task.model_copy(update={"scene": task.scene.model_copy(update={"camera": camera})})
    truth = stages.detected(task, SceneImage(image, "truth"), detection)
    return _design_m(task, truth)


def _photo_design_error(case: PhotoCase, method: str) -> float:
    """Largest keypoint distance (mm) from the reference; inf when no design came out."""
    from keymps.perception.markers import find_board_corners

    try:
        corners = find_board_corners(case.photo).corners_px if case.markers else case.corners_px
        photo = SceneImage(case.photo, "photo")
        if method == "threshold":  # the old way: the photo as it is
            task = _task(case, corners, False, {"name": "threshold", "roi": corners.tolist()})
            perception = _detect(task, _detector("threshold", {"roi": corners.tolist()}), photo)
        else:
            intrinsics = method == "board+intrinsics"
            task = _task(case, corners, intrinsics, {"name": "board"})
            perception = _detect(task, _detector("board"), stages.rectified(task, photo))
        if perception is None:
            return float("inf")
        found = _design_m(task, perception)
    except KeympsError:
        return float("inf")
    reference = _reference_m(case)
    if found.shape != reference.shape:
        return float("inf")
    return design_error_mm(found, reference)


def design_error_mm(found: np.ndarray, reference: np.ndarray) -> float:
    """How far a ring of dots is from where it belongs: the largest distance of a dot from
    the reference ring (the closed path through its dots), or of the rings' centres. Where
    on its ring the first dot falls is free (a round cake has no "front")."""
    from scipy.interpolate import CubicSpline

    closed = np.vstack([reference, reference[:1]])
    along = np.r_[0, np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]
    ring = CubicSpline(along, closed, bc_type="periodic")
    path = ring(np.linspace(0, along[-1], 40 * len(reference) + 1))
    a, b = path[:-1], path[1:]
    ab = b - a
    ap = found[:, None, :] - a[None]
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0, 1)
    off_ring = np.linalg.norm(ap - t[..., None] * ab[None], axis=-1).min(axis=1).max()
    centre = np.linalg.norm(found.mean(axis=0) - reference.mean(axis=0))
    return float(max(off_ring, centre) * 1000)


PHOTO_METHODS = ("board+intrinsics", "board", "threshold")


def photo_benchmark(
    count: int, methods: tuple[str, ...] = PHOTO_METHODS
) -> dict[str, dict[str, Tally]]:
    """`count` photos of objects with height and `count` of flat prints, half with markers."""
    results: dict[str, dict[str, Tally]] = {m: {"tall": Tally(), "flat": Tally()} for m in methods}
    for seed in range(count):
        for kind, flat_object in (("tall", False), ("flat", True)):
            case = photo_case(seed, markers=seed % 2 == 0, flat_object=flat_object)
            for method in methods:
                error = _photo_design_error(case, method)
                label = (
                    f"seed {seed} tilt {case.tilt_deg:.0f} height {case.object_height * 1000:.0f} mm "
                    f"markers {case.markers}: {error:.2f} mm"
                )
                results[method][kind].add(error <= DESIGN_TOLERANCE_MM, error, label)
    return results


def table(flat: dict[str, dict[str, Tally]], photos: dict[str, dict[str, Tally]]) -> str:
    """Markdown table of both benchmarks."""

    def rate(tally: Tally) -> str:
        return f"{100 * tally.rate:.1f} % ({tally.passed}/{tally.cases})"

    lines = [
        "| detector | objects found within 3 px | hue-only objects | empty boards refused |",
        "|---|---|---|---|",
    ]
    for name, tallies in flat.items():
        lines.append(
            f"| `{name}` | {rate(tallies['found'])} | {rate(tallies['hue_only'])} | "
            f"{rate(tallies['refused'])} |"
        )
    lines += [
        "",
        "| method (photos at 20-45 degrees) | object 20-60 mm tall: designs within 1.5 mm | worst | "
        "flat print: within 1.5 mm | worst |",
        "|---|---|---|---|---|",
    ]
    names = {
        "board+intrinsics": "`board`, rectified on the top plane (corners + intrinsics)",
        "board": "`board`, rectified on the board plane (corners only)",
        "threshold": "`threshold` with `roi` = corners, homography grounding",
    }
    for method, tallies in photos.items():
        tall, flat_print = tallies["tall"], tallies["flat"]
        lines.append(
            f"| {names.get(method, method)} | {rate(tall)} | {_mm(tall.worst, tall)} | "
            f"{rate(flat_print)} | {_mm(flat_print.worst, flat_print)} |"
        )
    return "\n".join(lines)


def _mm(value: float, tally: Tally) -> str:
    missing = tally.cases - tally.passed
    text = f"{value:.2f} mm"
    return (
        text if not tally.failures or missing == 0 else f"{text} (failures: {len(tally.failures)})"
    )
