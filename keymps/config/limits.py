"""Resource bounds: inputs that would need unbounded memory or time are refused with one line.

Each bound is configurable (see docs/safety.md):

- image size in pixels, read from the file's header before anything is decoded
  (`scene.max_image_pixels`; OpenCV's own decoders refuse images over
  `OPENCV_IO_MAX_IMAGE_PIXELS`, which `import keymps` sets: keymps/_decoder_limit.py);
- planner answer length in characters, from `planner.max_pairs` (`max_answer_chars`);
- tool path length and estimated duration, right after the path is composed, before the costly
  inverse kinematics (`motion.max_path_length`, `motion.max_duration_s`);
- trajectory duration after timing (`motion.max_duration_s`).
"""

from __future__ import annotations

import re
import struct
from typing import TYPE_CHECKING

import numpy as np

from keymps.errors import KeympsError

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.types import ToolPath, Trajectory

ANSWER_BASE_CHARS = 20_000
"""Room for prose, a code fence and a rationale around the JSON."""
ANSWER_CHARS_PER_PAIR = 200
"""A pretty-printed pair with long decimals is about 100 characters."""


def max_answer_chars(max_pairs: int) -> int:
    """The longest planner answer read at all, for answers of up to `max_pairs` pairs."""
    return ANSWER_BASE_CHARS + ANSWER_CHARS_PER_PAIR * max_pairs


IMAGE_SIGNATURES = (
    b"\x89PNG\r\n\x1a\n",  # PNG
    b"\xff\xd8",  # JPEG
    b"BM",  # BMP
    b"II*\x00",  # TIFF, little-endian
    b"MM\x00*",  # TIFF, big-endian
    b"GIF87a",
    b"GIF89a",
    b"\x59\xa6\x6a\x95",  # Sun raster
    b"\x00\x00\x00\x0cjP  ",  # JPEG 2000 (JP2)
    b"\xff\x4f\xff\x51",  # JPEG 2000 codestream
    b"\x76\x2f\x31\x01",  # OpenEXR
    b"#?RADIANCE",
    b"#?RGBE",  # Radiance HDR
)
"""The first bytes of the files OpenCV decodes (with RIFF WebP, PNM/PFM and ISO-BMFF below)."""


def looks_like_an_image(head: bytes) -> bool:
    """Whether a file's first 16 bytes begin an image format OpenCV reads (a text file renamed
    .png, an empty file, a PDF do not): a cheap check before anything is decoded."""
    if head.startswith(IMAGE_SIGNATURES):
        return True
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return True
    if head[4:8] == b"ftyp":  # AVIF, HEIF
        return True
    return re.match(rb"P[1-7Ff]\s", head[:3]) is not None  # PNM, PAM, PFM


def image_size_from_header(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG, JPEG, GIF, BMP, WebP, TIFF or PNM header; None if unrecognised.

    `data` is the whole file: a TIFF's directory is often at its end, and a JPEG's frame header
    may follow any amount of metadata.
    """
    try:
        if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
            width, height = struct.unpack(">II", data[16:24])
            return int(width), int(height)
        if data[:2] == b"\xff\xd8":
            return _jpeg_size(data)
        if data[:6] in (b"GIF87a", b"GIF89a"):
            width, height = struct.unpack("<HH", data[6:10])
            return int(width), int(height)
        if data[:2] == b"BM":
            width, height = struct.unpack("<ii", data[18:26])
            return abs(int(width)), abs(int(height))
        if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
            return _webp_size(data)
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(data)
        if re.match(rb"P[1-7]\s", data[:3]):
            return _pnm_size(data[:4096])
    except (struct.error, ValueError):
        return None  # a header cut short: let the decoder report the corrupt file
    return None


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    frame = _jpeg_frame(data)
    return frame[:2] if frame else None


def _jpeg_frame(data: bytes) -> tuple[int, int, int, int] | None:
    """(width, height, bits per sample, components) from a JPEG's frame header."""
    index = 2
    while index + 9 < len(data):
        if data[index] != 0xFF:  # libjpeg skips stray bytes before a marker: so does this
            index = data.find(b"\xff", index)
            if index < 0:
                return None
            continue
        marker = data[index + 1]
        if marker == 0xDA:  # start of scan: no frame header came before it
            return None
        if marker == 0xFF:  # fill byte
            index += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length field
            index += 2
            continue
        length = struct.unpack(">H", data[index + 2 : index + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            height, width = struct.unpack(">HH", data[index + 5 : index + 9])
            return int(width), int(height), data[index + 4], data[index + 9]
        index += 2 + length
    return None


def _webp_size(data: bytes) -> tuple[int, int] | None:
    chunk = data[12:16]
    if chunk == b"VP8X":
        width = 1 + int.from_bytes(data[24:27], "little")
        height = 1 + int.from_bytes(data[27:30], "little")
        return width, height
    if chunk == b"VP8L":
        bits = int.from_bytes(data[21:25], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if chunk == b"VP8 ":
        width, height = struct.unpack("<HH", data[26:30])
        return int(width) & 0x3FFF, int(height) & 0x3FFF
    return None


def _pnm_size(head: bytes) -> tuple[int, int] | None:
    fields = netpbm_header(head)
    if "width" in fields and "height" in fields:
        return fields["width"], fields["height"]
    return None


def netpbm_header(head: bytes) -> dict[str, int]:
    """The numbers a Netpbm header gives ("width", "height", "maxval"), # comments allowed: P1-P6
    list them after the magic (P1 and P4 have no maxval), P7 (PAM) names them."""
    text = re.sub(rb"#[^\n]*", b" ", head[2:]).split()
    if head[1:2] == b"7":
        named = dict(zip(text[::2], text[1::2], strict=False))
        keys = {b"WIDTH": "width", b"HEIGHT": "height", b"MAXVAL": "maxval"}
        return {name: int(named[key]) for key, name in keys.items() if key in named}
    names = ["width", "height"] if head[1:2] in (b"1", b"4") else ["width", "height", "maxval"]
    found: dict[str, int] = {}
    for name, value in zip(names, text, strict=False):
        if not value.isdigit():
            break
        found[name] = int(value)
    return found


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    order = "<" if data[:2] == b"II" else ">"
    offset = struct.unpack(order + "I", data[4:8])[0]
    count = struct.unpack(order + "H", data[offset : offset + 2])[0]
    size: dict[int, int] = {}
    for entry in range(min(count, 512)):
        at = offset + 2 + 12 * entry
        tag, kind = struct.unpack(order + "HH", data[at : at + 4])
        if tag in (256, 257):  # ImageWidth, ImageLength: SHORT or LONG
            code = "H" if kind == 3 else "I"
            size[tag] = struct.unpack(order + code, data[at + 8 : at + 8 + struct.calcsize(code)])[
                0
            ]
    if 256 in size and 257 in size:
        return size[256], size[257]
    return None


def check_image_pixels(size_px: tuple[int, int], max_pixels: int, what: str) -> None:
    """Refuse an image larger than `max_pixels` (before it is decoded or rendered)."""
    width, height = size_px
    if width * height > max_pixels:
        raise KeympsError(
            f"{what} is {width} x {height} pixels ({width * height / 1e6:.1f} MP), more than "
            f"scene.max_image_pixels = {max_pixels} ({max_pixels / 1e6:.1f} MP); use a smaller "
            "image or raise the limit"
        )


DETECTION_BYTES_PER_PIXEL = 96
"""Peak memory a run takes per pixel of its scene, over what it held before: 86 bytes
measured (a whole offline run, peak in detection: the board detector's float32 Lab image,
board-model planes and masks; 6 to 24 MP, gray to RGBA, 8 and 16 bit alike), rounded up."""
UNKNOWN_LAYOUT = (4, 4)
"""Channels and bytes per sample assumed for a format whose header keymps does not read (a
float TIFF with alpha is the largest OpenCV decodes)."""


def image_layout_from_header(data: bytes) -> tuple[int, int] | None:
    """(channels, bytes per sample) OpenCV decodes a PNG or JPEG into, from its header; None
    for other formats."""
    try:
        if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
            depth, colour = data[24], data[25]  # palette and gray+alpha decode to 4 channels
            return {0: 1, 2: 3, 3: 4, 4: 4, 6: 4}.get(colour, 4), 2 if depth == 16 else 1
        if data[:2] == b"\xff\xd8":
            frame = _jpeg_frame(data)
            return (frame[3], 2 if frame[2] > 8 else 1) if frame else None
    except (IndexError, struct.error):
        return None
    return None


def image_bytes_needed(size_px: tuple[int, int], layout: tuple[int, int] | None) -> int:
    """The memory reading and detecting an image takes at its peak, bytes: decoding (the
    decoded samples, and for 16-bit or float samples two 32-bit working copies on the way to
    8-bit BGR) or detection (DETECTION_BYTES_PER_PIXEL), whichever is more."""
    channels, sample_bytes = layout or UNKNOWN_LAYOUT
    decoding = channels * sample_bytes + (2 * 4 * channels if sample_bytes > 1 else 0) + 3
    return size_px[0] * size_px[1] * max(decoding, DETECTION_BYTES_PER_PIXEL)


def check_image_memory(size_px: tuple[int, int], layout: tuple[int, int] | None, what: str) -> None:
    """Refuse an image the process has not the memory to read and detect (before decoding it),
    naming what bounds the memory; nothing is checked where that cannot be read."""
    from keymps._memory import memory_left

    left = memory_left()
    needed = image_bytes_needed(size_px, layout)
    if left is None or needed <= left[0]:
        return
    channels, sample_bytes = layout or UNKNOWN_LAYOUT
    described = f"{channels} channel{'s' * (channels > 1)} of {8 * sample_bytes} bits"
    raise KeympsError(
        f"{what} is {size_px[0]} x {size_px[1]} pixels, {described}: reading and detecting it "
        f"takes about {needed / 2**30:.1f} GB, more than the {left[0] / 2**30:.1f} GB "
        f"{left[1]} leaves this run; use a smaller image"
    )


BELOW_BOARD_M = 0.001
"""A planned point this far below the board can never pass the safety check (0.5 mm board
tolerance plus 0.5 mm path tolerance): say so before inverse kinematics, naming the pair."""


def check_tool_path(tool_path: ToolPath, task: Task) -> ToolPath:
    """Refuse a path below the board or too long to solve and time, before any IK runs."""
    for piece in tool_path.pieces:
        lowest = float(np.min(np.asarray(piece.points, dtype=float)[:, 2], initial=np.inf))
        if lowest < -BELOW_BOARD_M:
            where = (
                f"primitive {tool_path.keyword!r}"
                if piece.kind == "work"
                else "the travel move to its start"
            )
            at = piece.pairs_label() if piece.kind == "work" else f"pair {piece.pair_index + 1}"
            raise KeympsError(
                f"the tool path goes {-lowest * 1000:.1f} mm below the board at {at} "
                f"({where}); raise height.margin or keep that pair's keypoints off the board"
            )
    motion = task.motion
    moving = [(p.length_m, p.speed) for p in tool_path.pieces if len(p.points) > 1]
    length = float(sum(piece_length for piece_length, _ in moving))
    if not np.isfinite(length) or length > motion.max_path_length:
        raise KeympsError(
            f"the tool path is {length:.1f} m long ({len(tool_path.pieces)} pieces), more than "
            f"motion.max_path_length = {motion.max_path_length:g} m; ask for fewer or shorter "
            "strokes, or raise the limit"
        )
    at_speed = sum(piece_length / max(float(speed), 1e-9) for piece_length, speed in moving)
    estimate = max(at_speed, _rest_to_rest_s(length, task))
    if estimate > motion.max_duration_s:
        raise KeympsError(
            f"the tool path would take at least {estimate:.0f} s at the set speeds and tool "
            f"limits, more than motion.max_duration_s = {motion.max_duration_s:g} s; ask for "
            "fewer strokes, raise motion.work_speed or robot.max_tool_*, or raise the limit"
        )
    return tool_path


def _rest_to_rest_s(length: float, task: Task) -> float:
    """The shortest time to cover `length` metres from rest to rest at the tool's acceleration
    and jerk limits: a lower bound for the whole path too (its strokes each start and end at
    rest, and the square and cube roots are concave)."""
    robot = task.robot
    by_acceleration = 2.0 * np.sqrt(length / robot.max_tool_acceleration)
    by_jerk = np.cbrt(32.0 * length / robot.max_tool_jerk)
    return float(max(by_acceleration, by_jerk))


def check_duration(trajectory: Trajectory, task: Task) -> Trajectory:
    """Refuse a timed trajectory longer than motion.max_duration_s."""
    check_timed_duration(trajectory.duration_s, task)
    return trajectory


def check_timed_duration(duration_s: float, task: Task) -> None:
    """Refuse a motion timed longer than motion.max_duration_s (before it is sampled)."""
    limit = task.motion.max_duration_s
    if not np.isfinite(duration_s) or duration_s > limit:
        raise KeympsError(
            f"the trajectory lasts {duration_s:.0f} s, more than "
            f"motion.max_duration_s = {limit:g} s; ask for fewer strokes or raise the limit"
        )
