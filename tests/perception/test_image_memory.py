"""An image the process has not the memory for is refused in one line, before it is decoded.

An 8000 x 7999 PNG is within scene.max_image_pixels (64 MP) but a run takes over 5 GB for it
(detection's float32 Lab image, model planes, masks); on a smaller machine it ended in
"unexpected MemoryError". The run now budgets width x height x (the decoded samples and their
working copies, or detection's bytes per pixel) against the memory the process may still take
(the machine's available memory, a container's limit, ulimit -v) and refuses before decoding.
The runs here are child processes under a real address-space limit, their peak memory read
from /proc; the budget's bytes per pixel is checked against the peak of real runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from keymps.config.limits import image_bytes_needed, image_layout_from_header

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/status").exists(), reason="reads peak memory from Linux's /proc"
)


def scene(width: int, height: int, kind: str = "rgb8") -> np.ndarray:
    """A grey board with a cake on it, in the given layout."""
    image = np.full((height, width, 3), (200, 200, 200), np.uint8)
    cv2.circle(image, (width // 2, height // 2), min(width, height) // 4, (60, 90, 200), -1)
    if kind == "gray8":
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    if kind == "rgba16":
        return cv2.cvtColor(image, cv2.COLOR_BGR2BGRA).astype(np.uint16) * 257
    return image


def task(folder: Path, image: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "task.yaml"
    path.write_text(
        "name: big\ninstruction: Put 1 icing dot on the cake.\n"
        f"scene: {{image: {image}, object_height: 0.06}}\n"
        "planner: {backend: offline}\nprimitives: [line]\n"
        "robot: {model: ur3, tool: piping_bag}\nexecutor: {name: sim}\n"
    )
    return path


CHILD = """
import json, resource, sys
import keymps
from keymps import RunOptions, RunOverrides
from keymps.errors import KeympsError

def status(field):
    text = open("/proc/self/status").read()
    return int(text.split(field + ":")[1].split()[0]) * 1024

OFF = RunOptions(rerun="off")
keymps.run_task(sys.argv[1], options=OFF, overrides=RunOverrides(out=sys.argv[2]))  # warms up
base, limit_gb = status("VmHWM"), float(sys.argv[5])
if limit_gb:
    limit = status("VmSize") + int(limit_gb * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
try:
    keymps.run_task(sys.argv[3], options=OFF, overrides=RunOverrides(out=sys.argv[4]))
    error = None
except KeympsError as caught:
    error = str(caught)
print(json.dumps({"error": error, "peak_over_base": status("VmHWM") - base}))
"""


def child_run(tmp_path: Path, image: Path, limit_gb: float = 0.0) -> dict[str, Any]:
    """A run of `image` in a fresh process (after a small warm-up run), its address space
    limited to `limit_gb` more than it holds (0: no limit); its error and peak memory."""
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), scene(600, 360))
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            CHILD,
            str(task(tmp_path / "warm", small)),
            str(tmp_path / "warm-run"),
            str(task(tmp_path / "task", image)),
            str(tmp_path / "run"),
            str(limit_gb),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


@pytest.fixture(scope="module")
def huge_png(tmp_path_factory: Any) -> Path:
    """8000 x 7999 pixels (64 MP, within scene.max_image_pixels), about 0.2 MB of PNG."""
    path = Path(tmp_path_factory.mktemp("huge")) / "huge.png"
    cv2.imwrite(str(path), scene(8000, 7999))
    return path


def test_an_image_the_memory_left_cannot_take_is_refused_before_decoding(
    huge_png: Path, tmp_path: Path, fuzz_counter: Any
) -> None:
    outcome = child_run(tmp_path, huge_png, limit_gb=2.0)
    error = outcome["error"] or ""
    assert error.startswith(f"image: scene image {huge_png} is 8000 x 7999 pixels"), error
    assert "3 channels of 8 bits" in error and "address-space limit (ulimit -v)" in error
    assert "MemoryError" not in error and "\n" not in error
    assert outcome["peak_over_base"] < 100 * 2**20, "refused before decoding (192 MB)"
    assert not (tmp_path / "run" / "plan.png").exists()
    fuzz_counter.add("VLM attacks/image memory", "64 MP under a 2 GB limit", "refused")


def test_an_image_the_memory_left_can_take_still_runs(tmp_path: Path) -> None:
    image = tmp_path / "scene.png"
    cv2.imwrite(str(image), scene(2000, 1500))  # a budget of about 0.3 GB
    outcome = child_run(tmp_path, image, limit_gb=2.0)
    assert outcome["error"] is None
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["ok"] and record["image"]["size_px"] == [2000, 1500]


@pytest.mark.parametrize("kind", ["rgb8", "rgba16"])
def test_the_budget_covers_a_real_runs_peak(kind: str, tmp_path: Path) -> None:
    """Measured peak of a whole run (offline, sim executor) over its warm start, against the
    budget: never above it, and not far below (a stale constant would show)."""
    image = tmp_path / "scene.png"
    cv2.imwrite(str(image), scene(3000, 2000, kind))
    budget = image_bytes_needed((3000, 2000), image_layout_from_header(image.read_bytes()))
    peak = child_run(tmp_path, image)["peak_over_base"]
    assert 0.6 * budget < peak <= budget, (peak / 2**20, budget / 2**20)


@pytest.mark.parametrize(
    ("kind", "extension", "layout"),
    [
        ("rgb8", ".png", (3, 1)),
        ("gray8", ".png", (1, 1)),
        ("rgba16", ".png", (4, 2)),
        ("rgb8", ".jpg", (3, 1)),
        ("gray8", ".jpg", (1, 1)),
        ("rgb8", ".bmp", None),
    ],
)
def test_the_layout_is_read_from_the_header(
    kind: str, extension: str, layout: tuple[int, int] | None
) -> None:
    ok, encoded = cv2.imencode(extension, scene(40, 30, kind))
    assert ok and image_layout_from_header(encoded.tobytes()) == layout
