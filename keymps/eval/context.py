"""What an eval method receives (MethodContext) and what it returns (MethodOutput)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class MethodOutput:
    """What one method generated for one case."""

    work_pieces: tuple[np.ndarray, ...]
    """The generated work motion (cuts, strokes) as 3D points, board metres; no travel."""
    lines_m: np.ndarray
    """(K, 2, 2) where each generated piece starts and ends, seen from above (board metres)."""
    keyword: str | None
    calls: tuple[dict[str, Any], ...] = ()
    """Per VLM call: latency_s, cost_usd, prompt_tokens, completion_tokens."""
    images: dict[str, str] = field(default_factory=dict)
    """plan / outcome -> PNG path, when written."""
    scene: dict[str, Any] | None = None
    """The synthetic scene's sidecar as rendered for this run (saves rendering it again)."""
    cut_lines_m: np.ndarray | None = None
    """(M, 2, 2) where the knife's edge lay on the board, as the outcome stage predicted it
    (None when the run did not reach it): the edge reaches past a cut's start, which the lines
    do not show, and past the detected outline."""


@dataclass(frozen=True)
class MethodContext:
    """Everything a method needs to run one case once."""

    task_path: Path
    """The case's task file (written by the runner)."""
    folder: Path
    """This run's folder."""
    backend: str
    model: str | None
    api_base: str | None
    plan_only: bool = False
    """Stop after grounding: the design is all that is scored (Appendix F's equal parts)."""
    outcome: str = "off"
    """With plan_only: off (stop after grounding); predict (go on through the outcome stage,
    every plan accepted as answered); repair (a plan whose predicted outcome is wrong goes back
    to the VLM, one still wrong is refused)."""
    no_cache: bool = False
    """Always ask the VLM, never answer from the planner's cache."""
    image_format: str = "jpg"
    """plan and outcome images: jpg or png (keymps.run.RunOptions.image_format)."""
    dispatch: Callable[[Any, Any], Any] | None = None
    """Where VLM calls go (keymps.run.RunOptions.dispatch): the broker, or None to call out."""
