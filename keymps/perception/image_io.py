"""Reading scene images: one clear error per way a file can fail, pixels bounded before decoding."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from keymps.errors import ImageSourceError, KeympsError

UNSCALED_BELOW = 4096
"""A 16-bit image none of whose colour samples reaches this holds 12-bit (or fewer) camera data
stored without scaling: divided by 65535 it would be nearly black."""


def to_bgr8(image: np.ndarray, sample_max: int | None = None) -> np.ndarray:
    """Any decoded image (gray, BGR, BGRA; 8 or 16 bit; float in [0, 1]) -> BGR uint8.

    Integer samples run from 0 to `sample_max` (default: the type's largest value, 255 or
    65535). An alpha channel is dropped (its colour channels are kept as they are).
    """
    import cv2

    if sample_max is not None and image.dtype in (np.uint8, np.uint16):
        top = np.uint32(sample_max)
        wide = np.minimum(image.astype(np.uint32), top)
        image = (wide * 255 + top // 2) // top
    elif image.dtype == np.uint16:
        image = (image.astype(np.uint32) * 255 + 32767) // 65535
    elif np.issubdtype(image.dtype, np.floating):
        image = np.clip(image, 0.0, 1.0) * 255.0 + 0.5
    image = np.asarray(image).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    channels = image.shape[2]
    if channels == 1:
        return cv2.cvtColor(image[:, :, 0], cv2.COLOR_GRAY2BGR)
    if channels == 4:
        return np.ascontiguousarray(image[:, :, :3])
    return np.ascontiguousarray(image)


def read_image(path: Path, max_pixels: int | None = None) -> np.ndarray:
    """Read an image file as BGR uint8 with one clear error per way it can fail.

    With `max_pixels`, a larger image is refused from its header, before it is decoded.
    """
    import cv2

    from keymps.config.limits import image_layout_from_header, image_size_from_header

    if not path.exists():
        raise ImageSourceError(f"scene image not found: {path}")
    if path.is_dir():
        raise ImageSourceError(f"scene image is a folder, not an image: {path}")
    if not path.is_file():  # a device or a pipe (/dev/zero) would be read forever
        raise ImageSourceError(f"scene image is not a regular file: {path}")
    size_bytes = path.stat().st_size
    if max_pixels is not None and size_bytes > 8 * max_pixels + 2**20:
        raise ImageSourceError(
            f"scene image {path} is {size_bytes / 2**20:.0f} MB, more than any image within "
            f"scene.max_image_pixels = {max_pixels} could be"
        )
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ImageSourceError(f"cannot read scene image {path}: {error.strerror}") from None
    if not data:
        raise ImageSourceError(f"scene image is empty (0 bytes): {path}")
    header_size = image_size_from_header(data)
    if header_size is not None:
        if max_pixels is not None:
            _check_pixels(header_size, max_pixels, path)
        _check_memory(header_size, image_layout_from_header(data), path)
    try:
        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as error:  # OpenCV asserts on some corrupt headers (e.g. a BMP 1 x 1048577)
        if "CV_IO_MAX_IMAGE" in str(error):
            raise ImageSourceError(_over_decoder_limit(path, str(error))) from None
        decoded = None
    if decoded is None or decoded.size == 0:
        raise ImageSourceError(
            f"cannot decode scene image {path}: not an image OpenCV can read "
            "(PNG, JPEG, TIFF, BMP, WebP ...) or the file is corrupt"
        )
    if header_size is None:  # a format whose header keymps does not read: checked decoded
        size = (decoded.shape[1], decoded.shape[0])
        if max_pixels is not None:
            _check_pixels(size, max_pixels, path)
        channels = decoded.shape[2] if decoded.ndim == 3 else 1
        _check_memory(size, (channels, decoded.dtype.itemsize), path)
    return to_bgr8(decoded, _sample_max(decoded, data, path))


def _sample_max(decoded: np.ndarray, data: bytes, path: Path) -> int | None:
    """The largest value the samples can take, when it is not the type's own: stated by the
    file (a PNG's sBIT chunk, a Netpbm maxval) and not exceeded. A 16-bit image that states
    nothing and stays below UNSCALED_BELOW is refused: which depth it had is a guess."""
    stated = declared_sample_max(data)
    if decoded.dtype != np.uint16 and (decoded.dtype != np.uint8 or stated is None):
        return None
    colour = decoded if decoded.ndim == 2 else decoded[:, :, : min(3, decoded.shape[2])]
    largest = int(colour.max())
    if stated is not None and 0 < stated < np.iinfo(decoded.dtype).max and largest <= stated:
        return stated
    if decoded.dtype == np.uint16 and largest < UNSCALED_BELOW and stated is None:
        raise ImageSourceError(
            f"scene image {path} is 16-bit, but no sample reaches {UNSCALED_BELOW} (the largest "
            f"is {largest}): camera data of 12 bits or fewer stored unscaled, which would read "
            "as nearly black; scale it to 16 bits (times 16 for 12-bit data), save it as 8-bit, "
            "or state its depth (a PNG sBIT chunk, a PGM or PPM maxval)"
        )
    return None


def declared_sample_max(data: bytes) -> int | None:
    """The largest colour sample a file says it holds: 2**bits - 1 from a PNG's sBIT chunk
    (significant bits, the most of the colour channels), a Netpbm file's maxval; else None."""
    from keymps.config.limits import netpbm_header

    try:
        if data[:8] == b"\x89PNG\r\n\x1a\n":
            return _png_significant_max(data)
        if re.match(rb"P[1-7]\s", data[:3]):
            return netpbm_header(data[:4096]).get("maxval")
    except (struct.error, ValueError, IndexError):
        return None  # a header cut short: the decoder has read what it could
    return None


def _png_significant_max(data: bytes) -> int | None:
    colour_type = data[25]
    colour_bytes = {0: 1, 2: 3, 3: 3, 4: 1, 6: 3}.get(colour_type)
    at = 8
    while at + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[at : at + 8])
        if kind in (b"IDAT", b"IEND"):  # sBIT comes before the image data
            return None
        if kind == b"sBIT" and colour_bytes is not None and length >= colour_bytes:
            bits = max(data[at + 8 : at + 8 + colour_bytes])
            return 2**bits - 1 if 1 <= bits <= 16 else None
        at += 12 + length
    return None


def _check_memory(size_px: tuple[int, int], layout: tuple[int, int] | None, path: Path) -> None:
    from keymps.config.limits import check_image_memory

    try:
        check_image_memory(size_px, layout, f"scene image {path}")
    except KeympsError as error:
        raise ImageSourceError(str(error)) from None


def _check_pixels(size_px: tuple[int, int], max_pixels: int, path: Path) -> None:
    from keymps.config.limits import check_image_pixels

    try:
        check_image_pixels(size_px, max_pixels, f"scene image {path}")
    except KeympsError as error:
        raise ImageSourceError(str(error)) from None


def _over_decoder_limit(path: Path, opencv_message: str) -> str:
    from keymps._decoder_limit import ENV, in_force

    if "CV_IO_MAX_IMAGE_PIXELS" in opencv_message:
        limit = in_force()
        shown = f"{ENV} = {limit} ({limit / 1e6:.1f} MP)" if limit else ENV
        return (
            f"scene image {path} has more pixels than OpenCV's decoder limit {shown}, read "
            f"from its header before decoding; use a smaller image, or set {ENV} in the "
            "environment before keymps starts (and raise scene.max_image_pixels)"
        )
    return (
        f"scene image {path} is wider or taller than OpenCV decodes (OPENCV_IO_MAX_IMAGE_WIDTH "
        "and _HEIGHT, 1048576 px by default)"
    )
