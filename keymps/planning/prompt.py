"""Prompt templates: find them, fill their {{placeholders}}, build the chat messages.

A template is a Markdown file (prompts/cutting.md, prompts/icing.md) that becomes the system
message. Placeholders are `{{name}}`; an unknown name is an error naming the file and line.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from keymps.config.trust import (
    MAX_PROMPT_BYTES,
    prompt_roots,
    prompt_search_dirs,
    readable_file_problem,
)
from keymps.errors import KeympsError
from keymps.planning.answer import Step

PLACEHOLDERS: dict[str, str] = {
    "instruction": "the user's sentence",
    "primitives": "a bulleted list '- name: description' of the task's primitives",
    "primitive_names": "the primitive names, comma separated",
    "crop_width": "width of the image sent, pixels",
    "crop_height": "height of the image sent, pixels",
    "mm_per_pixel": "millimetres per pixel of the image sent (x; y if they differ)",
    "object_height_cm": "the object's height, centimetres",
    "max_pairs": "the largest number of keypoint pairs accepted",
    "output_format": "the JSON the model must answer with, for this call",
    "step": "what this call must decide (combined, keyword, or pairs)",
    "coordinates": "the coordinate paragraph for planner.coordinates (pixels or 0-1000)",
    "examples": "worked examples in the task's coordinate convention and answer form",
    "designs": "the named designs the answer may use (planner.answer), or that it may not",
}
"""Every placeholder a template may use, and what it becomes."""

_PLACEHOLDER = re.compile(r"\{\{\s*([a-zA-Z_][a-zA-Z0-9_]*)\s*\}\}")

_OUTPUT_FORMATS: dict[str, str] = {
    "combined": (
        "Answer with one JSON object and nothing else:\n"
        '{"keyword": "<one primitive name>", "pairs": [[[x0, y0], [x1, y1]], ...], '
        '"rationale": "<one or two sentences>"}'
    ),
    "keyword": (
        "This call chooses the primitive only. Answer with one JSON object and nothing else:\n"
        '{"keyword": "<one primitive name>", "rationale": "<one or two sentences>"}'
    ),
    "pairs": (
        "The primitive is already chosen; this call places the keypoint pairs only. Answer with "
        "one JSON object and nothing else:\n"
        '{"pairs": [[[x0, y0], [x1, y1]], ...], "rationale": "<one or two sentences>"}'
    ),
}

_STEPS = {
    "combined": "choose the primitive and generate the keypoint pairs",
    "keyword": "choose the primitive",
    "pairs": "generate the keypoint pairs",
}

ICING_WORDS = re.compile(r"icing|pip(e|ing)|frost|decorat|rosette|cream", re.IGNORECASE)


def prompt_family(primitives: Mapping[str, str]) -> str:
    """'icing' when the primitives are for icing, else 'cutting'."""
    text = " ".join(f"{name} {description}" for name, description in primitives.items())
    return "icing" if ICING_WORDS.search(text) else "cutting"


def find_prompt(
    explicit: Path | None, task_folder: Path, family: str, where: str = "planner.prompt"
) -> Path:
    """The task's prompt file, or prompts/<family>.md from the search path; either must be a
    small regular file inside the task's folder tree or a search folder (docs/security.md)."""
    if explicit is not None:
        wrong = readable_file_problem(explicit, prompt_roots(task_folder), MAX_PROMPT_BYTES)
        if wrong:
            raise KeympsError(f"{where}: {wrong}")
        return explicit
    searched = prompt_search_dirs(task_folder)
    for folder in searched:
        candidate = folder / f"{family}.md"
        if candidate.exists() or candidate.is_symlink():
            wrong = readable_file_problem(candidate, prompt_roots(task_folder), MAX_PROMPT_BYTES)
            if wrong:
                raise KeympsError(f"prompt template {family}.md: {wrong}")
            return candidate
    raise KeympsError(
        f"no prompt template {family}.md found (looked in: {', '.join(map(str, searched))}); "
        "set planner.prompt in the task file"
    )


_COMMENT = re.compile(r"<!--.*?-->", re.DOTALL)


def strip_comments(template: str) -> str:
    """The template without its HTML comments (notes for humans, never sent to the model); the
    lines they held stay as blank lines, so errors still name the right line."""
    return _COMMENT.sub(lambda m: "\n" * m.group(0).count("\n"), template)


def render_template(template: str, values: Mapping[str, str], source: str = "<prompt>") -> str:
    """Fill `{{name}}` placeholders; an unknown name is a KeympsError with file:line.

    HTML comments (`<!-- ... -->`) are dropped first: they are not sent.
    """
    template = strip_comments(template)
    for number, line in enumerate(template.splitlines(), start=1):
        for match in _PLACEHOLDER.finditer(line):
            if match.group(1) not in PLACEHOLDERS:
                known = ", ".join(PLACEHOLDERS)
                raise KeympsError(
                    f"{source}:{number}: unknown placeholder {{{{{match.group(1)}}}}} "
                    f"(known: {known})"
                )
    return _PLACEHOLDER.sub(lambda m: values[m.group(1)], template).strip("\n")


def template_values(
    *,
    instruction: str,
    primitives: Mapping[str, str],
    crop_size_px: tuple[int, int],
    metres_per_px: tuple[float, float],
    object_height: float,
    max_pairs: int,
    step: Step,
    convention: str = "pixels",
    answer: str = "pairs",
    family: str = "cutting",
) -> dict[str, str]:
    from keymps.planning.coordinates import paragraph
    from keymps.planning.examples import examples_text
    from keymps.planning.named_design import catalogue_text

    mx, my = (m * 1000 for m in metres_per_px)
    scale = f"{mx:.3g}" if abs(mx - my) <= 0.01 * mx else f"{mx:.3g} (x), {my:.3g} (y)"
    return {
        "instruction": instruction,
        "primitives": "\n".join(f"- {name}: {text}" for name, text in primitives.items()),
        "primitive_names": ", ".join(primitives),
        "crop_width": str(crop_size_px[0]),
        "crop_height": str(crop_size_px[1]),
        "mm_per_pixel": scale,
        "object_height_cm": f"{object_height * 100:.3g}",
        "max_pairs": str(max_pairs),
        "output_format": output_format(step, answer, convention),
        "step": _STEPS[step],
        "coordinates": paragraph(convention, crop_size_px),  # type: ignore[arg-type]
        "examples": examples_text(family, convention, answer),  # type: ignore[arg-type]
        "designs": _designs_text(family, answer, catalogue_text(family)),
    }


def _designs_text(family: str, answer: str, catalogue: str) -> str:
    if answer == "pairs":
        return "Not used for this task: answer with keypoint pairs."
    how = (
        "Answer with a design instead of pairs"
        if answer == "design"
        else "Instead of pairs you may name a design (then pairs is null)"
    )
    return (
        f"{how}: keymps measures the object and lays the design out exactly. Give its name and "
        "the parameters it takes (a parameter marked ? is optional; every parameter it does not "
        "take is null). Use pairs for anything the list does not describe."
        + ("" if answer == "either" else " This task takes designs only.")
        + f"\n\n{catalogue}"
    )


INTENT_FORMAT = (
    '"intent": {"pieces": ..., "equal": ..., "orientation": ..., "slice_width_cm": ..., '
    '"dots": ..., "rings": ..., "digits": ..., "piece_shape": ..., "edge_distance_cm": ...}'
)
INTENT_NOTE = (
    "\n`intent` states what your pairs achieve: how many pieces the cuts leave and whether "
    "they are equal, the cuts' direction relative to the object's own sides, the slice width, "
    "how many dots, rings or which digits, the pieces' shape (strip, wedge, square, round) "
    "and the icing's distance in from the edge (null for what you do not claim; all of it null or "
    "the whole intent null for a design of your own). keymps predicts what the robot's motion "
    "does to the object and sends your answer back if the result differs from it."
)


def output_format(step: Step, answer: str, convention: str) -> str:
    """The JSON this call answers with, for the answer form and the coordinate convention."""
    base = _OUTPUT_FORMATS[step]
    if convention == "yx_1000":
        base = base.replace("[[[x0, y0], [x1, y1]], ...]", "[[[y0, x0], [y1, x1]], ...]")
    if step != "keyword" and answer != "design":  # pairs state their intent
        base = base.replace('"rationale":', f'{INTENT_FORMAT}, "rationale":') + INTENT_NOTE
    if step == "keyword" or answer == "pairs":
        return base
    design = '{"name": "<design>", "count": ..., "layers": ..., "slice_width_cm": ..., '
    design += '"object_length_cm": ..., "orientation": ..., "text": ...}'
    if answer == "design":
        return re.sub(r'"pairs": \[\[\[.*?\]\], \.\.\.\]', f'"design": {design}', base)
    return base.replace(
        "...]",
        f'...] or null, "design": null or {design}',
        1,
    )


def png_bytes(image: Any) -> bytes:
    """The image encoded as PNG."""
    import cv2

    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise KeympsError("cannot encode the crop as PNG")
    return bytes(encoded.tobytes())


def png_data_url(image: Any, png: bytes | None = None) -> str:
    """The image as a base64 PNG data URL (what the VLM receives); `png`: already encoded."""
    encoded = png if png is not None else png_bytes(image)
    return "data:image/png;base64," + base64.b64encode(encoded).decode("ascii")


def build_messages(
    system_text: str,
    instruction: str,
    image_url: str,
    crop_size_px: tuple[int, int],
    keyword: str | None,
    history: Sequence[tuple[str, Sequence[str]]],
    objects: str = "",
) -> list[dict[str, Any]]:
    """System prompt, the user's sentence with the crop, then each invalid answer and its errors.

    `objects` lists the objects when the crop holds several (keymps.planning.objects)."""
    if objects:
        text = (
            f"Instruction: {instruction}\n"
            f"The image is the objects' crop, {crop_size_px[0]} x {crop_size_px[1]} pixels.\n"
            f"{objects}"
        )
    else:
        text = (
            f"Instruction: {instruction}\n"
            f"The image is the object's crop, {crop_size_px[0]} x {crop_size_px[1]} pixels."
        )
    if keyword is not None:
        text += f"\nThe chosen primitive is: {keyword}"
    return conversation(system_text, text, image_url, history)


def conversation(
    system_text: str,
    user_text: str,
    image_url: str | None,
    history: Sequence[tuple[str, Sequence[str]]],
) -> list[dict[str, Any]]:
    """System prompt, the user's text (with the image, unless None), then each earlier answer
    and its problems (an outcome's under their own heading), asking for a corrected answer."""
    content: Any = user_text
    if image_url is not None:
        content = [
            {"type": "text", "text": user_text},
            {"type": "image_url", "image_url": {"url": image_url}},
        ]
    messages: list[dict[str, Any]] = [
        {"role": "system", "content": system_text},
        {"role": "user", "content": content},
    ]
    for answer, errors in history:
        messages.append({"role": "assistant", "content": answer})
        heading = "Your answer was invalid:\n"
        if errors and all(e.startswith(OUTCOME_PROBLEM) for e in errors):
            heading = OUTCOME_HEADING
            errors = [e[len(OUTCOME_PROBLEM) :] for e in errors]
        messages.append(
            {
                "role": "user",
                "content": heading
                + "\n".join(f"- {e}" for e in errors)
                + "\nAnswer again with the corrected JSON object only.",
            }
        )
    return messages


OUTCOME_PROBLEM = "predicted outcome: "
"""How the outcome stage's problems start when they go back to the model for repair."""
OUTCOME_HEADING = (
    "keymps simulated the motion planned from your answer on the measured object; the result "
    "is not what was asked:\n"
)
