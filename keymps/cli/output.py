"""What `keymps run` and `keymps plugins` print (progress on stderr, the summary on stdout)."""

from __future__ import annotations

import json
import os
from typing import Any

import click

from keymps.planning.redaction import redact_text
from keymps.run import Run

_STAGE_TITLES = {
    "image": "load image",
    "detect": "detect object",
    "plan": "plan (keyword + keypoint pairs)",
    "ground": "ground pairs in 3D",
    "compose": "compose tool path",
    "solve": "inverse kinematics",
    "time": "time trajectory",
    "check": "safety check",
    "execute": "execute",
}


def _stage_detail(stage: str, result: Any) -> str:
    if stage == "image":
        width, height = result.size_px
        return f"{width}x{height} px"
    if stage == "detect":
        return "bbox " + ",".join(str(v) for v in result.bbox_px)
    if stage == "plan":
        detail = f"{result.backend}: {result.keyword}, {result.num_pairs} pair(s)"
        calls = [call for call in result.calls if call.model_call]
        if calls and calls[-1].cached:  # no model was asked this time (--no-cache asks it)
            detail += ", cached answer"
        return detail
    if stage == "ground":
        return f"{len(result.segments)} segment(s)"
    if stage == "compose":
        work = sum(1 for p in result.pieces if p.kind == "work")
        return f"{len(result.pieces)} pieces ({work} work)"
    if stage == "solve":
        return f"max IK error {result.max_position_error_m * 1000:.3f} mm"
    if stage == "time":
        return f"{result.duration_s:.1f} s, {result.samples} samples at {result.rate_hz:g} Hz"
    if stage == "check":
        return "pass"
    if stage == "execute":
        return f"{result.executor}: {result.message}" if result.message else result.executor
    return ""


class RunPrinter:
    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        # click drops the colours when stderr is not a terminal; NO_COLOR (no-color.org) too.
        # Plain click.echo rather than rich here: rich's import is 20 ms of every run.
        self.color: bool | None = False if os.environ.get("NO_COLOR") else None

    def stage_done(self, stage: str, seconds: float, result: Any) -> None:
        if self.quiet:
            return
        title = _STAGE_TITLES.get(stage, stage)
        detail = redact_text(_stage_detail(stage, result))
        tick = click.style("✓", fg="green")
        line = f"{tick} {title:<32} {seconds:7.3f} s  {click.style(detail, dim=True)}"
        click.echo(line, err=True, color=self.color)

    def summary(self, run: Run) -> None:
        folder = run.folder
        if self.quiet:
            click.echo(str(folder))
            return
        plan = run.stages.plan
        trajectory = run.stages.time
        lines = [
            f"backend     {run.backend} ({run.backend_reason})",
            f"keyword     {plan.keyword if plan else '-'}",
            f"segments    {plan.num_pairs if plan else 0}",
            f"duration    {trajectory.duration_s:.1f} s" if trajectory else "duration    -",
            f"run folder  {folder}",
        ]
        if (folder / "run.rrd").exists():
            lines.append(f"open with   rerun {folder / 'run.rrd'}")
        for warning in run.warnings:
            lines.append(f"warning     {warning}")
        click.echo(redact_text("\n".join(lines)))

    def failed(self, run: Run) -> None:
        """After a failed run: its warnings and folder (the error line follows on stderr)."""
        if self.quiet:
            click.echo(str(run.folder))
            return
        lines = [f"warning     {warning}" for warning in run.warnings]
        lines.append(f"run folder  {run.folder}")
        click.echo("\n".join(lines), err=True)


def print_plugins(as_json: bool) -> None:
    import contextlib
    import sys

    from keymps.plugin.manager import plugin_infos

    with contextlib.redirect_stdout(sys.stderr):  # a plugin printing as it loads stays out
        infos = plugin_infos()
    if as_json:
        click.echo(json.dumps([info.__dict__ for info in infos], indent=2, default=list))
        return
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    table = Table("plugin", "provides", "distribution", "version")
    for info in infos:
        provides = ", ".join(info.provides)
        if info.error is not None:
            provides = f"[red]failed to load:[/] {escape(info.error)}"
        table.add_row(info.name, provides, info.distribution, info.version)
    Console().print(table)
