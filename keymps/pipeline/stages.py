"""The engine's perception, plan and ground stages as functions: the code `keymps run` runs, for callers
that measure a part of it (`keymps eval`'s direct methods and its perception benchmark).

The engine calls the same functions inside its timed, announced stages (keymps.pipeline.engine),
so a benchmark built on them measures exactly what a run does: rectification with board
corners, the board refused as an object, the object's top surface, a crop covering every object.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from keymps.errors import KeympsError
from keymps.types import Detection, SceneImage

if TYPE_CHECKING:
    import numpy as np

    from keymps.config.task import Task
    from keymps.perception.scene_objects import SceneObject
    from keymps.primitives.dictionary import Primitive
    from keymps.run import Run
    from keymps.types import GroundedObject, Grounding, Plan

__all__ = [
    "Perception",
    "detected",
    "ground",
    "load_primitives",
    "perceive",
    "plan",
    "rectified",
]


@dataclass(frozen=True)
class Perception:
    """What the image and detect stages found (`run.stages.image`, `run.stages.detect`)."""

    scene: SceneImage
    """The image the later stages work in (rectified when the task gives board corners)."""
    detection: Detection
    """The object's top surface, its crop covering every object."""
    objects: tuple[SceneObject, ...]
    """Every object found, in id order, with its name and height from the task."""
    grounded: tuple[GroundedObject, ...]
    """Every object's footprint in board metres (`run.objects`)."""
    outline_m: np.ndarray
    """(N, 2) the chosen object's footprint in board metres (`run.outline_m`)."""


def rectified(task: Task, loaded: SceneImage) -> SceneImage:
    """The image stage after the image source: the scene as every later stage sees it.

    Args:
        task: The task (its `scene.camera` board corners and intrinsics, if any).
        loaded: What the image source returned.

    Returns:
        The metric top-down image when the task gives board corners, else `loaded` itself.
    """
    from keymps.perception.rectify import rectify_scene

    return rectify_scene(loaded, task)


def detected(task: Task, scene: SceneImage, found: Detection) -> Perception:
    """The detect stage after the detector: the board refused, the top surface, the crop.

    Args:
        task: The task (workspace, heights, `scene.objects`).
        scene: The image stage's result (`rectified`).
        found: What the detector returned for `scene`.

    Returns:
        The perception the plan stage plans on.

    Raises:
        keymps.errors.DetectionError: When the detection is the board, or has no top surface.
        keymps.errors.KeympsError: When the objects found do not match `scene.objects`.
    """
    from keymps.perception import frames as geometry
    from keymps.perception.rectify import top_surface
    from keymps.perception.scene_objects import (
        crop_covering_objects,
        grounded_objects,
        scene_objects,
    )
    from keymps.perception.search_area import refuse_the_board

    detection = top_surface(refuse_the_board(found, scene.size_px), scene)
    detection = crop_covering_objects(detection, scene.image)
    frame = geometry.ImageFrame.for_scene(task, scene)
    objects = scene_objects(detection, task, frame)  # a count mismatch stops here
    return Perception(
        scene=scene,
        detection=detection,
        objects=objects,
        grounded=grounded_objects(objects, frame),
        outline_m=geometry.object_outline_m(detection, task, scene),
    )


def perceive(task: Task, run: Run) -> Perception:
    """The image and detect stages with the task's image source and detector, built by name.

    Args:
        task: The task whose `scene.source` and `detector` run.
        run: The run the image source loads for (its folder, its options).

    Returns:
        What `keymps run` would plan on for this task.

    Raises:
        keymps.errors.KeympsError: On the first problem (a component, the image, the detection).
    """
    from keymps.plugin.manager import create_detector, create_image_source

    source = create_image_source(task.scene.source, task.scene.source_options)
    detector = create_detector(task.detector.name, task.detector.options)
    scene = rectified(task, _of_type(source.load(run), SceneImage, "image source"))
    return detected(task, scene, _of_type(detector.detect(scene), Detection, "detector"))


def load_primitives(task: Task) -> dict[str, Primitive]:
    """The task's primitives, found the way a run finds them (the task's folder first).

    Args:
        task: The task whose `primitives` are loaded.

    Returns:
        name -> primitive, in the task's order.
    """
    from keymps.primitives.dictionary import default_search_dirs
    from keymps.primitives.dictionary import load_primitives as load

    return load(task.primitives, default_search_dirs(task.folder))


def plan(
    task: Task,
    perception: Perception,
    primitives: Mapping[str, Primitive],
    run: Run,
    backend: str,
    repair: list[tuple[str, list[str]]] | None = None,
) -> Plan:
    """The plan stage: a backend's keyword and keypoint pairs, validated, repaired, recorded.

    Args:
        task: The task (instruction, planner settings).
        perception: The perception stages' result (`perceive`).
        primitives: The primitives to choose from (`load_primitives`).
        run: The run whose folder keeps the vlm/ records and whose options apply.
        backend: The planner backend's name (offline, litellm, replay ...).
        repair: Earlier answers and what their predicted outcome got wrong (outcome repair).

    Returns:
        The plan, its pairs in pixels of `perception.scene`.
    """
    from keymps.planning import planner as planning

    earlier = run.stages.plan.calls if repair and run.stages.plan is not None else ()
    return planning.make_plan(
        task,
        perception.detection,
        perception.scene,
        {name: p.description for name, p in primitives.items()},
        run,
        backend,
        {name: p.family for name, p in primitives.items()},
        perception.objects,
        repair=repair or [],
        earlier_calls=earlier,
    )


def ground(task: Task, perception: Perception, plan: Plan) -> Grounding:
    """The ground stage: the plan's pairs as 3D segments in the board frame (App. B, C).

    Args:
        task: The task (workspace, heights, `height` mode).
        perception: The perception the plan was made on.
        plan: The plan stage's result.

    Returns:
        The segments, in metres, on the objects they lie on.
    """
    from keymps.perception import frames as geometry

    scene, detection = perception.scene, perception.detection
    return geometry.ground(plan, detection, task, scene, perception.objects)


def _of_type(result: Any, expected: type, plugin: str) -> Any:
    if not isinstance(result, expected):
        got = "None" if result is None else type(result).__name__
        raise KeympsError(f"the {plugin} returned {got}, not a {expected.__name__}")
    return result
