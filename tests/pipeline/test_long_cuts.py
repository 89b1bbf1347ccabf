"""Cuts through more food than the knife's blade is long, over generated scenes.

The built-in knife's 16 cm blade lies on the board only along the end of a cut, so a cut
through a 20 cm cake, a 24 cm pizza or an 18 cm loaf lengthwise stopped short: every such plan
was refused at the outcome stage ("cut 1 stops 37.0 mm short of the object's edge"), and
nothing longer than the blade could be cut at all. keymps.motion.compose now cuts such a chord
from both ends (two strokes of the same pair, overlapping past the middle); the outcome stage
and the executors measure the two strokes as one cut.

Each case renders one object 16-28 cm across (a round cake, a square cake turned up to 20
degrees, a pizza, a loaf cut lengthwise), runs the whole pipeline with the sim executor and
holds the run to the sentence: ok, the predicted pieces as many as asked, every cut through
the food from edge to edge and measured so by the executor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from helpers.task_files import KNIFE, write_task

from keymps import load_task, run_task
from keymps.errors import KeympsError
from keymps.run import RunOptions, RunOverrides
from keymps.scenes.render import ObjectSpec, SceneSpec, render_scene

BOARD = (0.40, 0.32)
CASES = 24
SENTENCES = {
    "round_cake": [("Cut the cake into 8 equal slices", 8), ("cut it in half", 2)],
    "square_cake": [("Cut it vertically into 3 slices", 3), ("cut the cake in half", 2)],
    "round_pizza": [("Cut the pizza into 6 slices", 6), ("Cut it into 4 equal pieces", 4)],
    "banana_bread": [("Cut the loaf lengthwise in half", 2)],
}


@dataclass(frozen=True)
class Case:
    kind: str
    size: tuple[float, float]
    rotation: float
    sentence: str
    pieces: int
    seed: int


def _cases() -> list[Case]:
    rng = np.random.default_rng(1616)
    kinds = list(SENTENCES)
    cases = []
    for seed in range(CASES):
        kind = kinds[seed % len(kinds)]
        across = float(rng.uniform(0.165, 0.28 if kind != "banana_bread" else 0.26))
        size = (across, across) if kind != "banana_bread" else (across, 0.08)
        rotation = float(rng.uniform(-20, 20)) if kind == "square_cake" else 0.0
        sentence, pieces = SENTENCES[kind][int(rng.integers(len(SENTENCES[kind])))]
        cases.append(Case(kind, size, rotation, sentence, pieces, seed))
    return cases


@pytest.mark.slow
def test_cuts_longer_than_the_blade_cut_through(tmp_path: Path, fuzz_counter) -> None:
    failures = []
    for case in _cases():
        folder = tmp_path / f"case{case.seed}"
        folder.mkdir()
        height = 0.06 if case.kind != "round_pizza" else 0.02
        obj = ObjectSpec(case.kind, *case.size, height, case.rotation, centre=(0.20, 0.16))
        png, _ = render_scene(SceneSpec((obj,), seed=case.seed, board_size=BOARD)).save(
            folder / "scene.png"
        )
        task = write_task(folder, sentence=case.sentence, image=png, board_m=BOARD, tools=KNIFE,
                          object_height_m=height, name="long")  # fmt: skip
        options = RunOptions(rerun="off", quiet=True)
        try:
            run = run_task(load_task(task), options=options, overrides=RunOverrides(out=folder))
        except KeympsError as error:
            fuzz_counter.add("pipeline/cuts longer than the blade", case, "refused")
            failures.append((case, str(error)[:200]))
            continue
        outcome = run.stages.outcome
        assert outcome is not None and outcome.verdict == "pass"
        assert len(outcome.predicted.pieces) == case.pieces, case
        longest = max(cut.chord_m for cut in outcome.predicted.cuts)
        assert longest > 0.16, (case, longest)  # the case needs the blade's reach exceeded
        for cut in outcome.predicted.cuts:
            assert cut.length_m >= 0.98 * cut.chord_m, (case, cut.pair_index)
        fuzz_counter.add("pipeline/cuts longer than the blade", case, "cut through")
    assert not failures, failures
