"""After execution: the result an executor measured, held against the prediction."""

from __future__ import annotations

from keymps.types import Effect

MEASURED_FRACTION = 0.98
"""Every cut must run at least this fraction of its predicted length through the food."""
DEPTH_SLACK_M = 0.001
"""A cut predicted to reach the board must come within this of it in the executor too."""


def measured_problems(predicted: Effect, measured: Effect) -> list[str]:
    """Where the measured cuts fall short of the predicted ones, one line each."""
    problems = []
    made = {cut.pair_index: cut for cut in measured.cuts}
    for cut in predicted.cuts:
        if cut.length_m <= 0:
            continue
        name = f"cut {cut.pair_index + 1}"
        got = made.get(cut.pair_index)
        if got is None:
            problems.append(
                f"{name} did not go into the food (predicted {1000 * cut.length_m:.1f} mm)"
            )
        elif got.length_m < MEASURED_FRACTION * cut.length_m:
            problems.append(
                f"{name} ran {1000 * got.length_m:.1f} mm through the food, "
                f"{100 * got.length_m / cut.length_m:.0f} % of the {1000 * cut.length_m:.1f} mm "
                f"predicted (at least {100 * MEASURED_FRACTION:g} %)"
            )
        elif len(cut.severed_m) and got.depth_m < cut.depth_m - DEPTH_SLACK_M:
            problems.append(
                f"{name} went {1000 * got.depth_m:.1f} mm deep, not the "
                f"{1000 * cut.depth_m:.1f} mm down to the board predicted"
            )
    return problems
