"""The outcome stage: predict what the timed trajectory does to the food, hold it against the
plan's intent (and the task's `expect:`), and give the verdict before anything moves."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import fields, replace
from typing import TYPE_CHECKING

import numpy as np

from keymps.outcome.predict import Food, Tool, predict
from keymps.outcome.shapes import SHAPE_TOLERANCES, edge_distance_problems, piece_shape_problems
from keymps.outcome.verdict import (
    TOLERANCES,
    cut_problems,
    icing_intent_problems,
    icing_problems,
    intent_problems,
)
from keymps.types import (
    EQUAL_PARTS_TOLERANCE,
    Effect,
    Outcome,
    OutcomeVerdict,
    PlanIntent,
    ToolPath,
    Trajectory,
)

if TYPE_CHECKING:
    from keymps.config.task import Expect, Task
    from keymps.robot.model import RobotModel
    from keymps.types import GroundedObject


def check_outcome(
    model: RobotModel,
    trajectory: Trajectory,
    tool_path: ToolPath,
    foods: Sequence[Food],
    tool: Tool,
    intents: Sequence[PlanIntent],
    accept: bool = False,
) -> Outcome:
    """The predicted effect and the verdict: pass, fail, or accepted (failed, and `accept`:
    the expert's --accept-outcome)."""
    predicted = predict(model, trajectory, tool_path, foods, tool)
    problems = judge(predicted, foods, tool, intents, tool_path)
    verdict: OutcomeVerdict = "pass" if not problems else ("accepted" if accept else "fail")
    tolerances = TOLERANCES | SHAPE_TOLERANCES
    for intent in intents:
        if intent.equal is not None:
            tolerances["equal"] = intent.equal
    return Outcome(verdict, tuple(intents), predicted, tuple(problems), tolerances)


def judge(
    predicted: Effect,
    foods: Sequence[Food],
    tool: Tool,
    intents: Sequence[PlanIntent],
    tool_path: ToolPath,
) -> list[str]:
    """Every problem of the predicted effect, one line each, the checks every plan gets first."""
    worked = {piece.object_id for piece in tool_path.pieces if piece.kind == "work"}
    if tool.cuts:
        problems = cut_problems(predicted, foods, tool.blade_length)
    else:
        pairs = sorted({k for p in tool_path.pieces if p.kind == "work" for k in p.piped_pairs})
        problems = icing_problems(predicted, pairs, tool.line_width)
    for intent in intents:
        for food in foods:
            if food.id not in worked or intent.object_id not in (None, food.id):
                continue
            if tool.cuts:
                found = intent_problems(predicted, intent, food)
                problems += found or piece_shape_problems(predicted, intent, food)
            else:
                problems += icing_intent_problems(predicted, intent, food)
                problems += edge_distance_problems(predicted, intent, food)
    return problems


def foods_of(
    objects: Sequence[GroundedObject], outline_m: np.ndarray | None, height: float
) -> list[Food]:
    """The objects the prediction cuts or ices: every grounded object, else the one footprint."""
    if objects:
        return [Food(o.id, float(o.height), np.asarray(o.outline_m, float)) for o in objects]
    if outline_m is None:
        return []
    return [Food(1, float(height), np.asarray(outline_m, float))]


def expected(expect: Expect | None) -> PlanIntent | None:
    """The task file's `expect:` block as an intent (metres to millimetres)."""
    if expect is None:
        return None
    equal = expect.equal
    return PlanIntent(
        pieces=expect.pieces,
        equal=EQUAL_PARTS_TOLERANCE if equal is True else (None if equal is False else equal),
        equal_by=expect.equal_by,
        orientation=expect.orientation,
        slice_width_mm=1000 * expect.slice_width if expect.slice_width else None,
        object_length_mm=1000 * expect.object_length if expect.object_length else None,
        dots=expect.dots,
        rings=expect.rings,
        digits=expect.digits,
        source="expect",
    )


def stated_intents(
    plan_intents: Sequence[PlanIntent],
    task: Task,
    asked: PlanIntent | None = None,
    objects: int = 1,
) -> tuple[PlanIntent, ...]:
    """The plan's intents with the task's `expect:` over them: every field it gives replaces
    the plan's (the user's assertion is the truth); alone, it is the intent of each object.

    Without `expect:`, a model's plan on one object that states its intent (from its answer
    or a named design) is also held to `asked`, the instruction as the offline grammar reads
    it (keymps.planning.intent.sentence_intent): a model that misreads "into 3" as 4, and
    claims 4, is refused like one whose cuts miss its own claim. A plan that states nothing
    is checked only for what is never right; with several `objects` the sentence may ask
    different things of each, so only the plan's claims are checked."""
    asserted = expected(task.expect)
    if asserted is None:
        from_model = bool(plan_intents) and all(
            intent.source in ("answer", "design") for intent in plan_intents
        )
        if asked is None or not from_model or objects > 1:
            return tuple(plan_intents)
        return (*plan_intents, asked)
    if not plan_intents:
        return (asserted,)
    given = {f.name: getattr(asserted, f.name) for f in fields(asserted) if f.name != "source"}
    given = {name: value for name, value in given.items() if value is not None}
    return tuple(replace(intent, **given, source="expect") for intent in plan_intents)
