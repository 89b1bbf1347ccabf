"""From a suite case to the scene it is run on and the task file that runs it."""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from keymps.eval.suites import Case, Suite
    from keymps.scenes.render import SceneSpec

DEFAULT_TASK: dict[str, Any] = {
    "detector": {"name": "board"},
    "height": {"mode": "start", "margin": 0.005},
    "motion": {"clearance": 0.03, "work_speed": 0.03, "travel_speed": 0.15},
    "robot": {"model": "ur3", "tool": "knife"},
    "executor": {"name": "file"},
}
"""What a case's task starts from before the suite's and the case's own sections."""


@dataclass(frozen=True)
class CaseScene:
    """The exact dimensions a case's scene is rendered with for one seed."""

    kinds: tuple[str, ...]
    seed: int
    length: float
    width: float
    height: float
    rotation: float
    board: tuple[float, float]
    px_per_m: float
    heights: tuple[float, ...] = ()
    """Several objects: each one's height, left to right (sizes come from the seed)."""

    def source_options(self) -> dict[str, Any]:
        """scene.source_options for the `synthetic` image source (renders exactly this scene)."""
        if self.heights:  # several objects: sizes from the seed, heights from scene.objects
            return {
                "object": list(self.kinds),
                "seed": self.seed,
                "rotation": round(self.rotation, 4),
                "px_per_m": self.px_per_m,
            }
        return {
            "object": list(self.kinds) if len(self.kinds) > 1 else self.kinds[0],
            "seed": self.seed,
            "length": round(self.length, 6),
            "width": round(self.width, 6),
            "height": round(self.height, 6),
            "rotation": round(self.rotation, 4),
            "px_per_m": self.px_per_m,
        }

    def spec(self) -> SceneSpec:
        from dataclasses import replace

        from keymps.scenes.render import SceneSpec

        options = self.source_options()
        if self.heights:
            spec = SceneSpec.from_kinds(
                list(self.kinds),
                seed=self.seed,
                rotation=options["rotation"],
                board_size=self.board,
                px_per_m=self.px_per_m,
            )
            objects = tuple(
                replace(o, height=round(h, 6))
                for o, h in zip(spec.objects, self.heights, strict=True)
            )
            return replace(spec, objects=objects)
        return SceneSpec.from_kinds(
            list(self.kinds),
            seed=self.seed,
            length=options["length"],
            width=options["width"],
            height=options["height"],
            rotation=options["rotation"],
            board_size=self.board,
            px_per_m=self.px_per_m,
        )


def case_scene(suite: Suite, case: Case, seed: int) -> CaseScene:
    """The case's object with its dimensions randomized by `seed` (same seed, same scene)."""
    from keymps.scenes.render import KINDS

    kind = KINDS[case.kinds[0]]
    rng = np.random.default_rng([seed, 8])
    j = case.scene.jitter
    if len(case.kinds) > 1:
        return CaseScene(
            kinds=tuple(case.kinds),
            seed=seed,
            length=kind.length,
            width=kind.width,
            height=kind.height,
            rotation=float(case.scene.rotation if case.scene.rotation is not None else 0.0),
            board=(float(suite.board[0]), float(suite.board[1])),
            px_per_m=float(suite.px_per_m),
            heights=tuple(
                float(KINDS[k].height * rng.uniform(1.0 - j, 1.0 + j)) for k in case.kinds
            ),
        )
    scale = rng.uniform(1.0 - j, 1.0 + j, size=3)
    length = (case.scene.length or kind.length) * scale[0]
    width = length if kind.round else (case.scene.width or kind.width) * scale[1]
    height = (case.scene.height or kind.height) * scale[2]
    if case.scene.rotation is not None:
        rotation = case.scene.rotation
    elif kind.round:
        rotation = rng.uniform(-180.0, 180.0)
    else:
        rotation = rng.uniform(-3.0, 3.0)
    return CaseScene(
        kinds=tuple(case.kinds),
        seed=seed,
        length=float(length),
        width=float(width),
        height=float(height),
        rotation=float(rotation),
        board=(float(suite.board[0]), float(suite.board[1])),
        px_per_m=float(suite.px_per_m),
    )


def merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Deep merge of task sections: mappings merged key by key, anything else replaced."""
    result = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(result.get(key), dict):
            result[key] = merged(result[key], value)
        else:
            result[key] = copy.deepcopy(value)
    return result


def case_task_data(
    suite: Suite, case: Case, seed: int, primitives: list[str] | None = None
) -> dict[str, Any]:
    """The task (as task-file data) that runs `case` on its scene for `seed`."""
    scene = case_scene(suite, case, seed)
    sections = merged(merged(DEFAULT_TASK, suite.task), case.task)
    data: dict[str, Any] = {
        "name": f"{suite.name}-{case.id}-{'-'.join(case.kinds)}",
        "instruction": case.instruction,
        "scene": {
            "source": "synthetic",
            "source_options": scene.source_options(),
            "workspace": {"size": list(scene.board), "shift": [0.0, 0.0]},
            "object_height": round(scene.height, 6),
        },
        "primitives": list(primitives or case.primitives or suite.primitives),
    }
    if scene.heights:  # the objects, left to right, with their names and heights
        data["scene"]["object_height"] = round(max(scene.heights), 6)
        data["scene"]["objects"] = [
            {"name": kind.replace("_", " "), "height": round(height, 6)}
            for kind, height in zip(scene.kinds, scene.heights, strict=True)
        ]
    return merged(sections, data)
