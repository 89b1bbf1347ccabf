"""Fuzzed scene images: every file is a scene, or one clean error line; nothing is executed.

Hypothesis draws small images (8 or 16 bit; gray, BGR or BGRA; 1 to 64 px a side), encodes them
as PNG, JPEG, BMP, TIFF or WebP with OpenCV, and sometimes corrupts the bytes; the file image
source and the threshold detector read them (stage level, cheap). Named cases (empty file,
1 x 1, 16-bit, RGBA, grayscale, corrupt bytes, headers claiming 20000 x 20000) go through full
runs with a recording executor standing in for the robot.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.budget import Budget
from helpers.fuzz_support import (
    FAST,
    RecordingExecutor,
    ScriptedBackend,
    answer_text,
    assert_clean_error,
    install,
    task_copy,
)
from hypothesis import given, settings
from hypothesis import strategies as st

import keymps
from keymps.config.limits import image_size_from_header
from keymps.errors import KeympsError
from keymps.plugin.manager import create_component
from keymps.run import Run, RunOptions, RunOverrides

REPO = Path(__file__).resolve().parents[2]
FORMATS = [".png", ".jpg", ".bmp", ".tiff", ".webp"]


def png_header(width: int, height: int, bit_depth: int = 8, colour: int = 2) -> bytes:
    """A PNG signature and IHDR chunk claiming this size, then a tiny IDAT and IEND."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def jpeg_header(width: int, height: int) -> bytes:
    """A JPEG start, an APP0 segment and a baseline SOF0 claiming this size (no scan data)."""
    app0 = b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, height, width, 3)
    sof += b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8" + app0 + sof + b"\xff\xd9"


@st.composite
def images(draw: Any) -> tuple[str, bytes]:
    height = draw(st.integers(min_value=1, max_value=64))
    width = draw(st.integers(min_value=1, max_value=64))
    channels = draw(st.sampled_from([1, 3, 4]))
    deep = draw(st.booleans())
    suffix = draw(st.sampled_from(FORMATS))
    if suffix in (".jpg", ".bmp", ".webp"):
        deep = False  # 16 bit is PNG and TIFF only
    seed = draw(st.integers(min_value=0, max_value=2**32 - 1))
    rng = np.random.default_rng(seed)
    top = 65535 if deep else 255
    shape = (height, width) if channels == 1 else (height, width, channels)
    array = rng.integers(0, top + 1, size=shape).astype(np.uint16 if deep else np.uint8)
    if draw(st.booleans()):  # a bright object on a dark board, so detection can succeed
        array[...] = top // 8
        array[height // 4 : 3 * height // 4 + 1, width // 4 : 3 * width // 4 + 1] = top
    ok, encoded = cv2.imencode(suffix, array)
    assert ok
    data = encoded.tobytes()
    damage = draw(st.sampled_from(["none", "none", "truncate", "flip", "splice", "header only"]))
    if damage == "truncate":
        data = data[: draw(st.integers(min_value=0, max_value=len(data)))]
    elif damage == "flip":
        for _ in range(draw(st.integers(1, 8))):
            at = draw(st.integers(0, len(data) - 1))
            data = data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1 :]
    elif damage == "splice":
        data = data[: len(data) // 2] + draw(st.binary(max_size=64)) + data[len(data) // 2 :]
    elif damage == "header only":
        data = data[:32]
    return suffix, data


@pytest.fixture(scope="module")
def stage_parts(tmp_path_factory: Any) -> tuple[Any, Any, Any]:
    folder = tmp_path_factory.mktemp("images")
    task = keymps.load_task(task_copy(folder))
    return folder, create_component("detector", "threshold", {}), task


def load_and_detect(path: Path, task: Any, detector: Any) -> str:
    """The image and detect stages on one file; the outcome in a word, or a failed invariant."""
    source = create_component("image_source", "file", {"path": str(path)})
    budget = Budget()
    try:
        scene = source.load(Run(task=task, folder=path.parent))
        assert scene.image.dtype == np.uint8 and scene.image.ndim == 3
        assert scene.image.shape[2] == 3
        detector.detect(scene)
    except KeympsError as error:
        assert_clean_error(error)
        outcome = "refused"
    else:
        outcome = "detected"
    budget.check(5.0)
    return outcome


@settings(FAST, max_examples=600)
@given(case=images())
def test_fuzzed_image_files_load_or_fail_cleanly(
    case: tuple[str, bytes], stage_parts: Any, fuzz_counter: Any
) -> None:
    folder, detector, task = stage_parts
    suffix, data = case
    path = folder / f"fuzz{suffix}"
    path.write_bytes(data)
    fuzz_counter.add("images/encoded and damaged", data, load_and_detect(path, task, detector))


@settings(FAST, max_examples=300)
@given(data=st.binary(max_size=512), suffix=st.sampled_from([*FORMATS, ".txt", ""]))
def test_random_bytes_fail_cleanly(
    data: bytes, suffix: str, stage_parts: Any, fuzz_counter: Any
) -> None:
    folder, detector, task = stage_parts
    path = folder / f"bytes{suffix}"
    path.write_bytes(data)
    fuzz_counter.add("images/random bytes", data, load_and_detect(path, task, detector))


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".bmp", ".tiff", ".webp"])
def test_the_header_size_matches_what_opencv_decodes(suffix: str) -> None:
    image = np.zeros((37, 53, 3), np.uint8)
    data = cv2.imencode(suffix, image)[1].tobytes()
    assert image_size_from_header(data) == (53, 37)


def test_headers_claiming_huge_sizes_are_read() -> None:
    assert image_size_from_header(png_header(20000, 20000)) == (20000, 20000)
    assert image_size_from_header(jpeg_header(20000, 20000)) == (20000, 20000)
    assert image_size_from_header(b"GIF89a" + struct.pack("<HH", 20000, 20000)) == (20000, 20000)
    assert image_size_from_header(b"\x89PNG\r\n\x1a\n\x00") is None  # cut short: the decoder says
    assert image_size_from_header(b"not an image") is None


def _scene_files(folder: Path) -> dict[str, bytes]:
    scene = cv2.imread(str(REPO / "tasks/scenes/round_cake.png"), cv2.IMREAD_UNCHANGED)
    gray = cv2.cvtColor(scene, cv2.COLOR_BGR2GRAY)
    rgba = cv2.cvtColor(scene, cv2.COLOR_BGR2BGRA)
    rgba[..., 3] = 0  # fully transparent: the colour channels are still the scene
    deep = scene.astype(np.uint16) * 257
    twelve = ((scene.astype(np.uint32) * 4095 + 127) // 255).astype(np.uint16)  # unscaled
    twelve_png = cv2.imencode(".png", twelve)[1].tobytes()
    sbit = b"sBIT" + bytes([12, 12, 12])
    sbit_chunk = struct.pack(">I", 3) + sbit + struct.pack(">I", zlib.crc32(sbit))
    return {
        "empty.png": b"",
        "one-pixel.png": cv2.imencode(".png", np.full((1, 1, 3), 200, np.uint8))[1].tobytes(),
        "gray.png": cv2.imencode(".png", gray)[1].tobytes(),
        "rgba.png": cv2.imencode(".png", rgba)[1].tobytes(),
        "16-bit.png": cv2.imencode(".png", deep)[1].tobytes(),
        "16-bit.tiff": cv2.imencode(".tiff", deep)[1].tobytes(),
        "12-bit-sbit.png": twelve_png[:33] + sbit_chunk + twelve_png[33:],
        "12-bit.ppm": cv2.imencode(".ppm", twelve)[1].tobytes().replace(b"65535", b"4095", 1),
        "12-bit-unscaled.png": twelve_png,
        "12-bit-unscaled.tiff": cv2.imencode(".tiff", twelve)[1].tobytes(),
        "corrupt.png": cv2.imencode(".png", scene)[1].tobytes()[:-4000],
        "garbage.jpg": bytes(range(256)) * 8,
        "20000x20000.png": png_header(20000, 20000),
        "20000x20000.jpg": jpeg_header(20000, 20000),
        "huge-bmp.bmp": b"BM" + b"\x00" * 16 + struct.pack("<ii", 20000, -20000) + b"\x00" * 40,
        "text.png": b"hello, I am not an image\n",
    }


EXPECTED = {
    "empty.png": "empty file (0 bytes)",
    "one-pixel.png": "no object found",
    "corrupt.png": None,  # PNG decoders may keep the rows they got: a scene, or a clean refusal
    "garbage.jpg": "not an image file",
    "12-bit-unscaled.png": "is 16-bit, but no sample reaches 4096",
    "12-bit-unscaled.tiff": "is 16-bit, but no sample reaches 4096",
    "20000x20000.png": "20000 x 20000 pixels (400.0 MP), more than scene.max_image_pixels",
    "20000x20000.jpg": "20000 x 20000 pixels (400.0 MP), more than scene.max_image_pixels",
    "huge-bmp.bmp": "more than scene.max_image_pixels",
    "text.png": "not an image file",
}


def test_named_images_in_full_runs(keymps_plugins: Any, tmp_path: Path, fuzz_counter: Any) -> None:
    install(keymps_plugins)
    task = keymps.load_task(task_copy(tmp_path / "task"))
    centre_dot = lambda request: answer_text(  # noqa: E731
        "line", [[[c / 2 for c in request.crop_size_px]] * 2]
    )
    for name, data in _scene_files(tmp_path).items():
        image = tmp_path / name
        image.write_bytes(data)
        RecordingExecutor.calls = []
        ScriptedBackend.answers = [centre_dot, centre_dot]
        budget = Budget()
        try:
            run = keymps.run_task(
                task,
                options=RunOptions(rerun="off"),
                overrides=RunOverrides(
                    image=image,
                    backend="scripted",
                    executor="recording",
                    out=tmp_path / f"run-{name}",
                ),
            )
        except KeympsError as error:
            assert_clean_error(error)
            assert RecordingExecutor.calls == [], name
            expected = EXPECTED.get(name, "a scene")
            assert expected is None or expected in str(error), (name, str(error))
            fuzz_counter.add("images/named, full runs", name, "refused")
        else:
            assert EXPECTED.get(name) is None, f"{name} should have been refused"
            assert len(RecordingExecutor.calls) == 1
            assert run.stages.image.image.shape[2] == 3
            if name.startswith("12-bit"):  # the scene itself, not a nearly black one
                scene = cv2.imread(str(REPO / "tasks/scenes/round_cake.png"))
                assert np.abs(run.stages.image.image.astype(int) - scene).max() <= 1, name
            fuzz_counter.add("images/named, full runs", name, "executed")
        budget.check(5.0, name)


def test_the_image_limit_is_configurable(tmp_path: Path, keymps_plugins: Any) -> None:
    install(keymps_plugins)
    path = task_copy(
        tmp_path, **{"object_height: 0.06": "object_height: 0.06\n  max_image_pixels: 1000"}
    )
    with pytest.raises(KeympsError, match=r"more than scene.max_image_pixels = 1000 \(0.0 MP\)"):
        keymps.run_task(
            path,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(backend="offline", executor="recording", out=tmp_path / "r"),
        )
    assert RecordingExecutor.calls == []
    synthetic = task_copy(
        tmp_path / "synthetic",
        **{
            "image: ": "source: synthetic\n  source_options: {px_per_m: 20000}\n  image: ",
            "size: [0.30, 0.18]": "size: [3.0, 3.0]",  # the largest board a task allows
        },
    )
    budget = Budget()
    with pytest.raises(KeympsError, match=r"the synthetic scene is 60000 x 60000 pixels"):
        keymps.run_task(
            synthetic,
            options=RunOptions(rerun="off"),
            overrides=RunOverrides(executor="recording", out=tmp_path / "s"),
        )
    budget.check(5.0)


@pytest.mark.parametrize("kind", ["/dev/zero", "fifo", "sparse 2 GB file"])
def test_files_that_never_end_are_not_read(kind: str, tmp_path: Path, keymps_plugins: Any) -> None:
    """Found by probing: scene.source_options.path: /dev/zero read forever (memory, no end)."""
    install(keymps_plugins)
    if kind == "/dev/zero":
        target = Path("/dev/zero")
    elif kind == "fifo":
        target = tmp_path / "pipe.png"
        os.mkfifo(target)
    else:
        target = tmp_path / "huge.png"
        with target.open("wb") as handle:
            handle.truncate(2 * 2**30)  # sparse: no disk used
    path = task_copy(
        tmp_path / "task",
        **{"image: ": f"source_options: {{path: {target}}}\n  image: "},
    )
    budget = Budget()
    with pytest.raises(KeympsError) as caught:
        keymps.run_task(
            path,
            overrides=RunOverrides(backend="offline", executor="recording", out=tmp_path / "r"),
        )
    budget.check(5.0)
    assert_clean_error(caught.value)
    expected = "more than any image within" if kind.startswith("sparse") else "not a regular file"
    assert expected in str(caught.value)
    assert RecordingExecutor.calls == []


def test_a_header_opencv_asserts_on_is_a_clean_error(stage_parts: Any) -> None:
    """Found by the fuzzer above: a BMP claiming 1 x 1048577 pixels made cv2.imdecode raise
    (OpenCV decodes no image taller than 2**20 px)."""
    folder, detector, task = stage_parts
    image = np.zeros((1, 1), np.uint8)
    data = bytearray(cv2.imencode(".bmp", image)[1].tobytes())
    data[22:26] = struct.pack("<i", 1_048_577)
    path = folder / "tall.bmp"
    path.write_bytes(bytes(data))
    with pytest.raises(KeympsError, match="is wider or taller than OpenCV decodes"):
        create_component("image_source", "file", {"path": str(path)}).load(
            Run(task=task, folder=folder)
        )
