"""After execution: a measured result that falls short of the prediction makes the run not ok."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from keymps import RunOptions, RunOverrides, load_task, run_task
from keymps.errors import StageError
from keymps.outcome.measured import measured_problems
from keymps.plugin import hookimpl
from keymps.types import CutEffect, Effect, ExecutionReport

REPO = Path(__file__).resolve().parents[2]


def _cut(pair: int, length: float, depth: float = 0.02, severed: bool = True) -> CutEffect:
    lines = np.array([[[0.0, 0.0], [length, 0.0]]]) if severed else np.zeros((0, 2, 2))
    return CutEffect(pair, 1, length, depth, lines, length)


def test_a_cut_short_of_its_prediction_is_named_with_its_numbers() -> None:
    predicted = Effect(cuts=(_cut(0, 0.150), _cut(1, 0.150), _cut(2, 0.150)))
    measured = Effect(cuts=(_cut(0, 0.1215, severed=False), _cut(1, 0.149, severed=False),
                            _cut(2, 0.150, 0.015, severed=False)))  # fmt: skip
    assert measured_problems(predicted, measured) == [
        "cut 1 ran 121.5 mm through the food, 81 % of the 150.0 mm predicted (at least 98 %)",
        "cut 3 went 15.0 mm deep, not the 20.0 mm down to the board predicted",
    ]
    assert measured_problems(predicted, Effect(cuts=measured.cuts[1:]))[0] == (
        "cut 1 did not go into the food (predicted 150.0 mm)"
    )
    assert measured_problems(predicted, predicted) == []


class SlippingKnife:
    """Stands in for a real-robot executor that measures its cuts (a physical robot cannot
    exist here): it reports every cut a fifth short, as a knife slipping in the food would."""

    name = "slipping"

    def execute(self, validated, run) -> ExecutionReport:
        cuts = run.stages.outcome.predicted.cuts
        short = tuple(replace(c, length_m=0.8 * c.length_m, severed_m=np.zeros((0, 2, 2)),
                              chord_m=None) for c in cuts)  # fmt: skip
        return ExecutionReport(self.name, True, "cut", measured=Effect(cuts=short))


def test_the_run_is_not_ok_when_the_executor_measures_less(tmp_path, keymps_plugins) -> None:
    class Plugin:
        @hookimpl
        def register_executors(self, register):
            register("slipping", lambda options: SlippingKnife())

    keymps_plugins.register(Plugin(), name="slipping-knife")
    task = load_task(REPO / "tasks" / "object_cutting.yaml")
    with pytest.raises(StageError) as caught:
        run_task(
            task,
            options=RunOptions(rerun="off", quiet=True),
            overrides=RunOverrides(backend="offline", executor="slipping", out=tmp_path / "run"),
        )
    message = str(caught.value)
    assert caught.value.stage == "execute" and "falls short of the prediction" in message
    assert "80 % of the" in message and "(and 3 more)" in message
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "failed" and record["execution"]["ok"] is True
    assert record["outcome"]["verdict"] == "pass"
    assert len(record["outcome"]["measured_problems"]) == 4
    assert len(record["outcome"]["measured"]["cuts"]) == 4
