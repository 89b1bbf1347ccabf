"""A small sample of the perception benchmark (benchmarks/perception.py runs the full one)."""

from __future__ import annotations

from keymps.eval.perception import flat_benchmark, photo_benchmark, table


def test_the_board_detector_meets_the_targets_where_the_threshold_detector_does_not() -> None:
    flat = flat_benchmark(30)
    board, threshold = flat["board"], flat["threshold"]
    assert board["found"].cases == 27 and board["refused"].cases == 3
    assert board["found"].rate == 1.0, board["found"].failures
    assert board["hue_only"].rate == 1.0 and board["hue_only"].cases == 4
    assert board["refused"].rate == 1.0, board["refused"].failures
    assert threshold["found"].rate < 0.6 and threshold["hue_only"].rate < 0.5
    photos = photo_benchmark(1, methods=("board+intrinsics", "threshold"))
    assert photos["board+intrinsics"]["tall"].rate == 1.0, photos["board+intrinsics"][
        "tall"
    ].failures
    assert photos["board+intrinsics"]["flat"].rate == 1.0
    assert photos["threshold"]["tall"].worst > 5
    shown = table(flat, photos)
    assert "| `board` | 100.0 % (27/27) |" in shown and "`threshold` with `roi`" in shown
