"""The `keymps` command: run, validate, plugins (and the primitives, scene, eval groups)."""

from __future__ import annotations

import atexit
import contextlib
import importlib
import importlib.util
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from keymps._version import __version__
from keymps.cli.errors import user_errors

_LAZY_GROUPS: dict[str, tuple[str, str]] = {
    "primitives": ("keymps.cli.primitives", "primitives"),
    "scene": ("keymps.cli.scene", "scene"),
    "eval": ("keymps.cli.eval", "eval_command"),
    "calibrate": ("keymps.cli.calibrate", "calibrate"),
    "planner": ("keymps.cli.planner", "planner"),
}
"""Sub-commands that live in their own modules, imported only when listed or used."""


class _KeympsGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        available = [n for n, (m, _) in _LAZY_GROUPS.items() if importlib.util.find_spec(m)]
        return sorted([*super().list_commands(ctx), *available])

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in _LAZY_GROUPS:
            module_name, attribute = _LAZY_GROUPS[cmd_name]
            if importlib.util.find_spec(module_name) is None:
                return None
            command: click.Command = getattr(importlib.import_module(module_name), attribute)
            return command
        return super().get_command(ctx, cmd_name)


@click.group(cls=_KeympsGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="keymps")
def cli() -> None:
    """KeyMPs: one top-down image and one sentence to a safe, timed robot trajectory."""


@cli.command()
@click.argument("task_file", metavar="TASK", type=click.Path(path_type=Path))
@click.option("-i", "--instruction", help="Use this sentence instead of the task's.")
@click.option("--image", type=click.Path(path_type=Path), help="Use this scene image.")
@click.option("--backend", help="Planner backend: auto, offline, litellm, replay, or a plugin's.")
@click.option("--model", help="VLM model for litellm, e.g. openai/gpt-4o.")
@click.option("--api-base", help="OpenAI-compatible server URL (Ollama, vLLM ...).")
@click.option("--cassette", type=click.Path(path_type=Path), help="Cassette for --backend replay.")
@click.option("--record", type=click.Path(path_type=Path), help="Record VLM answers to a cassette.")
@click.option("--no-cache", is_flag=True, help="Always call the VLM, never answer from cache.")
@click.option("--executor", help="Executor: sim, file, or a plugin's (e.g. ur-rtde).")
@click.option("--confirm", is_flag=True, help="Allow a real-robot executor to move the arm.")
@click.option(
    "--accept-outcome",
    is_flag=True,
    help="Execute even when the predicted outcome contradicts the intent (recorded in run.json).",
)
@click.option("--out", type=click.Path(path_type=Path), help="Run folder (default runs/NAME-TIME).")
@click.option(
    "--rerun",
    "rerun_mode",
    type=click.Choice(["save", "spawn", "connect", "off"]),
    default="save",
    show_default=True,
    help="Rerun recording: save run.rrd, spawn a viewer, connect to one, or off.",
)
@click.option("--rerun-url", help="Viewer URL for --rerun connect.")
@click.option(
    "--warm-planner/--no-warm-planner", default=None,
    help="Start the warm planner when it is not up (keymps planner), or never use it. "
    "Default: use it when it is up ($KEYMPS_WARM_PLANNER: 1 or 0 as these).",
)  # fmt: skip
@click.option("-q", "--quiet", is_flag=True, help="Print only the run folder.")
@user_errors
def run(task_file: Path, rerun_mode: str, rerun_url: str | None, quiet: bool, **given: Any) -> None:
    """Run TASK (a task file) end to end: detect, plan, ground, compose, solve, time, check,
    predict the outcome, execute."""
    from keymps._memory import collector_paused_for_start_up

    if rerun_mode == "connect" and not rerun_url:
        raise click.UsageError("--rerun connect needs --rerun-url")
    with collector_paused_for_start_up() as start_up_done:
        _run(task_file, rerun_mode, rerun_url, quiet, given, start_up_done)


def _run(
    task_file: Path,
    rerun_mode: str,
    rerun_url: str | None,
    quiet: bool,
    given: dict[str, Any],
    start_up_done: Callable[[], None],
) -> None:
    from keymps.perception.board_model import prepare_lab_tables

    # The default detector's OpenCV tables (100 ms) are built on the other core while the task
    # loads; the board detector would start them only when it is made, too late to be hidden.
    prepare_lab_tables()
    from keymps.plugin.manager import skip_pydantic_plugin_scan

    skip_pydantic_plugin_scan()  # before the task models: the plugin scan is read once
    from keymps.cli.output import RunPrinter
    from keymps.errors import KeympsError
    from keymps.pipeline.engine import refuse_a_folder_of_other_files, run_task
    from keymps.planning.warm.dispatch import mode_from
    from keymps.run import Run, RunOptions, RunOverrides

    warm_planner = mode_from(given.pop("warm_planner"))
    if given.get("out") is not None:
        refuse_a_folder_of_other_files(Path(given["out"]))
    printer = RunPrinter(quiet=quiet)

    def stage_done(name: str, seconds: float, result: Any) -> None:
        start_up_done()  # the first stage has run: from here on the objects are the run's own
        printer.stage_done(name, seconds, result)

    try:
        finished = run_task(
            task_file,
            on_stage=stage_done,
            options=RunOptions(
                rerun=rerun_mode,
                rerun_url=rerun_url,
                quiet=quiet,
                no_cache=given.pop("no_cache"),
                record=given.pop("record"),
                confirm=given.pop("confirm"),
                accept_outcome=given.pop("accept_outcome"),
                warm_planner=warm_planner,
            ),
            overrides=RunOverrides(**given),
        )
    except KeympsError as error:
        if isinstance(error.run, Run):
            printer.failed(error.run)  # its warnings and folder explain the error line after
        raise
    printer.summary(finished)
    # The run folder's files are written and closed, the recording (saved or off) flushed and
    # closed by the recorder's `finished` stage: nothing is left for the interpreter to tear
    # down but memory. A viewer stream (spawn, connect) keeps its normal exit.
    if rerun_mode in ("save", "off"):
        everything_written()


@cli.command()
@click.argument(
    "task_files", metavar="TASK...", nargs=-1, required=True, type=click.Path(path_type=Path)
)
@user_errors
def validate(task_files: tuple[Path, ...]) -> None:
    """Check task files without running them: one line per problem, file:line:col first."""
    from keymps.pipeline.validation import validate_task_file

    failed = False
    for path in task_files:
        notes: list[str] = []
        problems = validate_task_file(path, notes)
        for line in problems:
            click.echo(line, err=True)
        if problems:
            failed = True
        else:
            click.echo(f"ok: {path}")
        for note in notes:
            click.echo(f"note: {note}", err=True)
    if failed:
        sys.exit(1)


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@user_errors
def plugins(as_json: bool) -> None:
    """List every plugin: name, what it provides, distribution and version."""
    from keymps.cli.output import print_plugins

    print_plugins(as_json)


def _one_line_warning(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> str:
    from keymps.planning.redaction import redact_text

    return f"warning: {redact_text(str(message))}\n"


_finished_cleanly = False


def everything_written() -> None:
    """A command says every file it wrote is closed: main() may skip the interpreter's teardown
    once the command has returned successfully."""
    global _finished_cleanly
    _finished_cleanly = True


SINGLE_THREADED = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""A run's linear algebra is 6 x 6 systems and batched 3 x 3 products: BLAS helper threads only
spin (on a shared machine, against other processes). Set before NumPy loads; a value the user
exported wins."""


def main() -> None:
    from keymps._memory import keep_freed_memory
    from keymps.interrupts import signals_stop_the_command

    for name in SINGLE_THREADED:
        os.environ.setdefault(name, "1")
    keep_freed_memory()  # freed arrays reused, not faulted in again page by page
    warnings.formatwarning = _one_line_warning
    try:
        with signals_stop_the_command() as signals:  # SIGTERM, SIGHUP stop a run as Ctrl-C does
            cli(prog_name="keymps")
    except SystemExit as done:
        if signals and isinstance(done.code, int):
            _exit_now(done.code, run_atexit=False)
        if not (_finished_cleanly and done.code in (None, 0)):
            raise
    else:  # pragma: no cover - click always ends with SystemExit in standalone mode
        return
    _exit_now(0)


def _exit_now(code: int, run_atexit: bool = True) -> None:
    """Exit without the interpreter's teardown (0.1-0.25 s of module and extension destructors
    after a run): the atexit handlers run first, then the streams are flushed. A command a
    signal stopped skips the atexit handlers and the wait for other threads too: the signal
    may have cut an import short and left Python's import lock held, and a thread importing
    then waited for it forever (1 SIGTERM in 30 hung the process)."""
    if run_atexit:
        atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    main()
