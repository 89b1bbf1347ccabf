"""Scenes of several objects on the paper's real board, and task files for them (issue 20 tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from helpers.task_files import ICING, KNIFE
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene

__all__ = ["BOARD", "ICING", "KNIFE", "loaves", "scene_file", "task_text"]

BOARD = (0.38, 0.24)


def scene_file(tmp_path: Path, objects: list[ObjectSpec], seed: int = 0) -> tuple[Path, dict]:
    spec = SceneSpec(tuple(objects), seed=seed, board_size=BOARD)
    rendered = render_scene(spec)
    png, _ = rendered.save(tmp_path / f"scene{seed}.png")
    return png, rendered.truth


def task_text(png: Path, instruction: str, tools: str, extra: str = "") -> str:
    return (
        f"name: multi\ninstruction: {instruction}\n"
        f"scene:\n  image: {png}\n  workspace: {{size: [{BOARD[0]}, {BOARD[1]}]}}\n{extra}"
        f"planner: {{backend: offline}}\n{tools}executor: {{name: sim}}\n"
    )


def loaves(seed: int, count: int = 2) -> list[ObjectSpec]:
    """`count` loaves standing upright (rotated 90 degrees) side by side, sizes varied."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(0.0, BOARD[0], count + 2)[1:-1]
    spacing = BOARD[0] / (count + 1)
    return [
        ObjectSpec(
            "banana_bread",
            float(rng.uniform(0.14, 0.18)),
            float(min(0.08, rng.uniform(0.55, 0.7) * spacing)),
            float(rng.uniform(0.05, 0.09)),
            float(90 + rng.uniform(-4, 4)),
            centre=(float(x + rng.uniform(-0.005, 0.005)), float(0.12 + rng.uniform(-0.01, 0.01))),
        )
        for x in xs
    ]
