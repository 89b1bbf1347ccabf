"""The default detector: the object is what differs from a model of the board, in colour.

1. The board's colour is fitted where the board must be, a band along the border of the
   searched area, as a smooth surface in CIE Lab (keymps.perception.board_model): lighting
   gradients and vignetting are part of the board.
2. Every pixel's distance to that surface, forgiving half of a darkening (soft shadows).
3. A threshold from the board's own noise, raised for each object to half its own contrast
   (so the edge falls where a pixel is half object, as the true box is drawn; a faint object
   beside a bright one keeps its own edge), or the task's.
4. Regions: crumbs (under min_area) are dropped; a region that touches three or more sides of
   the searched area, or covers most of it, is the board (or the table), never an object: the
   detection stops there. Every remaining region is an object, in Detection.objects, numbered
   left to right, then top to bottom; the largest gives the detection its own box. `pick` keeps
   one of them only (by decreasing area), warning about others of its size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from keymps.perception.board_model import (
    BoardModel,
    board_in_shadow,
    distance_to_board,
    fit_board,
    lab_planes,
    prepare_lab_tables,
    to_lab,
)
from keymps.perception.board_on_table import board_holding_an_object
from keymps.perception.image_io import to_bgr8
from keymps.perception.search_area import (
    SearchArea,
    comparable_object_warnings,
    odd_kernel,
    roi_polygon,
)
from keymps.plugin import DetectionError, RegisterDetector, hookimpl
from keymps.plugin import parse_options as plugin_options
from keymps.sorted_values import median, percentile
from keymps.types import DetectedObject, Detection, SceneImage

NOISE_FACTOR = 1.5
"""The automatic threshold is at least this times the board's 99.5th-percentile distance."""
MIN_THRESHOLD = 3.0
"""Lab units: below this no camera tells board from object."""
TEXTURE_CONTRAST = 1.6
"""A region whose median distance is under this times the noise threshold is board texture."""


class BoardOptions(BaseModel):
    """The detector section of a task file (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    threshold: float | None = Field(default=None, gt=0, le=200)
    """Lab distance (Delta E) a pixel must be from the board model to be object; automatic
    when not given (see the module docstring)."""
    blur: int = Field(default=5, ge=0, le=99)
    """Gaussian kernel size in pixels (odd) before the colour comparison; 0 or 1: none."""
    padding: int = Field(default=10, ge=0, le=10_000)
    """Pixels added around the box for the crop sent to the planner."""
    min_area: int | None = Field(default=None, ge=1)
    """Regions smaller than this many pixels are crumbs; default 0.1 % of the searched area
    (at least 50 px)."""
    border: int | None = Field(default=None, ge=1, le=1000)
    """Width in pixels of the band along the searched area's border where the board is
    sampled; default 2 % of the area's shorter side (at least 3 px)."""
    edge: int = Field(default=2, ge=0, le=100)
    """Pixels along the searched area's border left out of every region: the board's own
    edge, blended with the table in a rectified photo."""
    surface: int = Field(default=2, ge=0, le=3)
    """Degree of the polynomial the board's colour follows across the image (0: uniform,
    1: a linear lighting gradient, 2: also vignetting)."""
    shadow: float = Field(default=0.5, ge=0, lt=1)
    """Fraction of a pixel's darkening forgiven (a soft shadow); 0 counts it in full."""
    max_coverage: float = Field(default=0.75, gt=0, le=1)
    """A region covering more than this fraction of the searched area is the board."""
    comparable: float = Field(default=0.5, gt=0, le=1)
    """With `pick`: another region at least this fraction of the picked one's area triggers
    a warning."""
    pick: int | None = Field(default=None, ge=0)
    """Keep only this object, by index in order of decreasing area (0 = the largest); by
    default every object is kept (the planner addresses them)."""
    roi: list[tuple[float, float]] | None = None
    """Search only inside this polygon of image pixels, or box [x0, y0, x1, y1]."""
    board_on_table: bool = True
    """Refuse a large four-sided region that holds a region of another colour: a board
    photographed on a darker table (keymps.perception.board_on_table); false takes it as the
    object (a square cake with a decoration)."""

    _polygon = field_validator("roi", mode="before")(roi_polygon)
    _odd = field_validator("blur")(odd_kernel)


def parse_options(options: dict[str, Any]) -> BoardOptions:
    """Validate the task file's detector options; one clear line per bad option."""
    return plugin_options(BoardOptions, options, "board detector")


@dataclass(frozen=True)
class Region:
    """One connected area that differs from the board."""

    contour: np.ndarray
    """(N, 2) boundary pixel indices (OpenCV's external contour)."""
    mask: np.ndarray
    """Bool H x W, filled (holes included)."""
    area: float
    bbox: tuple[int, int, int, int]
    coverage: float
    """Fraction of the searched area."""
    sides: tuple[str, ...]
    along: float
    """The largest fraction of one side's length the region runs along."""
    contrast: float
    """Median distance to the board model inside the region, Lab."""
    edge_contrast: float
    """Median distance 3 to 7 px inside its edge (past the blur): what places the edge."""

    def describe(self) -> dict[str, Any]:
        return {
            "bbox_px": list(self.bbox),
            "area_px": round(self.area, 1),
            "coverage": round(self.coverage, 4),
            "sides_touched": list(self.sides),
            "along_side": round(self.along, 3),
            "contrast": round(self.contrast, 2),
            "edge_contrast": round(self.edge_contrast, 2),
        }


class BoardDetector:
    """Detects objects against a colour model of the board (see the module docstring)."""

    def __init__(self, options: BoardOptions | None = None):
        self.options = options or BoardOptions()

    def detect(self, scene: SceneImage | np.ndarray) -> Detection:
        """The objects on the board, the largest (or `pick`) as the detection's own box.

        Raises:
            DetectionError: an empty image, the board taken for an object, or no object.
        """
        image, lab = _image_and_lab(scene, self.options.blur)
        height, width = image.shape[:2]
        area = SearchArea.of((width, height), self.options.roi)
        distance, board, board_image, noise, shadow_px = self._board_distance(lab, area)
        min_area = self.min_area(area)
        bands = self._side_bands(area, distance)
        t_noise = max(MIN_THRESHOLD, NOISE_FACTOR * noise)
        first = self._regions(distance > t_noise, distance, area, bands, min_area)
        threshold, how, above = self._threshold(first, distance, t_noise, noise)
        report: dict[str, Any] = {
            "detector": "board",
            "searched_area": {"polygon_px": area.polygon.round(2).tolist(), "pixels": area.pixels},
            "board_model": board.describe(board_image) | {"noise_p995": round(noise, 3)},
            "threshold": {"value": round(threshold, 3), "how": how},
            "shadow_px": shadow_px,
            "min_area_px": min_area,
            "regions": [],
        }
        regions = self._regions(above, distance, area, bands, min_area)
        objects = self._objects(regions, lab, t_noise, report)
        if not objects:
            raise DetectionError(_nothing_found(min_area, threshold, how, shadow_px))
        chosen, numbered = self._choose(objects, report)
        return Detection(
            bbox_px=chosen.bbox,
            crop=_crop(image, chosen.bbox, self.options.padding),
            crop_origin_px=_crop_origin(chosen.bbox, self.options.padding),
            contour_px=chosen.contour.astype(float),
            mask=chosen.mask,
            others_px=tuple(r.bbox for r in objects if r is not chosen),
            warnings=tuple(_warnings(chosen, self.options.pick, objects, self.options)),
            objects=tuple(
                DetectedObject(
                    id=i + 1,
                    bbox_px=r.bbox,
                    contour_px=r.contour.astype(float),
                    area_px=r.area,
                    mask=r.mask,
                )
                for i, r in enumerate(numbered)
            ),
            report=report,
        )

    def _side_bands(self, area: SearchArea, distance: np.ndarray) -> list[np.ndarray]:
        """Where a region touches each side; the left-out edge zeroed in `distance` (in place)."""
        # a region touches a side when it reaches the first 1.5 px inside the left-out edge
        bands = area.side_bands(1.5 + self.options.edge)
        if self.options.edge:
            distance[area.border_band(self.options.edge)] = 0.0
            left_out = area.side_bands(self.options.edge)
            bands = [band & ~out for band, out in zip(bands, left_out, strict=True)]
        return bands

    def _threshold(
        self, first: list[Region], distance: np.ndarray, t_noise: float, noise: float
    ) -> tuple[float, str, np.ndarray]:
        """The threshold, how it was chosen, and the pixels above it (per region, when automatic)."""
        if self.options.threshold is not None:
            threshold = float(self.options.threshold)
            return threshold, "detector.threshold", distance > threshold
        candidates = [
            r for r in first if r.contrast >= TEXTURE_CONTRAST * t_noise or _board(r, self.options)
        ]
        if not candidates:
            how = f"automatic: {NOISE_FACTOR:g} x the board's noise {noise:.2f}"
            return t_noise, how, distance > t_noise
        strongest = max(candidates, key=lambda r: r.area)
        threshold = max(t_noise, 0.5 * strongest.edge_contrast)
        how = (
            "automatic: each region at half its own edge contrast (the largest "
            f"{strongest.edge_contrast:.1f}), at least {NOISE_FACTOR:g} x the board's noise "
            f"{noise:.2f}"
        )
        objects_first = [r for r in candidates if not _board(r, self.options)]
        above = _each_at_half_its_contrast(first, objects_first, distance, threshold, t_noise)
        return threshold, how, above

    def _objects(
        self, regions: list[Region], lab: np.ndarray, t_noise: float, report: dict[str, Any]
    ) -> list[Region]:
        """The regions that are objects, each region's verdict added to `report`.

        Raises:
            DetectionError: a region is the board (or the table) rather than an object.
        """
        objects, board_like = [], []
        for region in regions:
            entry = region.describe()
            why = _board_reason(region, self.options) if _board(region, self.options) else None
            if why is None and self.options.board_on_table:
                why = board_holding_an_object(region.mask, region.contour, region.coverage, lab)
            if why is not None:
                entry["verdict"] = "board"
                entry["why"] = why
                board_like.append((region, why))
            elif self.options.threshold is None and region.contrast < TEXTURE_CONTRAST * t_noise:
                entry["verdict"] = "texture"
                entry["why"] = (
                    f"median contrast {region.contrast:.1f} is under {TEXTURE_CONTRAST:g} x the "
                    f"noise threshold {t_noise:.1f}: grain or a stain of the board"
                )
            else:
                entry["verdict"] = "object"
                objects.append(region)
            report["regions"].append(entry)
        if board_like:
            raise DetectionError(_board_message(*board_like[0]))
        return objects

    def _choose(self, objects: list[Region], report: dict[str, Any]) -> tuple[Region, list[Region]]:
        """The chosen object and those kept, in reading order; `objects` sorted by area."""
        objects.sort(key=lambda r: r.area, reverse=True)
        pick = self.options.pick
        if pick is not None and pick >= len(objects):
            raise DetectionError(
                f"detector.pick is {pick} but only {len(objects)} object(s) were found "
                f"(by decreasing area: {_list(objects)})"
            )
        chosen = objects[pick or 0]
        report["chosen"] = {
            "bbox_px": list(chosen.bbox),
            "why": "the largest object" if pick is None else f"detector.pick = {pick}",
        }
        numbered = sorted(objects if pick is None else [chosen], key=_reading_order)
        report["objects"] = [
            {"id": i + 1, "bbox_px": list(r.bbox), "area_px": round(r.area, 1)}
            for i, r in enumerate(numbered)
        ]
        return chosen, numbered

    def min_area(self, area: SearchArea) -> int:
        if self.options.min_area is not None:
            return self.options.min_area
        return max(50, round(0.001 * area.pixels))

    def _board_distance(
        self, lab: np.ndarray, area: SearchArea
    ) -> tuple[np.ndarray, BoardModel, np.ndarray, float, int]:
        """Distance to the board model (0 on the board in shadow), the model (and its planes),
        the board's noise (99.5th percentile) and how many pixels were board in shadow."""
        import cv2

        height, width = area.mask.shape
        border = self.options.border or max(3, round(0.02 * min(width, height)))
        band = area.border_band(border)
        degree = self.options.surface
        planes = lab_planes(lab)
        model = fit_board(lab, band, degree)
        surface = model.planes()
        distance = distance_to_board(planes, surface, self.options.shadow)
        # refit on every pixel that looks like board, away from anything that does not
        rough = distance > max(MIN_THRESHOLD, 4.0 * model.residual + 2.0)
        grown = cv2.dilate(rough.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        board_pixels = area.mask & ~grown
        if board_pixels.sum() > 10 * (degree + 1) ** 2:
            model = fit_board(lab, board_pixels, degree)
            surface = model.planes(out=surface)  # into the first surface, used up
            distance = distance_to_board(planes, surface, self.options.shadow)
        else:
            board_pixels = band
        samples = distance[board_pixels]
        typical = float(median(samples))
        inliers = samples[samples <= 3.0 * typical + 1.0]
        noise = percentile(inliers, 99.5) if inliers.size else typical
        distance[~area.mask] = 0.0
        # a shadow darkens the board and keeps its colour: no object, however dark (an empty
        # board with a shadow was planned on; a cast shadow widened the object's box)
        t_noise = max(MIN_THRESHOLD, NOISE_FACTOR * noise)
        different = distance > t_noise
        shadowed = board_in_shadow(planes, surface, t_noise) & different
        # an object's blurred edge mixes it with the board, which can look like darkened
        # board: the pixels next to the object proper stay the object's
        proper = (different & ~shadowed).astype(np.uint8)
        shadowed &= cv2.dilate(proper, np.ones((3, 3), np.uint8)) == 0
        shadowed &= ~dark_rims(proper, shadowed, self.min_area(area))
        distance[shadowed] = 0.0
        return distance, model, surface, noise, int(np.count_nonzero(shadowed))

    def _regions(
        self,
        mask: np.ndarray,
        distance: np.ndarray,
        area: SearchArea,
        bands: list[np.ndarray],
        min_area: int,
    ) -> list[Region]:
        import cv2

        binary = (mask & area.mask).astype(np.uint8) * 255
        contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        band_pixels = [max(int(np.count_nonzero(band)), 1) for band in bands]
        found = []
        for contour in contours:
            region_area = float(cv2.contourArea(contour))
            if region_area < min_area:
                continue
            filled = np.zeros(binary.shape, np.uint8)
            cv2.drawContours(filled, [contour], -1, 255, cv2.FILLED)
            inside = filled > 0
            x, y, w, h = cv2.boundingRect(contour)
            # the region lies in its box: count there, not over the whole image
            box = np.s_[y : y + h, x : x + w]
            inside_box, bands_box = inside[box], [band[box] for band in bands]
            found.append(
                Region(
                    contour=contour.reshape(-1, 2),
                    mask=inside,
                    area=region_area,
                    bbox=(x, y, x + w, y + h),
                    coverage=float(inside_box.sum()) / max(area.pixels, 1),
                    sides=tuple(area.sides_touched(inside_box, bands_box)),
                    along=max(
                        float((inside_box & band).sum()) / pixels
                        for band, pixels in zip(bands_box, band_pixels, strict=True)
                    ),
                    contrast=float(median(distance[box][inside_box & mask[box]])),
                    edge_contrast=_edge_contrast(filled, distance, (x, y, x + w, y + h)),
                )
            )
        found.sort(key=lambda r: r.area, reverse=True)
        return found


RIM_COVERAGE = 0.9
"""Shadow-coloured pixels all round an object (in this fraction of the 36 directions from its
centre, each with 3 % of its band so coloured) are its own dark edge: a cast shadow falls on
one side (at most 81 % of directions in 163 shadowed perception scenes; the chocolate cakes'
rims 92 to 100 %)."""
RIM_DARK = 0.1
"""...and at least this fraction of the band around it is shadow-coloured (cakes 0.17-0.21)."""


def dark_rims(proper: np.ndarray, shadowed: np.ndarray, min_area: int) -> np.ndarray:
    """Bool H x W: the shadow-coloured pixels that ring an object all round, which are its own
    dark edge (a chocolate cake's rim is the wood board's colour, darker) and not its shadow.

    Args:
        proper: uint8 H x W, 1 where a pixel differs from the board and is no shadow.
        shadowed: bool H x W, pixels of the board's colour, darker (taken for shadow).
        min_area: regions of `proper` smaller than this (pixels) are not looked at.
    """
    import cv2

    count, labels, stats, centres = cv2.connectedComponentsWithStats(proper, connectivity=8)
    rims = np.zeros(shadowed.shape, bool)
    height, width = shadowed.shape
    for index in range(1, count):
        x, y, w, h, size = stats[index]
        if size < min_area:
            continue
        reach = int(max(4, round(0.015 * np.sqrt(size))))
        x0, y0 = max(x - reach, 0), max(y - reach, 0)
        x1, y1 = min(x + w + reach, width), min(y + h + reach, height)
        region = (labels[y0:y1, x0:x1] == index).astype(np.uint8)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
        band = (cv2.dilate(region, kernel) > 0) & (region == 0)
        dark = band & shadowed[y0:y1, x0:x1]
        ys, xs = np.nonzero(band)
        if len(ys) == 0 or dark.sum() < RIM_DARK * len(ys):
            continue
        angle = np.arctan2(ys + y0 - centres[index][1], xs + x0 - centres[index][0])
        sector = ((angle + np.pi) / (2 * np.pi) * 36).astype(int) % 36
        of_sector = np.bincount(sector, minlength=36)
        dark_in = np.bincount(sector, weights=dark[ys, xs], minlength=36)
        if ((dark_in >= 0.03 * np.maximum(of_sector, 1)) & (of_sector > 0)).mean() >= RIM_COVERAGE:
            rims[y0:y1, x0:x1] |= dark
    return rims


def _edge_contrast(
    filled: np.ndarray, distance: np.ndarray, bbox: tuple[int, int, int, int]
) -> float:
    import cv2

    x0, y0, x1, y1 = bbox
    part = filled[y0:y1, x0:x1]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    outer = cv2.erode(part, kernel, borderValue=0)
    inner = cv2.erode(outer, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)), borderValue=0)
    ring = (outer > 0) & (inner == 0)
    if not ring.any():
        ring = part > 0
    return float(median(distance[y0:y1, x0:x1][ring]))


MAX_ALONG_SIDE = 0.5
"""A region running along more than half of a side is the table or the board's edge: an
object cut off by the image border meets it along its own width."""


def _board(region: Region, options: BoardOptions) -> bool:
    return (
        len(region.sides) >= 3
        or region.coverage > options.max_coverage
        or region.along > MAX_ALONG_SIDE
    )


def _board_reason(region: Region, options: BoardOptions) -> str:
    if len(region.sides) >= 3:
        return f"touches {len(region.sides)} sides of the searched area ({', '.join(region.sides)})"
    if region.along > MAX_ALONG_SIDE:
        return (
            f"runs along {100 * region.along:.0f} % of the {' and '.join(region.sides)} side of "
            "the searched area"
        )
    return (
        f"covers {100 * region.coverage:.0f} % of the searched area "
        f"(more than detector.max_coverage {100 * options.max_coverage:.0f} %)"
    )


def _board_message(region: Region, why: str) -> str:
    held = "holding" in why
    return (
        f"the region found (box {list(region.bbox)}) {why}: that is "
        "the board or the table around it, not an object, and nothing is planned on it; "
        "if the photo shows more than the board, give scene.camera.board_corners_px "
        "(or detector.roi); "
        + (
            "if it really is the object (a square cake with a decoration), set "
            "detector.board_on_table: false"
            if held
            else "if the object really fills the board, use a larger board or raise "
            "detector.max_coverage"
        )
    )


def _image_and_lab(scene: SceneImage | np.ndarray, blur: int) -> tuple[np.ndarray, np.ndarray]:
    """The scene as 8-bit BGR, and in CIE Lab after a `blur` px Gaussian blur (none for 1)."""
    import cv2

    raw = scene.image if isinstance(scene, SceneImage) else np.asarray(scene)
    if raw.size == 0 or raw.ndim not in (2, 3):
        raise DetectionError(f"the scene image is empty (shape {raw.shape})")
    image = to_bgr8(raw)
    blurred = cv2.GaussianBlur(image, (blur, blur), 0) if blur > 1 else image
    return image, to_lab(blurred)


def _nothing_found(min_area: int, threshold: float, how: str, shadow_px: int) -> str:
    """Why no object was found, and what to try."""
    shade = (
        f"; {shadow_px} px darker than the board in the board's own colour were taken "
        "for shadow (an object of exactly the board's colour, only darker, cannot be "
        "told from one)"
        if shadow_px >= min_area
        else ""
    )
    return (
        f"no object found: nothing of at least {min_area} px differs from the board's "
        f"colour model by more than {threshold:.1f} (Lab; {how}){shade}; if an object "
        "is there, lower detector.threshold, or check the image and scene.camera"
    )


def _crop_origin(bbox: tuple[int, int, int, int], pad: int) -> tuple[int, int]:
    """The crop's top-left pixel: the box grown by `pad` px, within the image."""
    return max(0, bbox[0] - pad), max(0, bbox[1] - pad)


def _crop(image: np.ndarray, bbox: tuple[int, int, int, int], pad: int) -> np.ndarray:
    """The box grown by `pad` px on every side, cut to the image."""
    height, width = image.shape[:2]
    x0, y0 = _crop_origin(bbox, pad)
    x1, y1 = min(width, bbox[2] + pad), min(height, bbox[3] + pad)
    return np.ascontiguousarray(image[y0:y1, x0:x1])


def _reading_order(region: Region) -> tuple[float, float]:
    x0, y0, x1, y1 = region.bbox
    return ((x0 + x1) / 2, (y0 + y1) / 2)


def _list(regions: list[Region]) -> str:
    return "; ".join(
        f"pick {i}: box {list(r.bbox)} ({r.area:.0f} px)" for i, r in enumerate(regions)
    )


def _warnings(
    chosen: Region, pick: int | None, objects: list[Region], options: BoardOptions
) -> list[str]:
    found = []
    if chosen.sides:
        found.append(
            f"detect: the object (box {list(chosen.bbox)}) touches the "
            f"{' and '.join(chosen.sides)} side(s) of the searched area: it may be cut off, "
            "and its box smaller than the object"
        )
    if pick is not None:  # one object kept: name the others it might have meant
        found += comparable_object_warnings(objects, pick, options.comparable)
    return found


def make_detector(options: dict[str, Any]) -> BoardDetector:
    detector = BoardDetector(parse_options(options))
    prepare_lab_tables()  # OpenCV's first Lab conversion, on the other core while the run starts
    return detector


@hookimpl
def register_detectors(register: RegisterDetector) -> None:
    register("board", make_detector)


def _each_at_half_its_contrast(
    first: list[Region],
    candidates: list[Region],
    distance: np.ndarray,
    largest_threshold: float,
    t_noise: float,
) -> np.ndarray:
    """The pixels kept: inside each object-like region found at the noise threshold, those
    over half that region's own edge contrast; elsewhere those over the largest's threshold
    (board texture and board-like regions are judged as before). One threshold for all would drop a faint object
    beside a bright one (a potato beside a banana)."""
    above = distance > largest_threshold
    for region in first:
        if any(region is c for c in candidates):
            own = max(t_noise, 0.5 * region.edge_contrast)
            above[region.mask] = distance[region.mask] > own
    return above
