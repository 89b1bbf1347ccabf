"""The paper's Appendix A detector: the object is what differs from the most common intensity.

Grayscale, Gaussian blur, background = the most common intensity, mask = |I - bg| > threshold,
external contours, the largest one (or the one `pick` names), its bounding box.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from keymps.errors import KeympsError, StageError
from keymps.hookspecs import Register, hookimpl
from keymps.stages import Detection, SceneImage


class DetectionError(StageError):
    """The detector could not find the object (or cannot read the image)."""

    def __init__(self, message: str):
        super().__init__("detect", message)


class ThresholdOptions(BaseModel):
    """The detector section of a task file (every key but `name`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

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
    pick: int = Field(default=0, ge=0)
    """Which region to use, by index in order of decreasing area (0 = the largest)."""
    background: int | None = Field(default=None, ge=0, le=255)
    """Fixed background intensity instead of the most common one."""

    @field_validator("blur")
    @classmethod
    def _odd(cls, value: int) -> int:
        if value > 1 and value % 2 == 0:
            raise ValueError(f"must be odd (a Gaussian kernel size), got {value}")
        return value


def parse_options(options: dict[str, Any]) -> ThresholdOptions:
    """Validate the task file's detector options; one clear line per bad option."""
    try:
        return ThresholdOptions.model_validate(options)
    except ValidationError as error:
        problems = []
        for item in error.errors(include_url=False):
            key = ".".join(str(p) for p in item["loc"]) or "(options)"
            message = "unknown option" if item["type"] == "extra_forbidden" else item["msg"]
            message = message.removeprefix("Value error, ")
            problems.append(f"option {key!r}: {message}")
        known = ", ".join(ThresholdOptions.model_fields)
        raise KeympsError(f"threshold detector: {'; '.join(problems)} (options: {known})") from None


@dataclass(frozen=True)
class Region:
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
        background = self.background_intensity(blurred)
        difference = np.abs(blurred.astype(np.int16) - background)
        return (difference > self.options.threshold).astype(np.uint8) * 255, background

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
        import cv2

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
        if pick >= len(regions):
            raise DetectionError(
                f"detector.pick is {pick} but only {len(regions)} region(s) were found "
                f"(largest first: {_describe(regions)})"
            )
        chosen = regions[pick]
        others = [region for i, region in enumerate(regions) if i != pick]
        height_px, width_px = image.shape[:2]
        warnings = _warnings(chosen, pick, regions, (width_px, height_px), self.options)

        filled = np.zeros_like(mask)
        cv2.drawContours(filled, [chosen.contour.reshape(-1, 1, 2)], -1, 255, cv2.FILLED)
        x0, y0, x1, y1 = chosen.bbox
        pad = self.options.padding
        cx0, cy0 = max(0, x0 - pad), max(0, y0 - pad)
        cx1, cy1 = min(width_px, x1 + pad), min(height_px, y1 + pad)
        crop = np.ascontiguousarray(image[cy0:cy1, cx0:cx1])
        return Detection(
            bbox_px=chosen.bbox,
            crop=crop,
            crop_origin_px=(cx0, cy0),
            contour_px=chosen.contour.astype(float),
            mask=filled > 0,
            others_px=tuple(region.bbox for region in others),
            warnings=tuple(warnings),
        )


def _describe(regions: list[Region]) -> str:
    return "; ".join(
        f"#{i} box {list(region.bbox)} ({region.area:.0f} px)" for i, region in enumerate(regions)
    )


def _warnings(
    chosen: Region,
    pick: int,
    regions: list[Region],
    size_px: tuple[int, int],
    options: ThresholdOptions,
) -> list[str]:
    found = []
    x0, y0, x1, y1 = chosen.bbox
    width_px, height_px = size_px
    sides = [
        name
        for name, touching in (
            ("left", x0 <= 0),
            ("top", y0 <= 0),
            ("right", x1 >= width_px),
            ("bottom", y1 >= height_px),
        )
        if touching
    ]
    if sides:
        found.append(
            f"detect: the object (box {list(chosen.bbox)}) touches the image border "
            f"({', '.join(sides)}): it may be cut off, and its box smaller than the object"
        )
    for index, region in enumerate(regions):
        if index != pick and region.area >= options.comparable * chosen.area:
            found.append(
                f"detect: two objects of comparable size: #{pick} box {list(chosen.bbox)} "
                f"({chosen.area:.0f} px, used) and #{index} box {list(region.bbox)} "
                f"({region.area:.0f} px); set detector.pick to {index} to use the other"
            )
    return found


def make_detector(options: dict[str, Any]) -> ThresholdDetector:
    return ThresholdDetector(parse_options(options))


@hookimpl
def register_detectors(register: Register) -> None:
    register("threshold", make_detector)
