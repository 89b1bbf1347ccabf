"""The outcome stage's result as plain JSON data (run.json's `outcome`, docs/run-folder.md)."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np

from keymps.types import CutEffect, DepositEffect, Effect, Outcome, PieceEffect


def outcome_record(outcome: Outcome | None, accept: bool) -> dict[str, Any] | None:
    """verdict, intent (one per object), predicted, problems, tolerances, and the measured
    result with where it fell short, once an executor measured it."""
    if outcome is None:
        return None
    return {
        "verdict": outcome.verdict,
        "accept_outcome": accept,
        "intent": [_plain(asdict(intent)) for intent in outcome.intents],
        "predicted": effect_record(outcome.predicted),
        "problems": list(outcome.problems),
        "tolerances": {k: _number(v) for k, v in outcome.tolerances.items()},
        "measured": effect_record(outcome.measured) if outcome.measured is not None else None,
        "measured_problems": list(outcome.measured_problems),
    }


def effect_record(effect: Effect) -> dict[str, Any]:
    """Cuts, pieces and deposits in metres (board frame), m² and fractions."""
    return {
        "cuts": [_cut(cut) for cut in effect.cuts],
        "pieces": [_piece(piece) for piece in effect.pieces],
        "deposits": [_deposit(deposit) for deposit in effect.deposits],
        "strokes": effect.strokes,
        "loops": effect.loops,
    }


def _cut(cut: CutEffect) -> dict[str, Any]:
    return {
        "pair": cut.pair_index + 1,
        "object": cut.object_id,
        "length_m": _number(cut.length_m),
        "depth_m": _number(cut.depth_m),
        "chord_m": _number(cut.chord_m) if cut.chord_m is not None else None,
        "severed_m": _points(cut.severed_m),
        "swept_m": _points(cut.swept_m),
    }


def _piece(piece: PieceEffect) -> dict[str, Any]:
    return {
        "object": piece.object_id,
        "area_m2": _number(piece.area_m2, 8),
        "share": _number(piece.share, 4),
        "outline_m": _points(piece.outline_m),
    }


def _deposit(deposit: DepositEffect) -> dict[str, Any]:
    return {
        "kind": deposit.kind,
        "pair": deposit.pair_index + 1,
        "pairs": [pair + 1 for pair in deposit.piped_pairs],
        "object": deposit.object_id,
        "path_m": _points(deposit.path_m),
        "width_m": _number(deposit.width_m),
        "stroke": deposit.stroke,
        "on_top": deposit.on_top,
    }


def _points(values: np.ndarray) -> Any:
    return np.round(np.asarray(values, float), 5).tolist()


def _number(value: float, digits: int = 6) -> float | None:
    return round(float(value), digits) if math.isfinite(value) else None


def _plain(values: dict[str, Any]) -> dict[str, Any]:
    return {k: _number(v) if isinstance(v, float) else v for k, v in values.items()}
