"""keymps eval through the outcome stage: icing runs (no cuts) score, and Appendix F's success
is judged by the outcome stage's verifier, of the planned lines and of what the knife cuts."""

from __future__ import annotations

import numpy as np

from keymps.eval.runner import EvalOptions, run_suite
from keymps.eval.suites import load_suite
from keymps.outcome.verdict import equal_parts_problems


def test_icing_runs_go_through_the_outcome_stage_and_score(tmp_path):
    records = run_suite(
        load_suite("icing"), EvalOptions(out=tmp_path, cases=("1",), repeats=1, processes=1)
    )
    assert [r["ok"] for r in records] == [True], records


def test_appendix_f_scores_the_plan_and_the_cut(tmp_path):
    options = EvalOptions(out=tmp_path, cases=("round",), repeats=2, processes=1, outcome="predict")
    records = run_suite(load_suite("cake_six"), options)
    for record in records:
        assert record["ok"] and record["outcome"] == "predict"
        assert record["success"] is True and record["design_success"] is True, record
        assert record["parts"] == 6 and record["worst_deviation"] < 0.05


def test_the_verifier_names_unequal_pieces_of_a_disc():
    angles = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    disc = 0.06 * np.column_stack([np.cos(angles), np.sin(angles)])
    through = [[[-0.07, 0.0], [0.07, 0.0]], [[0.0, -0.07], [0.0, 0.07]]]
    problems, pieces = equal_parts_problems(disc, np.array(through), 4, 0.05)
    assert problems == [] and len(pieces) == 4
    off_centre = np.array(through) + [0.0, 0.01]
    problems, _ = equal_parts_problems(disc, off_centre, 4, 0.05)
    assert len(problems) == 1 and "the intent is 4 equal pieces" in problems[0]
