"""The built-in image sources: file, synthetic and opencv, and how each one fails."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from keymps.config.task import Task
from keymps.errors import KeympsError
from keymps.plugin.manager import create_component
from keymps.run import Run


def make_run(tmp_path: Path, **scene: Any) -> Run:
    task = Task.model_validate(
        {
            "name": "t",
            "instruction": "x",
            "scene": {"image": "scene.png", "object_height": 0.04, **scene},
            "primitives": ["a"],
            "path": tmp_path / "task.yaml",
        }
    )
    return Run(task=task, folder=tmp_path / "run")


def load(tmp_path: Path, source: str = "file", options: dict | None = None, **scene: Any) -> Any:
    component = create_component("image_source", source, options or {})
    return component.load(make_run(tmp_path, **scene))


def test_file_source_reads_relative_to_the_task_file(tmp_path: Path) -> None:
    image = np.random.default_rng(0).integers(0, 255, size=(30, 40, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "scene.png"), image)
    loaded = load(tmp_path)
    np.testing.assert_array_equal(loaded.image, image)
    assert loaded.size_px == (40, 30)
    assert loaded.source == str(tmp_path / "scene.png")


@pytest.mark.parametrize("kind", ["gray", "rgba", "16bit", "gray16"])
def test_file_source_converts_to_bgr8(tmp_path: Path, kind: str) -> None:
    bgr = np.zeros((20, 30, 3), np.uint8)
    bgr[:, :, 0], bgr[:, :, 1], bgr[:, :, 2] = 10, 128, 250
    if kind == "gray":
        written, expected = bgr[:, :, 1], np.full((20, 30, 3), 128)
    elif kind == "rgba":
        alpha = np.full((20, 30, 1), 100, np.uint8)
        written, expected = np.concatenate([bgr, alpha], axis=2), bgr
    elif kind == "16bit":
        written, expected = bgr.astype(np.uint16) * 257, bgr
    else:
        written, expected = np.full((20, 30), 40000, np.uint16), np.full((20, 30, 3), 156)
    assert cv2.imwrite(str(tmp_path / "scene.png"), written)
    loaded = load(tmp_path).image
    assert loaded.dtype == np.uint8 and loaded.shape == (20, 30, 3)
    np.testing.assert_array_equal(loaded, expected)


def test_file_source_failures_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(KeympsError, match=r"image: scene image not found: .*scene.png"):
        load(tmp_path)
    (tmp_path / "scene.png").write_bytes(b"")
    with pytest.raises(KeympsError, match=r"scene image is empty \(0 bytes\): .*scene.png"):
        load(tmp_path)
    (tmp_path / "scene.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not really a png")
    with pytest.raises(KeympsError, match=r"cannot decode scene image .*scene.png.* corrupt"):
        load(tmp_path)
    (tmp_path / "folder.png").mkdir()
    with pytest.raises(KeympsError, match="is a folder"):
        load(tmp_path, options={"path": "folder.png"})
    with pytest.raises(KeympsError, match=r"file image source: .*'colour': unknown option"):
        create_component("image_source", "file", {"colour": True})


def test_synthetic_source_renders_on_the_task_workspace(tmp_path: Path) -> None:
    run = make_run(tmp_path, source="synthetic", workspace={"size": [0.24, 0.16]})
    source = create_component(
        "image_source", "synthetic", {"object": "cucumber", "seed": 4, "px_per_m": 1000}
    )
    scene = source.load(run)
    assert scene.size_px == (240, 160)
    assert scene.source == "synthetic:cucumber:seed=4"
    truth = scene.truth
    assert truth["board_size_m"] == [0.24, 0.16]
    assert truth["objects"][0]["height_m"] == 0.04  # scene.object_height
    again = create_component(
        "image_source", "synthetic", {"object": "cucumber", "seed": 4, "px_per_m": 1000}
    ).load(make_run(tmp_path, source="synthetic", workspace={"size": [0.24, 0.16]}))
    np.testing.assert_array_equal(scene.image, again.image)
    with pytest.raises(KeympsError, match=r"scene.source_options.object: unknown object 'kiwi'"):
        create_component("image_source", "synthetic", {"object": "kiwi"})
    with pytest.raises(KeympsError, match=r"synthetic image source: .*'length'"):
        create_component("image_source", "synthetic", {"length": -1})


def test_opencv_source_grabs_a_frame_from_a_video(tmp_path: Path) -> None:
    video = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    assert writer.isOpened()
    for value in (40, 80, 120):
        writer.write(np.full((48, 64, 3), value, np.uint8))
    writer.release()
    source = create_component(
        "image_source", "opencv", {"camera": "camera.avi", "warmup_frames": 1}
    )
    scene = source.load(make_run(tmp_path, source="opencv"))
    assert scene.image.shape == (48, 64, 3) and scene.image.dtype == np.uint8
    assert abs(int(scene.image.mean()) - 80) <= 3  # the second frame, after one warm-up frame
    missing = create_component("image_source", "opencv", {"camera": str(tmp_path / "none.avi")})
    with pytest.raises(KeympsError, match=r"image: cannot open camera '.*none.avi'"):
        missing.load(make_run(tmp_path, source="opencv"))
    with pytest.raises(KeympsError, match=r"opencv image source: .*'warmup_frames'"):
        create_component("image_source", "opencv", {"warmup_frames": -2})


# --------------------------------------------------------------------- camera data below 16 bits


def _with_sbit(png: bytes, bits: list[int]) -> bytes:
    """The PNG with an sBIT chunk (significant bits per channel) right after its IHDR."""
    chunk = b"sBIT" + bytes(bits)
    crc = struct.pack(">I", zlib.crc32(chunk))
    return png[:33] + struct.pack(">I", len(bits)) + chunk + crc + png[33:]


def _deep_case(rng: np.random.Generator) -> tuple[str, bytes, np.ndarray]:
    """A scene as a camera of 9-15 bits stores it: unscaled in a 16-bit PNG that says so (sBIT),
    or in a PGM/PPM with its maxval; gray, colour or with alpha; lit anywhere from dim to
    bright. Returns the file's suffix, its bytes and the 8-bit image it must read as."""
    height, width = int(rng.integers(1, 80)), int(rng.integers(1, 80))
    channels = int(rng.choice([1, 3, 4]))
    netpbm = channels != 4 and rng.random() < 0.5  # (Netpbm's PAM would hold alpha)
    bits = int(rng.integers(9, 16))
    top = int(rng.choice([2**bits - 1, 1000, 3000, 10_000])) if netpbm else 2**bits - 1
    light = rng.uniform(0.05, 1.0)
    colour = rng.uniform(0, light, (height, width, min(channels, 3)))
    samples = np.round(colour * top).astype(np.uint16)
    expected = (samples.astype(np.int64) * 255 + top // 2) // top
    if channels == 4:
        samples = np.concatenate([samples, rng.integers(0, top + 1, (height, width, 1))], axis=2)
    stored = samples[:, :, 0] if channels == 1 else samples.astype(np.uint16)
    bgr = np.repeat(expected, 3, axis=2) if channels == 1 else expected
    if netpbm:
        data = cv2.imencode(".pgm" if channels == 1 else ".ppm", stored)[1].tobytes()
        return ".pnm", data.replace(b"65535", str(top).encode(), 1), bgr
    png = cv2.imencode(".png", stored)[1].tobytes()
    return ".png", _with_sbit(png, [bits] * channels), bgr


def test_camera_data_below_16_bits_reads_as_its_own_range(tmp_path: Path) -> None:
    """300 generated scenes stored by cameras of 9-15 bits (a PNG's sBIT, a Netpbm maxval): each
    reads as the 8-bit image of its own range (before: divided by 65535, a 12-bit scene was
    nearly black, its brightest pixel 16 of 255)."""
    rng = np.random.default_rng(20261202)
    for case in range(300):
        suffix, data, expected = _deep_case(rng)
        (tmp_path / f"scene{suffix}").write_bytes(data)
        loaded = load(tmp_path, options={"path": f"scene{suffix}"}).image
        assert loaded.dtype == np.uint8 and loaded.shape == expected.shape, case
        np.testing.assert_array_equal(loaded, expected, err_msg=f"case {case} ({suffix})")


def test_a_png_scaled_to_16_bits_as_its_sbit_asks_reads_as_16_bits(tmp_path: Path) -> None:
    """The PNG standard's way: 12 significant bits, stored scaled up to the full 16."""
    bgr = np.random.default_rng(1).integers(0, 256, (30, 40, 3)).astype(np.uint8)
    png = cv2.imencode(".png", bgr.astype(np.uint16) * 257)[1].tobytes()
    (tmp_path / "scene.png").write_bytes(_with_sbit(png, [12, 12, 12]))
    np.testing.assert_array_equal(load(tmp_path).image, bgr)


@pytest.mark.parametrize("suffix", [".png", ".tiff"])
def test_unscaled_12_bit_data_that_does_not_say_so_is_refused(tmp_path: Path, suffix: str) -> None:
    samples = np.random.default_rng(2).integers(0, 4096, (30, 40, 3)).astype(np.uint16)
    assert cv2.imwrite(str(tmp_path / f"scene{suffix}"), samples)
    with pytest.raises(KeympsError) as refused:
        load(tmp_path, options={"path": f"scene{suffix}"})
    message = str(refused.value)
    assert "is 16-bit, but no sample reaches 4096 (the largest is 4095)" in message
    assert f"scene{suffix}" in message and "\n" not in message
