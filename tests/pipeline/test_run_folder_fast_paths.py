"""The run folder's pictures: the fast PNG writer keeps every pixel.

Each fast path is held against the implementation it replaced, on generated inputs."""

from __future__ import annotations

from typing import Any

import numpy as np

RNG_SEED = 20261201


def test_run_folder_png_keeps_every_pixel(tmp_path: Any) -> None:
    import cv2

    from keymps.run_files import write_image

    rng = np.random.default_rng(RNG_SEED + 16)
    for trial in range(6):
        height, width = (int(v) for v in rng.integers(1, 400, 2))
        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        if trial % 2:  # flat areas and edges, as drawn scenes have
            image[: height // 2] = image[0, 0]
        path = write_image(tmp_path / f"{trial}.png", image)
        assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), image)
