"""The `mujoco` image source: the task's scene rendered by the simulator's top-down camera.

The board (the task's workspace) and the objects (keymps.scenes kinds: footprint, size, height,
placement) are built as MuJoCo bodies and seen from the same orthographic camera the `mujoco`
executor films with, so a whole run can start in the simulator: render, detect, plan, execute,
render the outcome. Without a `colour` the tops carry the kind's synthetic texture (crust,
toppings, icing); with one they are that flat colour.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from keymps.plugin import ImageSourceError, KeympsError, parse_options
from keymps.types import SceneImage

if TYPE_CHECKING:
    from keymps.run import Run

RGB = tuple[int, int, int]


class MujocoSourceOptions(BaseModel):
    """scene.source_options for `source: mujoco`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    object: str | list[str] = "round_cake"
    """One object kind (keymps scene kinds), or several (placed left to right)."""
    seed: int = 0
    """Varies the placement, outline and texture."""
    length: float | None = Field(default=None, gt=0, le=5)
    width: float | None = Field(default=None, gt=0, le=5)
    height: float | None = Field(default=None, gt=0, le=1)
    """Object height in metres; scene.object_height when omitted."""
    rotation: float | None = Field(default=None, ge=-180, le=180)
    colour: tuple[int, int, int] | None = None
    """RGB 0-255: the objects' flat colour (else the kind's texture)."""
    board_colour: tuple[int, int, int] | None = None
    """RGB 0-255: a plain board (else wood)."""
    px_per_m: float = Field(default=2000.0, ge=100, le=10_000)


class MujocoSource:
    """Builds the scene in MuJoCo and renders it from the top-down camera."""

    def __init__(self, options: MujocoSourceOptions):
        self.options = options

    def load(self, run: Run) -> SceneImage:
        import cv2

        from keymps.config.limits import check_image_pixels
        from keymps.scenes.render import SceneSpec, render_scene_cached
        from keymps_mujoco.model import TOP_CAMERA, Prop, Settings, build_scene
        from keymps_mujoco.render import Renderer

        task = run.task
        options = self.options
        kinds = [options.object] if isinstance(options.object, str) else list(options.object)
        height = options.height if options.height is not None else task.scene.object_height
        workspace = task.scene.workspace
        spec = SceneSpec.from_kinds(
            kinds,
            seed=options.seed,
            length=options.length,
            width=options.width,
            height=height,
            rotation=options.rotation,
            board_size=tuple(workspace.size),
            px_per_m=options.px_per_m,
        )
        size_px = spec.image_size_px
        try:
            check_image_pixels(size_px, task.scene.max_image_pixels, "the mujoco scene")
        except KeympsError as error:
            raise ImageSourceError(str(error)) from None
        synthetic = render_scene_cached(spec)
        shift = (float(workspace.shift[0]), float(workspace.shift[1]))
        texture = np.ascontiguousarray(synthetic.image[:, :, ::-1])  # RGB
        if options.board_colour is not None:
            texture[:] = np.array(options.board_colour, np.uint8)
        props = []
        for truth in synthetic.truth["objects"]:
            outline = np.asarray(truth["outline_m"], dtype=float) + shift
            if options.colour is not None or options.board_colour is not None:
                fill = (
                    options.colour
                    if options.colour is not None
                    else _mean(synthetic.image, truth["outline_px"])
                )
                pixels = np.round(np.asarray(truth["outline_px"]) * 16).astype(np.int32)
                cv2.fillPoly(texture, [pixels], tuple(int(v) for v in fill), cv2.LINE_AA, 4)
            props.append(Prop(outline, float(truth["height_m"]), name=truth["kind"]))
        scene = build_scene(
            None,
            (float(workspace.size[0]), float(workspace.size[1])),
            shift,
            tuple(props),
            texture,
            Settings(top_size_px=size_px, perspective_size_px=size_px),
        )
        with Renderer(scene) as renderer:
            image = renderer.render(TOP_CAMERA, size_px, show_arm=False)
        return SceneImage(image=image, source=f"mujoco:{'+'.join(kinds)}:seed={options.seed}")


def _mean(image_bgr: np.ndarray, outline_px: Any) -> RGB:
    import cv2

    mask = np.zeros(image_bgr.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(outline_px)).astype(np.int32)], 1)
    b, g, r = (int(v) for v in image_bgr[mask > 0].mean(axis=0))
    return (r, g, b)


def make_source(options: dict[str, Any]) -> MujocoSource:
    parsed = parse_options(
        MujocoSourceOptions, options, "mujoco image source: scene.source_options"
    )
    from keymps.scenes.render import check_kinds

    kinds = [parsed.object] if isinstance(parsed.object, str) else list(parsed.object)
    check_kinds(kinds, where="scene.source_options.object")
    return MujocoSource(parsed)
