"""The paper's Appendix A detector: the object is what differs from the most common intensity.

Grayscale, Gaussian blur, background = the most common intensity, mask = |I - bg| > threshold,
external contours. Every region of at least `min_area` pixels is an object (Detection.objects,
numbered left to right, then top to bottom); the crop covers all of them. `pick` keeps one
region only (the paper's single object).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from keymps.errors import DetectionError
from keymps.perception.search_area import comparable_object_warnings, odd_kernel, roi_polygon
from keymps.plugin import RegisterDetector, hookimpl
from keymps.plugin import parse_options as plugin_options
from keymps.types import DetectedObject, Detection, SceneImage


class ThresholdOptions(BaseModel):
    """The detector section of a task file (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)

    threshold: int = Field(default=30, ge=1, le=254)
    """A pixel is object when its blurred intensity differs from the background by more."""
    blur: int = Field(default=5, ge=0, le=99)
    """Gaussian kernel size in pixels (odd); 0 or 1 turns the blur off."""
    padding: int = Field(default=10, ge=0, le=10_000)
    """Pixels added around the box for the crop sent to the planner."""
    min_area: int = Field(default=100, ge=1)
    """Regions smaller than this many pixels are ignored (noise, crumbs)."""
    comparable: float = Field(default=0.5, gt=0, le=1)
    """A second region at least this fraction of the chosen one's area triggers a warning."""
    pick: int | None = Field(default=None, ge=0)
    """Keep only this region, by index in order of decreasing area (0 = the largest); by
    default every region is an object."""
    background: int | None = Field(default=None, ge=0, le=255)
    """Fixed background intensity instead of the most common one."""
    roi: list[tuple[float, float]] | None = None
    """Look only inside this polygon of full-image pixels (e.g. the board's four corners in a
    photo), or inside a box given as [x0, y0, x1, y1]."""

    _polygon = field_validator("roi", mode="before")(roi_polygon)
    _odd = field_validator("blur")(odd_kernel)


def parse_options(options: dict[str, Any]) -> ThresholdOptions:
    """Validate the task file's detector options; one clear line per bad option."""
    return plugin_options(ThresholdOptions, options, "threshold detector")


@dataclass(frozen=True)
class Region:
    """One thresholded blob: its contour, area and box (pixels)."""

    contour: np.ndarray
    area: float
    bbox: tuple[int, int, int, int]


def to_gray(image: np.ndarray) -> np.ndarray:
    """Any OpenCV image (gray, BGR, BGRA; 8 or 16 bit) -> 8-bit grayscale."""
    import cv2

    if image.dtype == np.uint16:
        image = (image // 257).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = np.clip(image, 0, 255).astype(np.uint8)
    if image.ndim == 2:
        return image
    if image.shape[2] == 1:
        return image[:, :, 0]
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


class ThresholdDetector:
    """Appendix A: pixel-intensity threshold against the most common intensity."""

    def __init__(self, options: ThresholdOptions | None = None):
        self.options = options or ThresholdOptions()

    def background_intensity(self, blurred: np.ndarray) -> int:
        if self.options.background is not None:
            return self.options.background
        histogram = np.bincount(blurred.ravel(), minlength=256)
        return int(np.argmax(histogram))

    def object_mask(self, image: np.ndarray) -> tuple[np.ndarray, int]:
        """The binary mask (uint8, 0/255) of pixels far from the background, and the background."""
        import cv2

        gray = to_gray(image)
        kernel = self.options.blur
        blurred = cv2.GaussianBlur(gray, (kernel, kernel), 0) if kernel > 1 else gray
        inside = self.search_area(gray.shape[1], gray.shape[0])
        background = self.background_intensity(blurred[inside])
        difference = np.abs(blurred.astype(np.int16) - background)
        mask = (difference > self.options.threshold).astype(np.uint8) * 255
        mask[~inside] = 0
        return mask, background

    def search_area(self, width_px: int, height_px: int) -> np.ndarray:
        """Boolean image of the pixels searched: the roi polygon, or the whole image."""
        import cv2

        if self.options.roi is None:
            return np.ones((height_px, width_px), bool)
        area = np.zeros((height_px, width_px), np.uint8)
        # Pixel centres at +0.5: a polygon vertex (x, y) is index (x - 0.5, y - 0.5).
        points = np.round((np.array(self.options.roi) - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(area, [points.reshape(-1, 1, 2)], 255, cv2.LINE_8, 4)
        if not area.any():
            raise DetectionError(
                f"detector.roi {self.options.roi} lies outside the {width_px} x {height_px} px image"
            )
        return area > 0

    def regions(self, mask: np.ndarray) -> list[Region]:
        """External contours of at least min_area pixels, largest first."""
        import cv2

        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        found = []
        for contour in contours:
            area = float(cv2.contourArea(contour))
            x, y, w, h = cv2.boundingRect(contour)
            if area < self.options.min_area:
                continue
            found.append(Region(contour.reshape(-1, 2), area, (x, y, x + w, y + h)))
        found.sort(key=lambda region: region.area, reverse=True)
        return found

    def detect(self, scene: SceneImage | np.ndarray) -> Detection:

        image = scene.image if isinstance(scene, SceneImage) else np.asarray(scene)
        if image.size == 0 or image.ndim not in (2, 3):
            raise DetectionError(f"the scene image is empty (shape {image.shape})")
        mask, background = self.object_mask(image)
        regions = self.regions(mask)
        if not regions:
            raise DetectionError(
                f"no object found: no region of at least {self.options.min_area} px differs "
                f"from the background intensity {background} by more than the threshold "
                f"{self.options.threshold}; lower detector.threshold or check the image"
            )
        pick = self.options.pick
        if pick is not None and pick >= len(regions):
            raise DetectionError(
                f"detector.pick is {pick} but only {len(regions)} region(s) were found "
                f"(by decreasing area: {_describe(regions)})"
            )
        chosen = regions[pick or 0]
        kept = [chosen] if pick is not None else regions
        others = [region for region in regions if region is not chosen]
        height_px, width_px = image.shape[:2]
        searched = self.search_area(width_px, height_px)
        warnings = _warnings(chosen, pick, regions, searched, self.options)

        objects = _numbered(kept, mask.shape)
        x0 = min(region.bbox[0] for region in kept)
        y0 = min(region.bbox[1] for region in kept)
        x1 = max(region.bbox[2] for region in kept)
        y1 = max(region.bbox[3] for region in kept)
        pad = self.options.padding
        cx0, cy0 = max(0, x0 - pad), max(0, y0 - pad)
        cx1, cy1 = min(width_px, x1 + pad), min(height_px, y1 + pad)
        crop = np.ascontiguousarray(image[cy0:cy1, cx0:cx1])
        primary = next(o for o in objects if o.bbox_px == chosen.bbox)
        return Detection(
            bbox_px=chosen.bbox,
            crop=crop,
            crop_origin_px=(cx0, cy0),
            contour_px=chosen.contour.astype(float),
            mask=primary.mask,
            others_px=tuple(region.bbox for region in others),
            warnings=tuple(warnings),
            objects=objects,
            report={
                "detector": "threshold",
                "background": background,
                "threshold": self.options.threshold,
                "regions": [
                    {"bbox_px": list(r.bbox), "area_px": round(r.area, 1)} for r in regions
                ],
                "pick": pick,
            },
        )


def _numbered(regions: list[Region], shape: tuple[int, ...]) -> tuple[DetectedObject, ...]:
    """The regions as objects, ids 1.. left to right, then top to bottom (by box centre)."""
    import cv2

    def key(region: Region) -> tuple[float, float]:
        x0, y0, x1, y1 = region.bbox
        return (x0 + x1) / 2, (y0 + y1) / 2

    objects = []
    for number, region in enumerate(sorted(regions, key=key), start=1):
        filled = np.zeros(shape[:2], np.uint8)
        cv2.drawContours(filled, [region.contour.reshape(-1, 1, 2)], -1, 255, cv2.FILLED)
        objects.append(
            DetectedObject(
                id=number,
                bbox_px=region.bbox,
                contour_px=region.contour.astype(float),
                area_px=region.area,
                mask=filled > 0,
            )
        )
    return tuple(objects)


def _describe(regions: list[Region]) -> str:
    return "; ".join(
        f"pick {i}: box {list(region.bbox)} ({region.area:.0f} px)"
        for i, region in enumerate(regions)
    )


def _warnings(
    chosen: Region,
    pick: int | None,
    regions: list[Region],
    searched: np.ndarray,
    options: ThresholdOptions,
) -> list[str]:
    found = []
    height_px, width_px = searched.shape
    xs, ys = chosen.contour[:, 0], chosen.contour[:, 1]
    sides = [
        name
        for name, touching in (
            ("left", xs.min() <= 0),
            ("top", ys.min() <= 0),
            ("right", xs.max() >= width_px - 1),
            ("bottom", ys.max() >= height_px - 1),
        )
        if touching
    ]
    if sides:
        found.append(
            f"detect: the object (box {list(chosen.bbox)}) touches the image border "
            f"({', '.join(sides)}): it may be cut off, and its box smaller than the object"
        )
    elif options.roi is not None:
        padded = np.pad(~searched, 1, constant_values=True)
        near_outside = padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]
        if near_outside[ys, xs].any():
            found.append(
                f"detect: the object (box {list(chosen.bbox)}) touches the border of "
                "detector.roi: it may be cut off, and its box smaller than the object"
            )
    if pick is not None:  # one object kept: name the others it might have meant
        found += comparable_object_warnings(regions, pick, options.comparable)
    return found


def make_detector(options: dict[str, Any]) -> ThresholdDetector:
    return ThresholdDetector(parse_options(options))


@hookimpl
def register_detectors(register: RegisterDetector) -> None:
    register("threshold", make_detector)
