"""Hundreds of generated scenes and sentences through the outcome stage, right plans and wrong.

Objects vary as the real world does (round, square and elongated, of varied sizes, turned);
sentences ask for equal pieces, parallel slices, halves and icing dots. Half the plans are the
offline planner's exact designs; the other half come from a backend plugin that draws them as
an imprecise VLM would (keypoints off by 0.5-2 % of the crop, a cut dropped, turned or moved, a
dot missing). Each plan is judged on the object's TRUE outline (the scene's sidecar), with a
knife model of its own (the edge, blade_length long, lies flat on the board behind the cut's
end): clearly wrong plans must be refused, clearly right ones must pass; the band near the
tolerances is counted, not judged. The counts are printed in the fuzz summary.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.task_files import ICING, KNIFE, write_task

from keymps import RunOptions, RunOverrides, load_task, run_task
from keymps.errors import KeympsError
from keymps.outcome.pieces import check_equal_parts
from keymps.plugin import hookimpl
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene
from keymps.types import BackendAnswer

CASES = 300
BLADE_M = 0.16  # the knife's blade_length
LINE_M = 0.004  # the piping bag's line_width
TOLERANCE = 0.05
BOARD = (0.30, 0.22)
END_M = 0.0015


@dataclass(frozen=True)
class Case:
    kind: str
    size: tuple[float, float]
    rotation: float
    sentence: str
    flaw: tuple[str, float]
    """How the plan is drawn: ("exact", 0), ("noise", sigma), ("drop" | "turn" | "shift", x)."""
    seed: int

    @property
    def icing(self) -> bool:
        return "dot" in self.sentence


def _cases() -> list[Case]:
    rng = np.random.default_rng(36)
    cases = []
    for seed in range(CASES):
        kind = str(rng.choice(["round_cake", "round_pizza", "square_cake", "meat_loaf"]))
        side = float(rng.uniform(0.10, 0.15))
        size = (side, side) if kind != "meat_loaf" else (0.15, float(rng.uniform(0.06, 0.09)))
        rotation = 0.0 if kind.startswith("round") else float(rng.uniform(-25, 25))
        sentence = _sentence(kind, rng)
        flaws = ["exact"] * 4 + ["noise", "drop", "turn", "shift"]
        flaw = str(rng.choice(flaws))
        amount = float(rng.choice([0.005, 0.01, 0.02])) if flaw == "noise" else 0.0
        cases.append(Case(kind, size, rotation, sentence, (flaw, amount), seed))
    return cases


def _sentence(kind: str, rng: np.random.Generator) -> str:
    n = int(rng.integers(2, 9))
    if kind == "round_cake" and rng.random() < 0.4:
        return f"Put {int(rng.integers(6, 45))} icing dots around the cake"
    if kind == "square_cake" and rng.random() < 0.2:
        return f"Put {int(rng.integers(6, 40))} icing dots around the cake"
    if kind != "round_pizza" and rng.random() < 0.4:
        return f"Cut it {'vertically' if rng.random() < 0.5 else 'horizontally'} into {n} slices"
    return f"Cut it into {n} equal pieces" if rng.random() < 0.85 else "Cut it in half"


SPEC: dict[str, Any] = {}
"""The flaw the `imprecise` backend draws the current case's plan with."""


class ImpreciseOffline:
    """A plugin backend: the offline planner's answer, drawn with the current case's flaw."""

    name = "imprecise"
    cacheable = False

    def complete(self, request: Any) -> BackendAnswer:
        from keymps.default_plugins.offline import OfflineBackend

        answer = json.loads(OfflineBackend().complete(request).text)
        pairs = np.asarray(answer["pairs"], float)
        width, height = request.crop_size_px
        answer["pairs"] = np.clip(_flawed(pairs, SPEC["flaw"], SPEC["rng"], width, height),
                                  0, [width, height]).tolist()  # fmt: skip
        return BackendAnswer(text=json.dumps(answer))


def _flawed(pairs: np.ndarray, flaw: tuple[str, float], rng: Any, width: int, height: int):
    kind, amount = flaw
    size = max(width, height)
    pairs = pairs.copy()
    k = int(rng.integers(len(pairs)))
    if kind == "noise":
        return pairs + rng.normal(0.0, amount * size, pairs.shape)
    if kind == "drop" and len(pairs) > 1:
        return np.delete(pairs, k, axis=0)
    if kind == "turn":
        angle = math.radians(float(rng.uniform(8, 15)) * rng.choice([-1, 1]))
        middle = pairs[k].mean(axis=0)
        turn = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        pairs[k] = middle + (pairs[k] - middle) @ turn.T
    if kind == "shift":
        pairs[k] = pairs[k] + rng.uniform(0.05, 0.1) * size * rng.choice([-1, 1], size=2)
    return pairs


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[Case, str, str]]:
    """(case, truth: right | wrong | near, what the run did: ok | outcome | <stage>)."""
    from keymps.plugin import manager as plugins
    from keymps.plugin.testing import PluginHarness

    harness = PluginHarness()

    class Plugin:
        @hookimpl
        def register_vlm_backends(self, register):
            register("imprecise", lambda options: ImpreciseOffline())

    harness.register(Plugin(), name="imprecise-plugin")
    folder = tmp_path_factory.mktemp("generated")
    with plugins.manager_in_use(harness.manager):
        return [_run(case, folder) for case in _cases()]


def _run(case: Case, folder: Path) -> tuple[Case, str, str]:
    obj = ObjectSpec(case.kind, case.size[0], case.size[1], 0.05, case.rotation)
    rendered = render_scene(SceneSpec((obj,), seed=case.seed, board_size=BOARD))
    png, _ = rendered.save(folder / "scene.png")
    tools = ICING if case.icing else KNIFE
    planner = "backend: imprecise, attempts: 1"
    task = write_task(
        folder, sentence=case.sentence, image=png, board_m=BOARD, planner=planner, tools=tools
    )
    SPEC.update(flaw=case.flaw, rng=np.random.default_rng(case.seed))
    try:
        run = run_task(
            load_task(task),
            options=RunOptions(rerun="off", quiet=True),
            overrides=RunOverrides(out=folder / "run"),
            through="outcome",
        )
        did = "ok"
    except KeympsError as error:
        run, did = error.run, getattr(error, "stage", "error")
    grounding = run.stages.ground if run is not None else None
    if grounding is None:
        return case, "near", did
    truth = rendered.truth["objects"][0]
    return case, _truth(case, truth, grounding.segments_m), did


def _truth(case: Case, truth: dict, segments: np.ndarray) -> str:
    """right, wrong or near: the plan judged on the true outline by this test's own models."""
    outline = np.asarray(truth["outline_m"], float)
    if case.icing:
        return _icing_truth(case, outline, segments[:, :, :2])
    starts, goals = segments[:, 0, :2], segments[:, 1, :2]
    along = (goals - starts) / np.linalg.norm(goals - starts, axis=1, keepdims=True)
    # the edge lies flat on the board behind the cut's end; an end within END_M of the edge
    # (the detected outline is about half a pixel off the true one) reaches it
    cut = np.stack([goals - BLADE_M * along, goals + END_M * along], axis=1)
    parts = 2 if "half" in case.sentence else int(case.sentence.split("into ")[1].split()[0])
    parallel = "ly into" in case.sentence or case.kind == "meat_loaf"
    if parallel:
        return _slices_truth(case, outline, cut, parts)
    check = check_equal_parts(outline, cut, parts, TOLERANCE)
    return _band(len(check.areas_m2) == parts, check.worst_deviation / TOLERANCE)


def _slices_truth(case: Case, outline: np.ndarray, cut: np.ndarray, parts: int) -> str:
    """Parallel slices: in the asked direction (the object's own side nearest the image's
    vertical or horizontal, or the image's own for an object within 10 degrees of it), equal
    in width (a square's: in area), the pieces counted."""
    angles = np.arctan2(cut[:, 1, 1] - cut[:, 0, 1], cut[:, 1, 0] - cut[:, 0, 0])
    mean = angles[0] + float(np.mean([math.remainder(a - angles[0], math.pi) for a in angles]))
    accepted, boundary = [mean], False  # equal slices of a long object: any one direction
    if "ly into" in case.sentence:
        image = math.pi / 2 if "vertically" in case.sentence else 0.0
        axis = math.radians(case.rotation)
        own = min(axis, axis + math.pi / 2, key=lambda a: abs(math.remainder(a - image, math.pi)))
        tilt = math.degrees(abs(math.remainder(own - image, math.pi)))
        accepted, boundary = ([image, own] if tilt < 10 else [own]), 8 <= tilt <= 12
    wanted = min(accepted, key=lambda a: abs(math.remainder(mean - a, math.pi)))
    off = max(abs(math.remainder(a - wanted, math.pi)) for a in angles)
    pieces = check_equal_parts(outline, cut, parts, TOLERANCE)
    if case.kind == "square_cake":
        deviation = pieces.worst_deviation / TOLERANCE
    else:
        across = np.array([-math.sin(wanted), math.cos(wanted)])
        extent = outline @ across
        positions = np.sort(cut.mean(axis=1) @ across)
        widths = np.diff([extent.min(), *positions, extent.max()])
        deviation = float(np.abs(widths / widths.mean() - 1).max()) / TOLERANCE
    if len(pieces.areas_m2) != parts or (off > math.radians(8) and not boundary):
        return "wrong"
    if boundary or off > math.radians(3):  # near the limits: not judged
        return "near"
    return "wrong" if deviation > 1.5 else ("right" if deviation < 0.6 else "near")


def _icing_truth(case: Case, outline: np.ndarray, pairs: np.ndarray) -> str:
    """Dots (a pair's middle) two line widths across: merging, off the top, missing."""
    import cv2

    wanted = int(case.sentence.split()[1])
    if float(np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1).max()) > 2 * LINE_M:
        return "wrong"  # a stroke, not a dot
    dots = pairs.mean(axis=1)
    gaps = np.linalg.norm(dots[:, None] - dots[None], axis=2) + np.eye(len(dots))
    closest = float(gaps.min()) if len(dots) > 1 else 1.0
    contour = outline.astype(np.float32).reshape(-1, 1, 2)
    inside = min(cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in dots)
    if len(dots) != wanted or closest < 2 * LINE_M - 0.001 or inside < LINE_M - 0.001:
        return "wrong"
    if closest > 2 * LINE_M + 0.001 and inside > LINE_M + 0.001:
        return "right"
    return "near"


def _band(count_right: bool, deviation: float) -> str:
    if not count_right or deviation > 1.5:
        return "wrong"
    return "right" if deviation < 0.6 else "near"


@pytest.mark.slow
def test_no_wrong_plan_passes_and_no_right_plan_is_refused(results, fuzz_counter):
    for case, truth, did in results:
        verdict = {"ok": "passed", "outcome": "refused"}.get(did, f"stopped at {did}")
        fuzz_counter.add("outcome/generated plans", case, f"{truth} plan {verdict}")
    assert len(results) >= 300
    wrong_passed = [(c, t) for c, t, did in results if t == "wrong" and did == "ok"]
    right_refused = [(c, t) for c, t, did in results if t == "right" and did == "outcome"]
    assert not wrong_passed, wrong_passed[:5]
    assert not right_refused, right_refused[:5]
    counts = {t: sum(1 for _, truth, _ in results if truth == t) for t in ("right", "wrong")}
    assert counts["right"] >= 120 and counts["wrong"] >= 60, counts  # both kinds are tested
