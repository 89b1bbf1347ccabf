"""Planning (Sec. IV-B/C): the primitive keyword and K keypoint pairs, from any backend.

make_plan renders the prompt, asks the backend (one combined call, or keyword then pairs),
validates each answer, sends invalid ones back with the problems for repair, records every
attempt under run.folder/vlm, and answers from the cache or records to a cassette on request.

Backends implement keymps.plugin.VlmBackend (see docs/vlm.md). The factory receives the planner options: model, api_base, api_key_env, temperature,
timeout_s, cassette (None when unset), and api_base_trusted: False when only the task file
chose the server (its api_base, or a provider's default port on this machine), and then a
backend sends no key from the environment (docs/security.md).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.planning.answer import parse_and_validate
from keymps.planning.backend_choice import (
    api_base_trusted,
    choose_backend,
    credential_source,
    keys_the_task_may_send,
    model_provider,
)
from keymps.planning.redaction import redact_text, remember
from keymps.run_files import write_atomically
from keymps.types import (
    BackendAnswer,
    Detection,
    Plan,
    PlanObject,
    PlanRequest,
    SceneImage,
    VlmCall,
)

if TYPE_CHECKING:
    from keymps.config.task import Task
    from keymps.perception.scene_objects import SceneObject
    from keymps.planning.coordinates import Convention
    from keymps.planning.session import PlanSession
    from keymps.run import Run


def backend_options(task: Task) -> dict[str, Any]:
    """What a backend factory receives: the planner settings a backend may need."""
    planner = task.planner
    return {
        "model": planner.model,
        "api_base": planner.api_base,
        "api_key_env": planner.api_key_env,
        "temperature": planner.temperature,
        "timeout_s": planner.timeout_s,
        "max_tokens": planner.max_tokens,
        "cassette": str(task.resolve(planner.cassette)) if planner.cassette else None,
        "api_base_trusted": api_base_trusted(task),
    }


def prepare_backend_in_background(backend: str, options: dict[str, Any]) -> threading.Thread:
    """Start the backend's set-up (`prepare()`: litellm's import, seconds) on a thread now, so
    that it overlaps whatever comes before the first request; that request waits for what is
    left of it. A backend without `prepare`, or one that cannot be made with these options
    (the plan stage makes it again and says why), is left alone."""
    from keymps.plugin.components import prepare_backend
    from keymps.plugin.manager import create_component, get_manager

    get_manager()  # set up in this thread: the plugin scan is not shared with a thread

    def set_up() -> None:
        with contextlib.suppress(Exception):  # the plan stage makes it again and says why
            prepare_backend(create_component("vlm_backend", backend, options))

    thread = threading.Thread(target=set_up, name="keymps-backend-prepare", daemon=True)
    thread.start()
    return thread


def crop_metres_per_px(task: Task, detection: Detection, scene: SceneImage) -> tuple[float, float]:
    """Metres per pixel at the crop's centre, along x and y (Appendix B or the camera's homography)."""
    width, height = scene.size_px
    try:
        from keymps.perception.frames import ImageFrame
    except ModuleNotFoundError as error:
        if error.name != "keymps.perception.frames":
            raise
        ws = task.scene.workspace.size
        return ws[0] / width, ws[1] / height
    frame = ImageFrame.for_scene(task, scene)
    cx = detection.crop_origin_px[0] + detection.crop_size_px[0] / 2
    cy = detection.crop_origin_px[1] + detection.crop_size_px[1] / 2
    board = frame.to_board(np.array([[cx, cy], [cx + 1, cy], [cx, cy + 1]], dtype=float))
    return (
        float(np.linalg.norm(board[1] - board[0])),
        float(np.linalg.norm(board[2] - board[0])),
    )


def crop_mask(detection: Detection, scene: SceneImage) -> np.ndarray | None:
    """The detector's mask cut to the crop (it may cover the crop or the whole image)."""
    mask = detection.mask
    if mask is None:
        return None
    w, h = detection.crop_size_px
    if mask.shape[:2] == (h, w):
        return np.asarray(mask).astype(bool)
    if mask.shape[:2] == scene.image.shape[:2]:
        x0, y0 = detection.crop_origin_px
        return np.asarray(mask[y0 : y0 + h, x0 : x0 + w]).astype(bool)
    return None


def _line_width_mm(task: Task) -> float:
    from keymps.robot.description import tool_from_task

    try:
        return 1000.0 * tool_from_task(task).line_width
    except KeympsError:  # an unknown tool is reported by the robot model, not here
        return 0.0


def make_plan(
    task: Task,
    detection: Detection,
    scene: SceneImage,
    primitives: Mapping[str, str],
    run: Run,
    backend: str,
    families: Mapping[str, str] | None = None,
    objects: tuple[SceneObject, ...] | None = None,
    repair: Sequence[tuple[str, list[str]]] = (),
    earlier_calls: Sequence[VlmCall] = (),
) -> Plan:
    """Ask `backend` for the keyword and keypoint pairs; validated, repaired, recorded.

    `repair`: earlier valid answers and what their predicted outcome got wrong (the outcome
    stage's repair rounds), shown to the model before it answers again; `earlier_calls`: those
    rounds' calls (recorded in vlm/ before this round's, and counted in the plan's).

    `families`: primitive name -> family (cutting, icing); read from the descriptions when
    None. The sentence and the plan must fit the task's tool family (keymps.planning.family).
    `objects`: the scene's objects (keymps.perception.scene_objects; from the detection when
    None). Each pair is assigned to the object it lies on (plan.pair_objects), and the pairs are
    ordered object by object along a short tour from the robot base.
    """
    from keymps.planning.family import check_plan, check_sentence, families_from_descriptions
    from keymps.planning.intent import plan_intents
    from keymps.plugin.components import BackendAbilities
    from keymps.plugin.manager import create_vlm_backend

    if not primitives:
        raise KeympsError("primitives: the task lists no primitives to choose from")
    families = dict(families) if families is not None else families_from_descriptions(primitives)
    check_sentence(task, task.instruction, families)
    remember(*keys_the_task_may_send(task))
    backend_object = create_vlm_backend(backend, backend_options(task))
    prompt_path = _prompt_path(task, primitives)
    asks_model = BackendAbilities.of(backend_object).asks_model
    view = _view(task, detection, scene, objects, task.planner.model if asks_model else None)
    session = _session(task, run, (backend, backend_object), primitives, view, prompt_path)
    session.calls.extend(earlier_calls)  # recorded before this round's calls
    keyword, placed, rationale = _ask(session, task.planner.combined, repair)
    check_plan(task, keyword, families)
    pairs_crop, layout = _pairs_in_crop(placed, keyword, families, task, detection, view)
    if layout is not None:
        rationale = f"{rationale} [named design laid out by keymps: {layout}]".strip()
    pairs_crop, owners = _by_object(pairs_crop, view.crop_objects, task, detection, scene)
    return Plan(
        keyword=keyword,
        pairs_crop_px=pairs_crop,
        pairs_px=pairs_crop + np.asarray(detection.crop_origin_px, dtype=float),
        backend=backend,
        model=view.model,
        rationale=redact_text(rationale),
        calls=tuple(session.calls),
        coordinates=view.convention,
        design=placed.design.model_dump() if placed.design is not None else None,
        image_sent_px=view.size if view.size != view.crop_size else None,
        pair_objects=owners,
        intents=plan_intents(placed, session.family, asks_model),
    )


@dataclass(frozen=True)
class _View:
    """The crop as the model sees it (`size` px) beside the full-resolution crop it came from."""

    model: str | None  # None: the backend asks no model and answers in pixels of the full crop
    convention: Convention
    crop_size: tuple[int, int]
    crop_metres_per_px: tuple[float, float]
    crop_objects: tuple[PlanObject, ...]
    size: tuple[int, int]
    image: np.ndarray
    mask: np.ndarray | None
    metres_per_px: tuple[float, float]
    objects: tuple[PlanObject, ...]


def _prompt_path(task: Task, primitives: Mapping[str, str]) -> Path:
    """The system prompt template: the task's planner.prompt, else the family's shipped one."""
    from keymps.planning.prompt import find_prompt, prompt_family

    planner = task.planner
    return find_prompt(
        task.resolve(planner.prompt) if planner.prompt else None,
        task.folder,
        prompt_family(primitives),
        where=f"{task.where('planner', 'prompt')}: planner.prompt",
    )


def _view(
    task: Task,
    detection: Detection,
    scene: SceneImage,
    objects: tuple[SceneObject, ...] | None,
    model: str | None,
) -> _View:
    """The crop, its mask, scale and objects, at the size `model` is sent (full size for None)."""
    from keymps.perception.scene_objects import scene_objects
    from keymps.planning.coordinates import resolve, sent_size
    from keymps.planning.objects import plan_objects, scaled_objects

    crop = detection.crop
    crop_size = (int(crop.shape[1]), int(crop.shape[0]))
    size = sent_size(crop_size, model) if model is not None else crop_size
    metres_per_px = crop_metres_per_px(task, detection, scene)
    mask = crop_mask(detection, scene)
    sent, sent_mask, sent_metres = _downscaled(crop, mask, metres_per_px, size)
    if objects is None:
        from keymps.perception.frames import ImageFrame

        objects = scene_objects(detection, task, ImageFrame.for_scene(task, scene))
    in_crop = plan_objects(
        objects, detection.crop_origin_px, crop_size, scene.image.shape, metres_per_px, mask
    )
    return _View(
        model=model,
        convention=resolve(task.planner.coordinates, model) if model is not None else "pixels",
        crop_size=crop_size,
        crop_metres_per_px=metres_per_px,
        crop_objects=in_crop,
        size=size,
        image=sent,
        mask=sent_mask,
        metres_per_px=sent_metres,
        objects=scaled_objects(in_crop, crop_size, size, sent_mask),
    )


def _session(
    task: Task,
    run: Run,
    backend: tuple[str, Any],
    primitives: Mapping[str, str],
    view: _View,
    prompt_path: Path,
) -> PlanSession:
    """The plan session over the request built from `view`; vlm/crop.png written."""
    from keymps.planning.objects import mark_objects
    from keymps.planning.prompt import png_bytes, png_data_url, prompt_family
    from keymps.planning.session import PlanSession

    planner = task.planner
    marked = mark_objects(view.image, view.objects)  # several objects: their numbers on it
    crop_png = png_bytes(marked)  # encoded once: sent, and kept as vlm/crop.png
    base = PlanRequest(
        instruction=task.instruction,
        crop=view.image,
        crop_mask=view.mask,
        metres_per_px=view.metres_per_px,
        primitives=dict(primitives),
        object_height=task.scene.object_height,
        max_pairs=planner.max_pairs,
        messages=[],
        schema={},
        model=view.model,
        temperature=planner.temperature,
        timeout_s=planner.timeout_s,
        task_name=task.name,
        line_width_mm=_line_width_mm(task),
        objects=view.objects,
        answer_mode=planner.answer,
    )
    session = PlanSession(
        task=task,
        run=run,
        backend_name=backend[0],
        backend=backend[1],
        base=base,
        system_template=_read_prompt(prompt_path),
        template_source=str(prompt_path),
        image_url=png_data_url(marked, crop_png),
        convention=view.convention,
        answer_mode=planner.answer,
        family=prompt_family(primitives),
    )
    session.vlm_folder.mkdir(parents=True, exist_ok=True)
    write_atomically(session.vlm_folder / "crop.png", crop_png)
    return session


def _ask(
    session: PlanSession, combined: bool, repair: Sequence[tuple[str, list[str]]]
) -> tuple[str, Any, str]:
    """The keyword, the answer that places the pairs and the rationale: one call or two."""
    if combined:
        answer = session.ask("combined", earlier=repair)
        return answer.keyword, answer, answer.rationale
    chosen = session.ask("keyword")
    placed = session.ask("pairs", keyword=chosen.keyword, earlier=repair)
    rationale = " ".join(r for r in (chosen.rationale, placed.rationale) if r)
    return chosen.keyword, placed, rationale


def _pairs_in_crop(
    placed: Any,
    keyword: str,
    families: Mapping[str, str],
    task: Task,
    detection: Detection,
    view: _View,
) -> tuple[np.ndarray, str | None]:
    """The answer's pairs in full-crop pixels, (K, 2, 2), and a named design's layout note."""
    from keymps.planning.coordinates import rescale, to_pixels

    if placed.design is None:
        answered = np.asarray(placed.pairs, dtype=float).reshape(-1, 2, 2)
        pixels = to_pixels(answered, view.convention, view.size)
        return rescale(pixels, view.size, view.crop_size), None
    on = _design_object(placed.design, view.crop_objects)
    return _lay_out(
        placed.design,
        keyword,
        families,
        detection,
        on.mask,
        view.crop_metres_per_px,
        task.planner.max_pairs,
        _line_width_mm(task),
    )


def _downscaled(
    crop: np.ndarray,
    mask: np.ndarray | None,
    metres_per_px: tuple[float, float],
    size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray | None, tuple[float, float]]:
    """The crop, its mask and pixel size at `size` (unchanged when it already is that size)."""
    width, height = int(crop.shape[1]), int(crop.shape[0])
    if (width, height) == size:
        return crop, mask, metres_per_px
    import cv2

    image = cv2.resize(crop, size, interpolation=cv2.INTER_AREA)
    small = None
    if mask is not None:
        small = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    scaled = (metres_per_px[0] * width / size[0], metres_per_px[1] * height / size[1])
    return image, small, scaled


def _lay_out(
    answer: Any,
    keyword: str,
    families: Mapping[str, str],
    detection: Detection,
    mask: np.ndarray | None,
    metres_per_px: tuple[float, float],
    max_pairs: int,
    line_width_mm: float = 0.0,
) -> tuple[np.ndarray, str]:
    """A named design's exact pairs in crop pixels, on the full-resolution crop."""
    from keymps.designs.place import place_design
    from keymps.planning.named_design import BY_NAME, to_intent

    intent, problems = to_intent(answer)
    if intent is None:  # validated already; kept for a backend that skips validation
        raise KeympsError(f"the named design is invalid: {'; '.join(problems)}")
    needed = BY_NAME[answer.name].family
    if families.get(keyword, needed) != needed:
        raise KeympsError(
            f"the plan names the {needed} design {answer.name!r} with the "
            f"{families[keyword]} primitive {keyword!r}"
        )
    return place_design(
        intent, detection.crop, mask, metres_per_px, max_pairs, line_width_mm=line_width_mm
    )


def _by_object(
    pairs_crop: np.ndarray,
    objects: tuple[PlanObject, ...],
    task: Task,
    detection: Detection,
    scene: SceneImage,
) -> tuple[np.ndarray, tuple[int, ...]]:
    """The pairs with the object each lies on, in visiting order (a short tour from the base)."""
    from keymps.perception.frames import ImageFrame
    from keymps.planning.objects import assign_pairs, visit_order

    owners = assign_pairs(pairs_crop, objects)
    frame = ImageFrame.for_scene(task, scene)
    base_px = frame.to_pixels(np.array([task.robot.base_xy(task.scene.workspace)], dtype=float))[0]
    start = base_px - np.asarray(detection.crop_origin_px, dtype=float)
    order = visit_order(owners, objects, (float(start[0]), float(start[1])))
    return pairs_crop[order], tuple(owners[k] for k in order)


def _design_object(answer: Any, objects: tuple[PlanObject, ...]) -> PlanObject:
    """The object a named design is for: the only one, or the one its `object` id names."""
    wanted = getattr(answer, "object", None)
    if len(objects) == 1 and wanted in (None, objects[0].id):
        return objects[0]
    by_id = {o.id: o for o in objects}
    if wanted is None:
        raise KeympsError(
            f"the named design {answer.name!r} does not say which of the {len(objects)} objects "
            f"it is for (design.object: one of {sorted(by_id)})"
        )
    if wanted not in by_id:
        raise KeympsError(
            f"the named design {answer.name!r} is for object {wanted}, but the objects are "
            f"{sorted(by_id)}"
        )
    return by_id[wanted]


def _read_prompt(path: Path) -> str:
    from keymps.config.trust import MAX_PROMPT_BYTES

    try:
        with path.open("rb") as handle:  # bounded: the file may have grown since it was checked
            data = handle.read(MAX_PROMPT_BYTES + 1)
        if len(data) > MAX_PROMPT_BYTES:
            raise KeympsError(f"prompt template {path} has more than {MAX_PROMPT_BYTES} bytes")
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise KeympsError(f"prompt template {path} is not a UTF-8 text file") from None
    except OSError as error:
        raise KeympsError(f"cannot read the prompt template {path}: {error.strerror}") from None


__all__ = [
    "BackendAnswer",
    "PlanRequest",
    "backend_options",
    "choose_backend",
    "credential_source",
    "make_plan",
    "model_provider",
    "parse_and_validate",
]
