"""Icing a distance from the edge of square, rectangular and round cakes, over generated scenes.

"Pipe dots 1 cm from the edge of the square cake" was refused by the outcome stage: the layout
ran the ring along a rectangle inside the measured outline, which comes nearer the edge at a
cake's rounded corners and where the detected side is uneven. The layout now insets the measured
outline itself (keymps.designs.outline.inset_polygon). Before, 8 of 100 offline plans on
square and rectangular cakes were refused (6 of them right by the true outline, 2 near the
tolerance); now none. Round objects had the same fault where the sentence gives the distance:
the ring was a circle, and a pizza's wavy crust comes nearer it (2 of 40 offline plans
refused); such a ring now follows the measured outline too.

Each case renders a cake (a rounded rectangle 8-16 cm long, square or up to half as wide,
turned up to 30 degrees; one case in five a round cake or a pizza instead) and runs the whole pipeline through the outcome stage with a sentence
asking for dots or an icing line 0.5-3 cm from the edge. The right plans are the offline
planner's; the wrong ones come from a VLM on a real local server (litellm over HTTP) answering
those pairs and their intent with a flaw: the ring moved out past the edge, one dot put off the
cake, the ring shifted or shrunk. Every plan is judged on the cake's TRUE outline by this test's
own geometry: no right plan may be refused, no wrong one may pass; the band near the
tolerances is counted, not judged.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.task_files import ICING, OFFLINE, vlm_planner, write_task
from helpers.vlm_server import VlmServer

from keymps import load_task, run_task
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene

CAKES = 100
BOARD = (0.30, 0.22)
QUIET = RunOptions(rerun="off", quiet=True)
KEY_VARIABLE = "EDGE_LAYOUT_API_KEY"
DOT_DIAMETER_M = 0.008
"""Two line widths of the piping bag: dots closer than this merge (docs/outcome.md)."""
SENTENCES = (
    "Pipe dots {q} from the edge of the square cake",
    "Put 12 icing dots {q} from the edge",
    "pipe a ring of dots {q} in from the edge",
    "pipe dots around the cake with a {q} margin",
    "Pipe a ring of icing {q} from the edge",
)
FLAWS = ("outward", "off_cake", "shift", "shrink")


@dataclass(frozen=True)
class Cake:
    kind: str
    """square_cake (a rounded rectangle), round_cake or round_pizza (a wavy crust)."""
    size: tuple[float, float]
    """Length and width, metres."""
    rotation: float
    """Degrees."""
    centre: tuple[float, float]
    sentence: str
    margin_m: float
    flaw: str | None
    """None: the offline planner's plan only; else also a VLM's plan with this flaw."""
    seed: int


def _cakes() -> list[Cake]:
    rng = np.random.default_rng(2024)
    cakes = []
    for seed in range(CAKES):
        length = float(rng.uniform(0.08, 0.16))
        width = length if rng.random() < 0.5 else length * float(rng.uniform(0.5, 1.0))
        margin_mm = float(rng.uniform(5.0, min(30.0, 0.3 * width * 1000)))
        written = f"{margin_mm / 10:.1f} cm" if rng.random() < 0.7 else f"{round(margin_mm)} mm"
        margin_m = float(written.split()[0]) / (100 if written.endswith("cm") else 1000)
        sentence = SENTENCES[int(rng.integers(len(SENTENCES)))].format(q=written)
        centre = (0.15 + float(rng.uniform(-0.02, 0.02)), 0.11 + float(rng.uniform(-0.01, 0.01)))
        flaw = FLAWS[seed // 2 % len(FLAWS)] if seed % 2 else None
        rotation = float(rng.uniform(-30, 30))
        kind = ("round_cake", "round_pizza")[seed // 5 % 2] if seed % 5 == 4 else "square_cake"
        if kind != "square_cake":
            width, sentence = length, sentence.replace("the square cake", "the round cake")
        cakes.append(Cake(kind, (length, width), rotation, centre, sentence, margin_m, flaw, seed))
    return cakes


ANSWER: dict[str, Any] = {}
"""What the local VLM answers to the current case."""
REFUSALS: dict[tuple[int, str], str] = {}


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> list[tuple[Cake, str, str, str]]:
    """(cake, plan: offline or the flaw, truth: right | wrong | near, what the run did)."""
    folder = tmp_path_factory.mktemp("edge")
    found = []
    with (
        pytest.MonkeyPatch.context() as patch,
        VlmServer(responder=lambda _: json.dumps(ANSWER)) as server,
    ):
        patch.setenv(KEY_VARIABLE, "sk-test-5e0c6b21f4a9d873")
        for cake in _cakes():
            found.extend(_runs(cake, folder, server))
    return found


def _task(folder: Path, cake: Cake, png: Path, planner: str) -> Path:
    return write_task(folder, sentence=cake.sentence, image=png, board_m=BOARD, planner=planner,
                      tools=ICING, name="edge")  # fmt: skip


def _runs(cake: Cake, folder: Path, server: VlmServer) -> list[tuple[Cake, str, str, str]]:
    """The offline plan of `cake` judged and run, and the VLM's flawed one if it has a flaw."""
    shape = ObjectSpec(cake.kind, *cake.size, 0.05, cake.rotation, centre=cake.centre)
    rendered = render_scene(SceneSpec((shape,), seed=cake.seed, board_size=BOARD))
    png, _ = rendered.save(folder / "scene.png")
    truth = np.asarray(rendered.truth["objects"][0]["outline_m"], float)
    offline = _task(folder, cake, png, OFFLINE)
    found = [_run(cake, "offline", offline, None, folder, truth)]
    if cake.flaw is None or found[0][3] == "plan":
        return found
    planned = run_task(load_task(offline), options=QUIET,
                       overrides=RunOverrides(out=folder / "plan"), through="ground")  # fmt: skip
    recorded = json.loads((planned.folder / "vlm" / "01-combined-attempt1.json").read_text())
    ANSWER.clear()
    ANSWER.update(_flawed(cake, recorded, planned))
    vlm = _task(folder, cake, png, vlm_planner(KEY_VARIABLE))
    return [*found, _run(cake, cake.flaw, vlm, server.openai_base, folder, truth)]


def _run(
    cake: Cake, plan: str, task: Path, api_base: str | None, folder: Path, truth: np.ndarray
) -> tuple[Cake, str, str, str]:
    try:
        overrides = RunOverrides(out=folder / "run", api_base=api_base)
        run = run_task(load_task(task), options=QUIET, overrides=overrides, through="outcome")
        did = "ok"
    except KeympsError as error:
        run, did = error.run, getattr(error, "stage", "error")
        REFUSALS[cake.seed, plan] = str(error)
    grounding = run.stages.ground if run is not None else None
    if grounding is None:
        return cake, plan, "near", did  # the offline planner refused the sentence
    return cake, plan, _truth(cake, truth, grounding.segments_m[:, :, :2]), did


def _flawed(cake: Cake, recorded: dict, planned: Any) -> dict:
    """The offline planner's answer (pairs in crop pixels, intent) with the cake's flaw."""
    import cv2

    answer = json.loads(recorded["answer"]) if "answer" in recorded else recorded
    rng = np.random.default_rng(cake.seed)
    pairs = np.asarray(planned.stages.plan.pairs_crop_px, float).copy()
    middle = pairs.reshape(-1, 2).mean(axis=0)
    detection = planned.stages.detect
    contour = (np.asarray(detection.contour_px, np.float32).reshape(-1, 1, 2)
               - np.asarray(detection.crop_origin_px, np.float32))  # fmt: skip
    if cake.flaw == "outward":  # the whole ring past the edge: its outer dots off the cake
        pairs = middle + (pairs - middle) * float(rng.uniform(1.3, 1.5))
    elif cake.flaw == "off_cake":  # one dot (or line end) moved out until 2-5 mm off
        k = int(rng.integers(len(pairs)))
        out = (pairs[k, 0] - middle) / max(float(np.linalg.norm(pairs[k, 0] - middle)), 1e-9)
        beyond = -float(rng.uniform(4, 10))  # pixels of 0.5 mm outside the contour
        while cv2.pointPolygonTest(contour, tuple(map(float, pairs[k, 0])), True) > beyond:
            pairs[k] += out
    elif cake.flaw == "shift":
        pairs += rng.uniform(8, 14) * np.array([math.cos(a := rng.uniform(0, 6.3)), math.sin(a)])
    else:  # shrink: the ring well inside where it was asked
        pairs = middle + (pairs - middle) * float(rng.uniform(0.7, 0.85))
    width, height = detection.crop_size_px
    pairs = np.clip(pairs, 0, [width - 1, height - 1])
    return {"keyword": "line", "pairs": np.round(pairs, 2).tolist(),
            "intent": answer.get("intent"), "rationale": "flawed"}  # fmt: skip


def _truth(cake: Cake, outline: np.ndarray, segments: np.ndarray) -> str:
    """right or wrong by the TRUE outline: every dot (or point of the line) that far from the
    edge, and no two dots merging; near within the band around the tolerances."""
    import cv2

    dots = np.all(np.isclose(segments[:, 0], segments[:, 1]), axis=1)
    points = (
        segments[dots, 0]
        if dots.all()
        else np.concatenate([np.linspace(a, b, 8) for a, b in segments])
    )
    contour = outline.astype(np.float32).reshape(-1, 1, 2)
    inside = np.array(
        [cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in points]
    )
    allowed = max(0.1 * cake.margin_m, 0.0015)
    worst = max(abs(float(inside.min()) - cake.margin_m), abs(float(inside.max()) - cake.margin_m))
    ratio = worst / allowed
    if dots.all() and len(points) > 1:
        gaps = np.linalg.norm(points[:, None] - points[None], axis=2)
        closest = float(gaps[~np.eye(len(points), dtype=bool)].min())
        ratio = max(ratio, 1.5 * DOT_DIAMETER_M / closest if closest < DOT_DIAMETER_M else 0.0)
    return "right" if ratio < 0.6 else ("wrong" if ratio > 1.5 else "near")


@pytest.mark.slow
def test_no_right_plan_is_refused_and_no_wrong_one_passes(results, fuzz_counter):
    for cake, plan, truth, did in results:
        verdict = {"ok": "passed", "outcome": "refused"}.get(did, f"stopped at {did}")
        fuzz_counter.add(f"designs/edge distance {plan}", cake, f"{truth} plan {verdict}")
    right_refused = [(c, p) for c, p, t, did in results if t == "right" and did != "ok"]
    wrong_passed = [(c, p) for c, p, t, did in results if t == "wrong" and did == "ok"]
    assert not right_refused, [(c, p, REFUSALS.get((c.seed, p))) for c, p in right_refused[:5]]
    assert not wrong_passed, wrong_passed[:5]
    offline = [t for _, p, t, _ in results if p == "offline"]
    assert offline.count("right") >= 0.95 * CAKES, offline
    for flaw in FLAWS:
        judged = [t for _, p, t, _ in results if p == flaw]
        assert judged.count("wrong") >= 6, (flaw, judged)
    off = [did for c, p, t, did in results if p == "off_cake"]
    assert off and set(off) == {"outcome"}, off  # a dot off the cake is never executed
