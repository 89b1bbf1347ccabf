"""The `offline` planner backend: exact designs from the sentence and the crop, no network.

It reads the instruction with keymps.designs.grammar, measures the object in the crop with
keymps.designs.crop_shape, lays out the design with keymps.designs.patterns (in millimetres, then crop pixels)
and picks the primitive from the primitives' descriptions. It answers the same JSON as a VLM.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from keymps.errors import KeympsError
from keymps.plugin import BackendBase, RegisterVlmBackend, hookimpl

if TYPE_CHECKING:
    from keymps.designs.addressing import Clause
    from keymps.designs.grammar import Intent
    from keymps.types import BackendAnswer, PlanObject, PlanRequest

HARD_OBJECTS = re.compile(
    r"\b(hard|crusty|crust|bread|baguette|sourdough|pumpkin|squash|potato(?:es)?|carrots?|"
    r"frozen|cabbage|melon|pineapple|chocolate|nuts?|coconut)\b",
    re.IGNORECASE,
)
"""Objects that call for a sawing primitive (the paper: hard or crusty objects)."""
HARD_PRIMITIVE = re.compile(r"\bsaw|\bfor (?:\w+ )?(?:hard|firm\w*|crusty|tough)\b", re.I)
"""A primitive for hard objects: a sawing name or description, or "For hard/firmer objects"."""
SOFT_PRIMITIVE = re.compile(r"\bfor (?:\w+ )?soft\b|^(?:straight|downward)$", re.I)
ICING_PRIMITIVE = re.compile(
    r"\b(?:icing|pip(?:e|ing)|frost\w*|rosettes?|decorat\w*|nozzle)\b", re.I
)
ICING_NAMES = {"line", "icing", "dot", "dots", "pipe", "piping", "rosette"}


def _singular(word: str) -> str:
    if word.endswith("oes"):
        return word[:-2]
    if word.endswith("s") and not word.endswith("ss"):
        return word[:-1]
    return word


def _words(text: str) -> set[str]:
    return {_singular(w) for w in re.findall(r"[a-z]{3,}", text.lower())}


def _stem(word: str) -> str:
    """The word without a plural or verb ending: 'sawing', 'sawed', 'saws' are all 'saw'."""
    word = _singular(word)
    for ending in ("ing", "ed"):
        if word.endswith(ending) and len(word) - len(ending) >= 3:
            return word[: -len(ending)]
    return word


def _stems(text: str) -> set[str]:
    return {_stem(w) for w in re.findall(r"[a-z]{3,}", text.lower())}


def _named_objects(description: str) -> set[str]:
    """The example objects a description lists in parentheses: "(crusty bread, baguette)"."""
    return set().union(*(_words(group) for group in re.findall(r"\(([^)]*)\)", description)))


def choose_primitive(
    family: str,
    primitives: Mapping[str, str],
    sentence: str,
    task_name: str = "",
    object_names: Sequence[str] = (),
) -> tuple[str, str]:
    """(name, why) of the primitive for this design, from names and descriptions.

    `object_names` are the names scene.objects gives the objects the design is for: "cut the
    left one in half" of a declared potato is a potato's cut.

    A primitive of the design's family named in the sentence ("with a rocking cut") or in the
    task's name ("rocking-eggplant") is taken first; `why` says which of the two named it.
    Otherwise icing designs take the icing primitive, and cuts the one primitive whose
    description names the object (from the sentence or the task name), else a hard-object
    primitive for a hard or crusty object, else a soft-object one.
    """
    names = list(primitives)
    icing = [n for n in names if n.lower() in ICING_NAMES or ICING_PRIMITIVE.search(primitives[n])]
    if len(names) == 1 and (names[0] in icing) == (family == "icing"):
        return names[0], "the only primitive"
    cutting = [n for n in names if n not in icing]
    task_words = task_name.replace("-", " ").replace("_", " ")
    context = " ".join([sentence, task_words, *object_names])
    asked = _asked_for(icing if family == "icing" else cutting, sentence, task_name, context)
    if asked:
        return asked
    if family == "icing":
        if icing:
            return icing[0], "its description is for icing"
        raise KeympsError(
            f"the sentence asks for icing, but no primitive of this task is for icing (cutting "
            f"primitives: {', '.join(names)}): use an icing task (piping_bag and an icing primitive)"
        )
    if not cutting:
        raise KeympsError(
            f"the sentence asks for cutting, but every primitive of this task is for icing "
            f"({', '.join(names)}): use a cutting task (knife and a cutting primitive)"
        )
    return _cutting_primitive(cutting, primitives, context)


def _asked_for(
    family_names: Sequence[str], sentence: str, task_name: str, context: str
) -> tuple[str, str] | None:
    """(name, why) of the one primitive of the family the sentence or task name names."""
    asked = [n for n in family_names if (stems := _stems(n)) and stems <= _stems(context)]
    if len(asked) != 1:
        return None
    named_by = _words(task_name.replace("-", " ").replace("_", " "))
    in_sentence = _stems(asked[0]) <= _stems(sentence)
    if in_sentence or not _stems(asked[0]) <= _stems(" ".join(named_by)):
        return asked[0], "the sentence names it"
    return asked[0], f"the task's name ({task_name}) names it"


def _cutting_primitive(
    cutting: Sequence[str], primitives: Mapping[str, str], context: str
) -> tuple[str, str]:
    """(name, why) of a cut: the one whose description names the object, else by hardness."""
    mentioned = _words(context)
    named = [n for n in cutting if mentioned & _named_objects(primitives[n])]
    if len(named) == 1:
        word = sorted(mentioned & _named_objects(primitives[named[0]]))[0]
        return named[0], f"its description names {word!r}"
    hard = HARD_OBJECTS.search(context)
    if hard:
        found = [n for n in cutting if HARD_PRIMITIVE.search(f"{n} {primitives[n]}")]
        if found:
            return found[0], f"{hard.group(0)!r} is hard or crusty"
    soft = [
        n
        for n in cutting
        if (SOFT_PRIMITIVE.search(n) or SOFT_PRIMITIVE.search(primitives[n]))
        and not HARD_PRIMITIVE.search(f"{n} {primitives[n]}")
    ]
    if soft:
        return soft[0], "a soft object: a cut without sawing"
    return cutting[0], "the first cutting primitive"


class OfflineBackend(BackendBase):
    """Deterministic planner: the same sentence and crop always give the same design."""

    name = "offline"
    asks_model = False
    """Not a VLM call: run.json and the eval tables count none for it."""

    def complete(self, request: PlanRequest) -> BackendAnswer:
        from keymps.designs.grammar import read_instruction
        from keymps.types import BackendAnswer

        started = time.perf_counter()
        objects = _objects(request)
        clauses = _clauses(request.instruction, objects)
        intents = [(read_clause(clause, read_instruction), clause) for clause in clauses]
        family = _one_family(intents, objects)
        names = [objects[i].name or "" for _, clause in intents for i in clause.objects]
        keyword, why = choose_primitive(
            family, request.primitives, request.instruction, request.task_name, names
        )
        answer: dict[str, Any] = {}
        if request.step in ("combined", "keyword"):
            answer["keyword"] = keyword
        rationale = f"primitive {keyword}: {why}"
        jobs = [(intent, objects[i]) for intent, clause in intents for i in clause.objects]
        if request.step in ("combined", "pairs") and request.answer_mode == "design":
            # planner.answer: design: the intent itself, laid out by keymps like any design
            answer["design"], named = _named_design(jobs, several=len(objects) > 1)
            rationale = f"{named}; {rationale}"
        elif request.step in ("combined", "pairs"):
            laid_out, layout = _laid_out_pairs(jobs, request, several=len(objects) > 1)
            answer |= laid_out
            rationale = f"{layout}; {rationale}"
        answer["rationale"] = f"offline planner ({_described(intents, objects)}): {rationale}"
        return BackendAnswer(
            text=json.dumps(answer),
            latency_s=time.perf_counter() - started,
            cost_usd=0.0,
            model=None,
        )


def _one_family(intents: list[tuple[Intent, Clause]], objects: dict[int, PlanObject]) -> str:
    """The design family all clauses share (one plan has one primitive), else refuse."""
    if len({intent.family for intent, _ in intents}) > 1:
        raise KeympsError(
            "the offline planner makes one plan with one primitive, but the sentence asks "
            + " and ".join(
                f"{intent.family} on {_labels(clause.objects, objects)}"
                for intent, clause in intents
            )
        )
    return intents[0][0].family


def _described(intents: list[tuple[Intent, Clause]], objects: dict[int, PlanObject]) -> str:
    """The designs read from the sentence, each with its objects when there are several."""
    return "; ".join(
        intent.describe() + ("" if len(objects) == 1 else f" on {_labels(clause.objects, objects)}")
        for intent, clause in intents
    )


def _named_design(
    jobs: list[tuple[Intent, PlanObject]], several: bool
) -> tuple[dict[str, Any], str]:
    """The answer's `design` field for the one design the sentence asks for, and its mention."""
    from keymps.planning.named_design import design_answer

    if len(jobs) > 1:
        raise KeympsError(
            f"the offline planner reads {len(jobs)} designs ("
            + "; ".join(f"{i.describe()} on {o.label}" for i, o in jobs)
            + "), but planner.answer: design names one: use planner.answer: either"
        )
    intent, obj = jobs[0]
    _refuse_what_a_named_design_loses(intent)
    design = design_answer(intent) | ({"object": obj.id} if several else {})
    return design, f"named design {intent.design}"


def _laid_out_pairs(
    jobs: list[tuple[Intent, PlanObject]], request: PlanRequest, several: bool
) -> tuple[dict[str, Any], str]:
    """The answer's `pairs` (crop pixels) and `intent` fields for every job, and the layout."""
    budget = max(1, request.max_pairs // len(jobs))
    laid = [_lay_out(intent, obj, request, budget) for intent, obj in jobs]
    pairs_px = np.concatenate([pairs for pairs, _ in laid], axis=0)
    if len(pairs_px) > request.max_pairs:
        raise KeympsError(
            f"the offline design needs {len(pairs_px)} keypoint pairs, more than "
            f"planner.max_pairs = {request.max_pairs}"
        )
    fields: dict[str, Any] = {"pairs": np.round(pairs_px, 3).tolist()}
    if "intent" in request.schema.get("schema", {}).get("properties", {}):
        fields["intent"] = _stated(jobs, several=several)
    if len(jobs) == 1:
        return fields, laid[0][1]
    layout = "; ".join(
        f"{obj.label}: {text}" for (_, obj), (_, text) in zip(jobs, laid, strict=True)
    )
    return fields, layout


def _stated(jobs: list[tuple[Intent, PlanObject]], several: bool) -> list[dict[str, Any]]:
    """What the designs leave on their objects, as an answer's `intent` field."""
    from dataclasses import replace

    from keymps.planning.intent import answer_of_intent, intent_of_design

    return [
        answer_of_intent(replace(intent_of_design(design), object_id=obj.id if several else None))
        for design, obj in jobs
    ]


def _refuse_what_a_named_design_loses(intent: Intent) -> None:
    """A named design has no distance from the edge, no inset for the tips and no piece shape:
    a sentence that gives one is not answered without it."""
    lost = [
        f"{intent.edge_distance_mm / 10:g} cm from the edge" if intent.edge_distance_mm else "",
        "the tips' inset" if intent.design == "tips" and intent.slice_width_mm else "",
        f"{intent.piece_shape} pieces" if intent.piece_shape in ("strip", "round") else "",
    ]
    if any(lost):
        raise KeympsError(
            f"the offline planner reads {intent.describe()}, and a named design cannot carry "
            f"{', '.join(w for w in lost if w)}: use planner.answer: either (or pairs)"
        )


def _objects(request: PlanRequest) -> dict[int, PlanObject]:
    """The request's objects by id; a request without them is one object filling the crop."""
    from keymps.types import PlanObject

    if request.objects:
        return {o.id: o for o in request.objects}
    width, height = request.crop_size_px
    size = (width * request.metres_per_px[0], height * request.metres_per_px[1])
    whole = PlanObject(
        1, None, request.object_height, (0, 0, width, height), request.crop_mask, size
    )
    return {1: whole}


def _clauses(sentence: str, objects: dict[int, PlanObject]) -> list[Clause]:
    from keymps.designs.addressing import Target, split_by_object

    targets = [Target(o.id, o.name, o.centre_px, _box_size(o), o.area_px) for o in objects.values()]
    return split_by_object(sentence, targets)


def read_clause(clause: Clause, read: Any) -> Intent:
    """The clause's design; a clause the grammar cannot read alone names its object."""
    from keymps.designs.grammar import UnreadableInstruction

    if not clause.reference:
        return read(clause.text)  # type: ignore[no-any-return]
    try:
        return read(clause.text)  # type: ignore[no-any-return]
    except UnreadableInstruction as error:
        raise UnreadableInstruction(f"for {clause.reference!r}: {error}") from None


def _box_size(obj: PlanObject) -> tuple[float, float]:
    x0, y0, x1, y1 = obj.bbox_px
    return float(x1 - x0), float(y1 - y0)


def _labels(ids: tuple[int, ...], objects: dict[int, PlanObject]) -> str:
    return " and ".join(objects[i].label for i in ids)


def _lay_out(
    intent: Intent, obj: PlanObject, request: PlanRequest, max_pairs: int
) -> tuple[np.ndarray, str]:
    """The design on one object, in crop pixels (keymps.designs.place: cuts end at its box)."""
    from keymps.designs.place import place_design

    try:
        return place_design(
            intent,
            request.crop,
            obj.mask,
            request.metres_per_px,
            max_pairs,
            line_width_mm=request.line_width_mm,
        )
    except KeympsError as error:
        if str(error).startswith("the offline planner"):
            raise
        raise KeympsError(
            f"the offline planner cannot lay out {intent.describe()} on this object: {error}"
        ) from None


def _factory(options: dict[str, Any]) -> OfflineBackend:
    return OfflineBackend()


@hookimpl
def register_vlm_backends(register: RegisterVlmBackend) -> None:
    register("offline", _factory)
