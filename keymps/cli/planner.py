"""`keymps planner start|stop|status`: the warm planner that keeps litellm imported between runs."""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import click

from keymps.cli.errors import user_errors


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def planner() -> None:
    """The warm planner: one local process that keeps litellm imported, so that `keymps run`
    with a VLM does not import it (seconds) every time. `keymps run` uses it whenever it is up;
    `keymps run --warm-planner` (or KEYMPS_WARM_PLANNER=1) starts it when it is not. It listens
    only on a Unix socket of yours and exits after its idle timeout (docs/vlm.md)."""


@planner.command()
@click.option(
    "--idle-timeout", type=click.FloatRange(1, 7 * 24 * 3600), default=None,
    help="Exit after this many seconds without a request (default 600).",
)  # fmt: skip
@user_errors
def start(idle_timeout: float | None) -> None:
    """Start the warm planner in the background; return once it answers."""
    from keymps.errors import KeympsError
    from keymps.planning.warm.client import PlannerUnavailable, WarmPlanner

    warm = WarmPlanner()
    status = warm.status()
    if status is not None:
        click.echo(f"already running: {_describe(status)}")
        return
    problem = warm.folder_problem()
    if problem:
        raise KeympsError(problem)
    process = None if warm.lock_held() else warm.start(idle_timeout)
    try:
        status = warm.wait_until_up(process)
    except PlannerUnavailable as reason:
        raise KeympsError(f"the warm planner {reason} (log: {warm.place.log})") from None
    click.echo(f"started: {_describe(status)}")


@planner.command()
@user_errors
def stop() -> None:
    """Stop the warm planner (requests it is answering finish first)."""
    from keymps.planning.warm.client import WarmPlanner

    warm = WarmPlanner()
    status = warm.status()
    if status is None or not warm.stop():
        click.echo("not running")
        return
    click.echo(f"stopped (pid {status['pid']})")


@planner.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@user_errors
def status(as_json: bool) -> None:
    """Say whether the warm planner is running (exit status 0) or not (3)."""
    from keymps.planning.warm.client import WarmPlanner

    warm = WarmPlanner()
    found = warm.status()
    if as_json:
        click.echo(json.dumps({"running": found is not None, **(found or {})}))
    elif found is None:
        click.echo(f"not running (socket {warm.place.socket})")
    else:
        click.echo(f"running: {_describe(found)}; log {warm.place.log}")
    if found is None:
        sys.exit(3)


def _describe(status: dict[str, Any]) -> str:
    up = time.time() - float(status.get("started", time.time()))
    return (
        f"pid {status.get('pid')}, up {up:.0f} s, {status.get('requests', 0)} requests, exits "
        f"after {float(status.get('idle_timeout_s', 0)):g} s idle, socket {status.get('socket')}"
    )
