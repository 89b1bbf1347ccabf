"""Built-in image sources: an image file, a synthetic scene, or one frame from an OpenCV camera."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field

from keymps.errors import ImageSourceError, KeympsError
from keymps.perception.image_io import read_image, to_bgr8
from keymps.plugin import RegisterImageSource, hookimpl, parse_options
from keymps.types import SceneImage


def _parse(model: type[BaseModel], options: dict[str, Any], source: str) -> Any:
    return parse_options(model, options, f"{source} image source: scene.source_options")


MAX_OBJECTS = 50
"""Objects in one synthetic scene (the renderer places them left to right on the board)."""
MAX_CAMERA_SIDE_PX = 2**16
"""No camera frame is wider or taller than this."""


class FileOptions(BaseModel):
    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)
    path: Path | None = None
    """Read this file instead of scene.image (relative to the task file)."""


class FileSource:
    """scene.image, resolved relative to the task file."""

    def __init__(self, options: FileOptions):
        self.options = options

    def load(self, run: Any) -> SceneImage:
        task = run.task
        relative = self.options.path or task.scene.image
        if relative is None:
            raise ImageSourceError("scene.image is not set (the file source needs an image)")
        path = task.resolve(Path(relative))
        return SceneImage(image=read_image(path, task.scene.max_image_pixels), source=str(path))


class SyntheticOptions(BaseModel):
    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)
    object: str | Annotated[list[str], Field(max_length=MAX_OBJECTS)] = "round_cake"
    """One object kind, or several (placed left to right)."""
    seed: int = Field(default=0, ge=0, le=2**63 - 1)
    length: float | None = Field(default=None, gt=0, le=5)
    width: float | None = Field(default=None, gt=0, le=5)
    height: float | None = Field(default=None, gt=0, le=1)
    """Object height in metres; scene.object_height when omitted."""
    rotation: float | None = Field(default=None, ge=-180, le=180)
    px_per_m: float = Field(default=2000.0, ge=100, le=20_000)


class SyntheticSource:
    """A scene rendered by keymps.scenes.render on the task's workspace (its size is the board's)."""

    def __init__(self, options: SyntheticOptions):
        self.options = options

    def load(self, run: Any) -> SceneImage:
        from keymps.config.limits import check_image_pixels
        from keymps.scenes.render import SceneSpec, render_scene_cached

        task = run.task
        options = self.options
        kinds = [options.object] if isinstance(options.object, str) else list(options.object)
        spec = SceneSpec.from_kinds(
            kinds,
            seed=options.seed,
            length=options.length,
            width=options.width,
            height=options.height if options.height is not None else task.scene.object_height,
            rotation=options.rotation,
            board_size=tuple(task.scene.workspace.size),
            px_per_m=options.px_per_m,
        )
        declared = task.scene.objects or []
        if options.height is None and len(declared) == len(spec.objects):
            # several objects of their own heights: the ones scene.objects gives, left to right
            spec = replace(
                spec,
                objects=tuple(
                    replace(o, height=d.height) if d.height is not None else o
                    for o, d in zip(spec.objects, declared, strict=True)
                ),
            )
        size_px = spec.image_size_px
        try:
            check_image_pixels(size_px, task.scene.max_image_pixels, "the synthetic scene")
        except KeympsError as error:
            raise ImageSourceError(str(error)) from None
        scene = render_scene_cached(spec)
        return SceneImage(
            image=scene.image,
            source=f"synthetic:{'+'.join(kinds)}:seed={options.seed}",
            truth=scene.truth,
        )


class OpenCvOptions(BaseModel):
    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True)
    camera: int | str = 0
    """A camera index (0, 1 ...), a video file, or a stream URL OpenCV can open."""
    warmup_frames: int = Field(default=5, ge=0, le=300)
    """Frames read and dropped first (auto exposure settles)."""
    width: int | None = Field(default=None, gt=0, le=MAX_CAMERA_SIDE_PX)
    height: int | None = Field(default=None, gt=0, le=MAX_CAMERA_SIDE_PX)


class OpenCvSource:
    """One frame grabbed from cv2.VideoCapture."""

    def __init__(self, options: OpenCvOptions):
        self.options = options

    def load(self, run: Any = None) -> SceneImage:
        import cv2

        camera = self.options.camera
        if isinstance(camera, str) and camera.strip().isdigit():
            camera = int(camera)
        if isinstance(camera, str) and "://" not in camera and run is not None:
            camera = str(run.task.resolve(Path(camera)))
        capture = cv2.VideoCapture(camera)
        try:
            if not capture.isOpened():
                raise ImageSourceError(
                    f"cannot open camera {camera!r} (scene.source_options.camera): no such device, "
                    "file or stream, or it is in use"
                )
            if self.options.width:
                capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.options.width)
            if self.options.height:
                capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.options.height)
            frame = None
            for _ in range(self.options.warmup_frames + 1):
                ok, grabbed = capture.read()
                if ok and grabbed is not None:
                    frame = grabbed
                elif frame is not None:
                    break  # a short video: keep its last frame
            if frame is None:
                raise ImageSourceError(f"camera {camera!r} opened but returned no frame")
        finally:
            capture.release()
        return SceneImage(image=to_bgr8(frame), source=f"opencv:{camera}")


def make_file_source(options: dict[str, Any]) -> FileSource:
    return FileSource(_parse(FileOptions, options, "file"))


def make_synthetic_source(options: dict[str, Any]) -> SyntheticSource:
    parsed = _parse(SyntheticOptions, options, "synthetic")
    from keymps.scenes.render import check_kinds

    kinds = [parsed.object] if isinstance(parsed.object, str) else list(parsed.object)
    check_kinds(kinds, where="scene.source_options.object")
    return SyntheticSource(parsed)


def make_opencv_source(options: dict[str, Any]) -> OpenCvSource:
    return OpenCvSource(_parse(OpenCvOptions, options, "opencv"))


@hookimpl
def register_image_sources(register: RegisterImageSource) -> None:
    register("file", make_file_source)
    register("synthetic", make_synthetic_source)
    register("opencv", make_opencv_source)
