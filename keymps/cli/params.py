"""Click parameter types the commands share."""

from __future__ import annotations

import math
from typing import Any

import click


class FiniteFloat(click.FloatRange):
    """A float within optional bounds that is never nan or inf (click's FloatRange lets nan
    through every bound, and inf through an open end)."""

    name = "finite float"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number

    def _describe_range(self) -> str:
        # click shows an unbounded range as "x<=None"
        if self.min is None and self.max is None:
            return ""
        return super()._describe_range()


def finite_numbers(text: str, count: tuple[int, ...], what: str) -> list[float]:
    """`count` comma-separated finite numbers, or a click error naming `what`."""
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise click.BadParameter(f"{what}: numbers separated by commas, got {text!r}") from None
    if len(values) not in count:
        wanted = " or ".join(str(c) for c in count)
        raise click.BadParameter(f"{what}: {wanted} numbers separated by commas, got {text!r}")
    if not all(math.isfinite(v) for v in values):
        raise click.BadParameter(f"{what}: every number must be finite, got {text!r}")
    return values
