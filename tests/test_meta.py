"""Meta-tests: every hook is tested and documented; every module stays importable and small."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from keymps.plugin import hookspecs

REPO = Path(__file__).resolve().parents[1]
HOOKS = sorted(
    name
    for name, value in vars(hookspecs).items()
    if inspect.isfunction(value) and hasattr(value, "keymps_spec")
)


def test_hookspecs_found() -> None:
    assert HOOKS == [
        "keymps_stage_done",
        "register_detectors",
        "register_executors",
        "register_image_sources",
        "register_vlm_backends",
    ]


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_has_a_docs_heading_with_its_signature(hook: str) -> None:
    docs = (REPO / "docs/plugins.md").read_text()
    parameters = ", ".join(inspect.signature(getattr(hookspecs, hook)).parameters)
    assert f"### {hook}({parameters})" in docs


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_is_exercised_by_a_test(hook: str) -> None:
    tests = [p for p in (REPO / "tests").glob("test_*.py") if p.name != "test_meta.py"]
    assert any(re.search(rf"\b{hook}\b", p.read_text()) for p in tests), hook


def test_modules_stay_small() -> None:
    too_long = {
        str(p.relative_to(REPO)): n
        for p in (REPO / "keymps").rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 400
    }
    assert not too_long, f"split these modules, each should have one job: {too_long}"
