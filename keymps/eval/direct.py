"""The methods that ask a VLM directly (keymps-text, vlm-keyword, vlm-dmp, vlm-mdmp).

They perceive the scene through keymps run's own image and detect stages
(keymps.pipeline.stages), ask with their own prompt (prompts/methods/METHOD.md) and
answer schema, repair invalid answers once, record every call under the run's vlm/ folder, and
return the motion they generate (no robot checks, as in the paper).
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Any

import numpy as np

from keymps.eval.context import MethodContext, MethodOutput
from keymps.eval.vlm import Seen, ask, look
from keymps.planning.answer import strict_object_schema
from keymps.text_drawing import on_text_thread


def _finish(
    context: MethodContext, seen: Seen, output: MethodOutput, calls: list[dict[str, Any]]
) -> MethodOutput:
    """Attach the calls, draw the generated motion over the scene (the plan image), keep the
    sidecar."""
    from keymps.run_files import image_file, write_image

    pieces_px = [seen.frame.to_pixels(np.asarray(piece)[:, :2]) for piece in output.work_pieces]
    image = on_text_thread(_draw_motion, seen.scene.image.copy(), pieces_px)
    path = write_image(image_file(context.folder, "plan", context.image_format), image)
    return replace(output, calls=tuple(calls), images={"plan": str(path)}, scene=seen.truth)


def _draw_motion(image: np.ndarray, pieces_px: list[np.ndarray]) -> np.ndarray:
    """Each work piece as a red line over the scene, numbered in green at its start."""
    import cv2

    for index, piece in enumerate(pieces_px):
        pixels = np.round(piece).astype(np.int32)
        cv2.polylines(image, [pixels.reshape(-1, 1, 2)], False, (0, 0, 255), 2, cv2.LINE_AA)
        x, y = (int(v) for v in pixels[0])
        cv2.putText(image, str(index + 1), (x + 4, y - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 160, 0), 1, cv2.LINE_AA)  # fmt: skip
    return image


def _number_list(value: Any, length: int, what: str) -> tuple[list[float] | None, str | None]:
    if (
        not isinstance(value, list)
        or len(value) != length
        or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in value)
    ):
        return None, f"{what} must be a list of {length} finite numbers"
    return [float(v) for v in value], None


_NUMBERS = {"type": "array", "items": {"type": "number"}}
_RATIONALE = {"type": "string", "description": "one or two sentences"}


def _compose(seen: Seen, keyword: str, starts: np.ndarray, goals: np.ndarray) -> MethodOutput:
    from keymps.motion.compose import compose_tool_path
    from keymps.robot.model import RobotModel
    from keymps.types import Segment

    task = seen.task
    segments = [
        Segment(start=s, goal=g, start_px=(0.0, 0.0), goal_px=(0.0, 0.0))
        for s, g in zip(starts, goals, strict=True)
    ]
    robot = RobotModel.from_task(task)
    path = compose_tool_path(
        segments,
        seen.primitives[keyword],
        object_top=task.scene.object_height,
        clearance=task.motion.clearance,
        work_speed=task.motion.work_speed,
        travel_speed=task.motion.travel_speed,
        yaw_mode=robot.tool.yaw,
        home=robot.home_tool_position(),
        home_yaw=robot.home_yaw(),
    )
    pieces = tuple(p.points for p in path.pieces if p.kind == "work")
    lines = np.stack([starts[:, :2], goals[:, :2]], axis=1)
    return MethodOutput(work_pieces=pieces, lines_m=lines, keyword=keyword)


def keymps_text(context: MethodContext) -> MethodOutput:
    """KeyMPs-text: the pairs from text only, then Appendix B/C grounding and the primitive."""
    from keymps.perception.frames import height_pair
    from keymps.planning.answer import answer_schema, parse_and_validate

    seen = look(context)
    keywords = list(seen.primitives)
    size = seen.detection.crop_size_px
    max_pairs = seen.task.planner.max_pairs

    def validate(data: Any) -> tuple[Any, list[str]]:
        return parse_and_validate(json.dumps(data), "combined", keywords, size, max_pairs)

    answer, calls = ask(
        context,
        seen,
        "keymps-text",
        False,
        answer_schema("combined", keywords, max_pairs),
        validate,
    )
    pairs_px = np.asarray(answer.pairs, dtype=float).reshape(-1, 2, 2)
    pairs_px = pairs_px + np.asarray(seen.detection.crop_origin_px, dtype=float)
    board = seen.frame.to_board(pairs_px.reshape(-1, 2)).reshape(-1, 2, 2)
    z_start, z_goal = height_pair(seen.task)
    starts = np.column_stack([board[:, 0], np.full(len(board), z_start)])
    goals = np.column_stack([board[:, 1], np.full(len(board), z_goal)])
    return _finish(context, seen, _compose(seen, answer.keyword, starts, goals), calls)


def vlm_keyword(context: MethodContext) -> MethodOutput:
    """VLM-Keyword: the primitive is chosen, but the 3D keypoints come from the VLM directly."""
    seen = look(context)
    keywords = list(seen.primitives)
    point3 = {**_NUMBERS, "description": "[x, y, z] in metres, board frame"}
    schema = strict_object_schema(
        "keymps_vlm_keyword_answer",
        {
            "keyword": {"type": "string", "enum": keywords},
            "pairs": {"type": "array", "items": {"type": "array", "items": point3}},
            "rationale": _RATIONALE,
        },
    )

    def validate(data: Any) -> tuple[Any, list[str]]:
        problems = []
        keyword = data.get("keyword") if isinstance(data, dict) else None
        if keyword not in keywords:
            problems.append(f"keyword must be one of {', '.join(keywords)}")
        pairs = data.get("pairs") if isinstance(data, dict) else None
        points = []
        if not isinstance(pairs, list) or not pairs:
            problems.append("pairs must be a non-empty list of [[x, y, z], [x, y, z]]")
        else:
            for index, pair in enumerate(pairs):
                if not isinstance(pair, list) or len(pair) != 2:
                    problems.append(f"pairs[{index}] must be [[x, y, z], [x, y, z]]")
                    continue
                for end in pair:
                    value, problem = _number_list(end, 3, f"pairs[{index}] points")
                    if problem:
                        problems.append(problem)
                    else:
                        points.append(value)
        if problems:
            return None, problems
        return (keyword, np.asarray(points, dtype=float).reshape(-1, 2, 3)), []

    (keyword, pairs), calls = ask(context, seen, "vlm-keyword", True, schema, validate)
    return _finish(context, seen, _compose(seen, keyword, pairs[:, 0], pairs[:, 1]), calls)


def _dmp_from(entry: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    start = np.asarray(entry["start"], dtype=float)
    goal = np.asarray(entry["goal"], dtype=float)
    weights = np.asarray(entry["weights"], dtype=float).reshape(-1, 3)
    return start, goal, weights


def _validate_dmp(entry: Any, where: str) -> list[str]:
    if not isinstance(entry, dict):
        return [f"{where} must be an object with start, goal, weights"]
    problems = []
    for key in ("start", "goal"):
        _, problem = _number_list(entry.get(key), 3, f"{where}.{key}")
        if problem:
            problems.append(problem)
    weights = entry.get("weights")
    if not isinstance(weights, list) or not 2 <= len(weights) <= 100:
        problems.append(f"{where}.weights must be a list of 2 to 100 [wx, wy, wz] rows")
    else:
        for row in weights:
            _, problem = _number_list(row, 3, f"{where}.weights rows")
            if problem:
                problems.append(problem)
                break
    return problems


def _rollout_dmps(entries: list[dict[str, Any]]) -> MethodOutput:
    from keymps.primitives.dmp import DMP

    pieces, lines = [], []
    for entry in entries:
        start, goal, weights = _dmp_from(entry)
        dmp = DMP(weights=weights, demo_start=start, demo_goal=goal, demo_duration=1.0)
        pieces.append(np.asarray(dmp.rollout(start, goal, num=1000).y))
        lines.append([start[:2], goal[:2]])
    return MethodOutput(
        work_pieces=tuple(pieces), lines_m=np.asarray(lines, dtype=float), keyword=None
    )


def _dmp_schema(name: str, several: bool) -> dict[str, Any]:
    properties: dict[str, Any] = {
        "start": {**_NUMBERS, "description": "[x, y, z] metres"},
        "goal": {**_NUMBERS, "description": "[x, y, z] metres"},
        "weights": {"type": "array", "items": _NUMBERS},
    }
    dmp = {
        "type": "object",
        "properties": properties,
        "required": list(properties),
        "additionalProperties": False,
    }
    if several:
        return strict_object_schema(
            name, {"dmps": {"type": "array", "items": dmp}, "rationale": _RATIONALE}
        )
    return strict_object_schema(name, {**properties, "rationale": _RATIONALE})


def vlm_dmp(context: MethodContext) -> MethodOutput:
    """VLM-DMP: one DMP (start, goal, forcing weights) written by the VLM is the whole motion."""
    seen = look(context)

    def validate(data: Any) -> tuple[Any, list[str]]:
        problems = _validate_dmp(data, "answer")
        return (None, problems) if problems else ([data], [])

    entries, calls = ask(
        context, seen, "vlm-dmp", True, _dmp_schema("keymps_vlm_dmp_answer", False), validate
    )
    return _finish(context, seen, _rollout_dmps(entries), calls)


def vlm_mdmp(context: MethodContext) -> MethodOutput:
    """VLM-MDMP: several DMPs written by the VLM, each one a piece of the motion."""
    seen = look(context)

    def validate(data: Any) -> tuple[Any, list[str]]:
        dmps = data.get("dmps") if isinstance(data, dict) else None
        if not isinstance(dmps, list) or not dmps:
            return None, ["dmps must be a non-empty list of {start, goal, weights}"]
        problems = [p for i, d in enumerate(dmps) for p in _validate_dmp(d, f"dmps[{i}]")]
        return (None, problems) if problems else (dmps, [])

    entries, calls = ask(
        context, seen, "vlm-mdmp", True, _dmp_schema("keymps_vlm_mdmp_answer", True), validate
    )
    return _finish(context, seen, _rollout_dmps(entries), calls)
