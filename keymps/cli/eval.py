"""`keymps eval SUITE`: run a benchmark suite (paper Tables I, IV, V and Appendix F) and score it."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from keymps.cli.errors import user_errors

if TYPE_CHECKING:
    from keymps.eval.runner import EvalOptions
    from keymps.eval.suites import Suite

METHOD_NAMES = (
    "keymps",
    "keymps-design",
    "vlm-keypoint",
    "keymps-text",
    "vlm-keyword",
    "vlm-dmp",
    "vlm-mdmp",
)


@click.command(
    name="eval",
    context_settings={"help_option_names": ["-h", "--help"]},
    epilog="Suites shipped: cutting_sim, icing, cake_six, real_cutting, multi_object "
    "(benchmarks/suites/), and `perception` (the detector benchmark of docs/perception.md: "
    "--repeats sets the boards per 100). Without --model the offline planner runs (methods "
    "keymps and vlm-keypoint only).",
)
@click.argument("suite_file", metavar="SUITE")
@click.option(
    "--method", "methods", multiple=True, type=click.Choice(METHOD_NAMES),
    help="Method to run (repeatable; default keymps).",
)  # fmt: skip
@click.option("--repeats", type=click.IntRange(1, 1000), help="Runs per case (suite default).")
@click.option(
    "--concurrency", type=click.IntRange(1, 64), default=1, show_default=True,
    help="VLM calls made at once (a few more runs prepare theirs meanwhile).",
)  # fmt: skip
@click.option(
    "--processes", type=click.IntRange(1, 64),
    help="Worker processes sharing the runs (default: one per core when there are "
    "enough runs; 1: all in this process).",
)  # fmt: skip
@click.option("--backend", help="Planner backend: offline, litellm, replay or a plugin's.")
@click.option("--model", help="VLM model for litellm, e.g. openai/gpt-4o.")
@click.option("--api-base", help="OpenAI-compatible server URL (Ollama, vLLM ...).")
@click.option("--case", "cases", multiple=True, help="Only this case id (repeatable).")
@click.option("--no-cache", is_flag=True, help="Always call the VLM, never answer from cache.")
@click.option(
    "--verify-outcome", "verify", is_flag=True,
    help="Equal-parts suites go through the outcome stage: a wrong plan is repaired or refused.",
)  # fmt: skip
@click.option(
    "--image-format", type=click.Choice(["jpg", "png"]), default="jpg", show_default=True,
    help="Each run's plan and outcome images (png: lossless, ten times the size).",
)  # fmt: skip
@click.option(
    "--out", type=click.Path(file_okay=False, path_type=Path),
    help="Results folder (default eval/SUITE[-METHODS]); rerunning into it resumes.",
)  # fmt: skip
@click.option(
    "--warm-planner/--no-warm-planner", default=None,
    help="Start the warm planner when it is not up (keymps planner), or never use it. "
    "Default: use it when it is up ($KEYMPS_WARM_PLANNER: 1 or 0 as these).",
)  # fmt: skip
@click.option("--quiet", is_flag=True, help="No progress bar.")
@user_errors
def eval_command(
    suite_file: str,
    methods: tuple[str, ...],
    repeats: int | None,
    concurrency: int,
    processes: int | None,
    backend: str | None,
    model: str | None,
    api_base: str | None,
    cases: tuple[str, ...],
    out: Path | None,
    no_cache: bool,
    verify: bool,
    image_format: str,
    warm_planner: bool | None,
    quiet: bool,
) -> None:
    """Run every case x method x repeat of SUITE (a file or a shipped suite's name), write
    results.jsonl, summary.md, summary.csv, d_boxplot.png and gallery.html, print the table."""
    import os

    if suite_file == PERCEPTION:
        _perception(out or Path("eval") / PERCEPTION, repeats or 4)
        return
    # Runs are the unit of parallelism; set before NumPy loads OpenBLAS, whose helper threads
    # would otherwise spin on the other core after every matrix product.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from keymps._memory import collector_paused_for_start_up

    with collector_paused_for_start_up() as start_up_done:
        warm = _get_going(backend, model, api_base, concurrency, processes, warm_planner)
        from keymps.eval.runner import EvalOptions
        from keymps.eval.suites import load_suite

        suite = load_suite(suite_file)
        chosen = methods or ("keymps",)
        folder = out or Path("eval") / "-".join([suite.name, *(chosen if methods else ())])
        options = EvalOptions(
            out=folder,
            methods=tuple(dict.fromkeys(chosen)),
            repeats=repeats,
            concurrency=concurrency,
            processes=processes,
            backend=backend,
            model=model,
            api_base=api_base,
            cases=cases,
            no_cache=no_cache,
            image_format=image_format,
            outcome="repair" if verify else "off",
            warm_planner=warm,
        )
        # start-up's objects frozen: never scanned again, here or in the forked workers
        start_up_done()
        records = _run_or_resume_hint(suite, options, quiet)
        _report(records, suite, folder)


def _get_going(
    backend: str | None,
    model: str | None,
    api_base: str | None,
    concurrency: int,
    processes: int | None,
    warm_planner: bool | None,
) -> Any:
    """Start what the runs will need on the other core while the suite is read; the warm
    planner mode (keymps.planning.warm.dispatch)."""
    from keymps.perception.board_model import prepare_lab_tables

    # OpenCV's Lab tables (100 ms) on the idle core while the suite loads; the worker
    # processes forked from this one inherit them (keymps.eval.pool waits before forking)
    prepare_lab_tables()
    from keymps.plugin.manager import skip_pydantic_plugin_scan

    skip_pydantic_plugin_scan()  # before the suite's models: the plugin scan is read once
    from keymps.eval.pool import get_going
    from keymps.eval.runner import backend_named
    from keymps.planning.warm.dispatch import mode_from

    warm = mode_from(warm_planner)
    # litellm's import (or the warm planner) and the workers' fork server
    get_going(
        backend_named(backend, model, api_base), model, api_base, concurrency, processes, warm
    )
    return warm


def _run_or_resume_hint(suite: Suite, options: EvalOptions, quiet: bool) -> list[dict[str, Any]]:
    """Every run's record; on Ctrl-C, how many are kept and how to resume, then exit."""
    try:
        return _run(suite, options, quiet)
    except KeyboardInterrupt as interrupt:
        from keymps.cli.errors import interrupted_exit_code
        from keymps.eval.runner import RESULTS_FILE, read_results

        results = options.out / RESULTS_FILE
        click.echo(
            f"interrupted: {len(read_results(results))} finished runs are in {results}; run the "
            "same command again to resume",
            err=True,
        )
        sys.exit(interrupted_exit_code(interrupt))


def _report(records: list[dict[str, Any]], suite: Suite, folder: Path) -> None:
    """Write the summaries and print the table and where everything is."""
    from keymps.eval.report import markdown_table, write_summary

    rows = write_summary(records, suite, folder)
    click.echo(markdown_table(rows, suite))
    failed = sum(1 for r in records if not r.get("ok"))
    click.echo(
        f"{len(records)} runs ({failed} failed); results in {folder}/ "
        "(results.jsonl, summary.md, summary.csv, gallery.html)"
    )
    from keymps.cli.app import everything_written

    # results.jsonl is synced record by record, the summaries are written and closed and the
    # workers have ended (skipping the teardown saves 0.3-0.5 s here)
    everything_written()


PERCEPTION = "perception"
"""Not a suite file: the generated perception benchmark (keymps.eval.perception)."""


def _perception(folder: Path, hundreds: int) -> None:
    """Board vs threshold detector on generated boards and photos; summary.md in `folder`."""
    from keymps.eval.perception import flat_benchmark, photo_benchmark, table

    flat = flat_benchmark(100 * hundreds)
    photos = photo_benchmark(10 * hundreds)
    text = table(flat, photos)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "summary.md").write_text(text + "\n", encoding="utf-8")
    board, tall = flat["board"], photos["board+intrinsics"]
    met = all(
        rate == 1.0
        for rate in (
            board["found"].rate,
            board["refused"].rate,
            tall["tall"].rate,
            tall["flat"].rate,
        )
    )
    click.echo(text)
    click.echo(f"{'targets met' if met else 'targets NOT met'}; table in {folder / 'summary.md'}")
    if not met:
        sys.exit(1)


def _run(suite: Suite, options: EvalOptions, quiet: bool) -> list[dict[str, Any]]:
    """Every run of the suite, with a progress bar unless quiet."""
    from keymps.eval.runner import plan_jobs, run_suite

    total = len(plan_jobs(suite, options))
    if quiet:
        return run_suite(suite, options)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    from keymps.eval.pool import OFFLINE_BACKENDS
    from keymps.eval.runner import resolve_backend

    progress = Progress(
        "[progress.description]{task.description}",
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        transient=True,
    )
    bar = progress.add_task(f"{suite.name}", total=total)
    # The bar's refresh thread starts with the first result for offline runs: their worker
    # processes are forked from this process, which must have no thread then (fork_here).
    if resolve_backend(options) not in OFFLINE_BACKENDS:
        progress.start()

    def advance(job: object, record: dict[str, object]) -> None:
        if not progress.live.is_started:
            progress.start()
        status = "ok" if record.get("ok") else "failed"
        progress.update(bar, advance=1, description=f"{suite.name}: {job.label} {status}")  # type: ignore[attr-defined]

    try:
        return run_suite(suite, options, on_result=advance)
    finally:
        progress.stop()
