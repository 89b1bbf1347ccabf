"""execution.mp4: the simulation filmed at a fixed rate of simulated time (plays in real time).

Each frame puts the chosen cameras side by side at one height. OpenCV's writer encodes MPEG-4
Part 2 (`mp4v`), which every OpenCV build can write and every common player reads.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from keymps.plugin import KeympsError


class VideoRecorder:
    """Renders and writes a frame whenever simulated time reaches the next frame's time."""

    def __init__(
        self,
        path: Path,
        renderer: Any,
        fps: float,
        cameras: list[tuple[str, tuple[int, int]]],
        decorate: Callable[[Any], None] | None = None,
        shadows: bool = True,
    ):
        import cv2

        self.path = path
        self.renderer = renderer
        self.fps = float(fps)
        self.cameras = cameras
        self.decorate = decorate
        self.shadows = shadows
        self.frames = 0
        width = sum(size[0] for _, size in cameras)
        height = max(size[1] for _, size in cameras)
        self.size = (width + width % 2, height + height % 2)  # encoders want even sizes
        path.parent.mkdir(parents=True, exist_ok=True)
        self.writer: Any = cv2.VideoWriter(
            str(path), cv2.VideoWriter.fourcc(*"mp4v"), self.fps, self.size
        )
        if not self.writer.isOpened():
            raise KeympsError(f"executor mujoco: OpenCV cannot write the video {path}")

    def due(self, t: float) -> bool:
        """Whether simulated time t has reached the next frame."""
        return t + 1e-9 >= self.frames / self.fps

    def frame(self, t: float) -> None:
        canvas = np.zeros((self.size[1], self.size[0], 3), np.uint8)
        x = 0
        for camera, (width, height) in self.cameras:
            canvas[:height, x : x + width] = self.renderer.render(
                camera,
                (width, height),
                extra=self.decorate,
                shadows=self.shadows and camera != "top",
            )
            x += width
        self.writer.write(canvas)
        self.frames += 1

    def close(self) -> Path:
        if self.writer is not None:
            self.writer.release()
            self.writer = None
        return self.path
