"""OpenCV's image decoders refuse, from the file's header, images larger than a pixel count.

OpenCV reads `OPENCV_IO_MAX_IMAGE_PIXELS` once, when cv2 is imported; `import keymps` sets it
(unless the user did) so that every format OpenCV reads (PNG, JPEG, TIFF, WebP, BMP, PNM, EXR,
JPEG 2000 ...) is refused before its pixels are allocated. keymps' own header reader
(keymps.config.limits) applies the task's `scene.max_image_pixels` on top of it.
"""

from __future__ import annotations

import os
import sys

ENV = "OPENCV_IO_MAX_IMAGE_PIXELS"
DECODER_MAX_PIXELS = 64_000_000
"""The limit set when the user set none: scene.max_image_pixels' default."""

_in_force: int | None = None


def install() -> None:
    """Set the decoder limit, if cv2 is not imported yet (then OpenCV's own 1 GP stays)."""
    global _in_force
    if "cv2" in sys.modules:
        return  # too late: OpenCV read the variable when cv2 was imported
    value = os.environ.setdefault(ENV, str(DECODER_MAX_PIXELS))
    try:
        _in_force = int(value)
    except ValueError:
        _in_force = None  # OpenCV refuses a malformed value itself, at import


def in_force() -> int | None:
    """The decoder limit OpenCV applies in this process, or None when it is not known."""
    return _in_force
