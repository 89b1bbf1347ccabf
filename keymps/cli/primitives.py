"""`keymps primitives`: list, show, learn and plot the primitive dictionary."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from keymps.cli.errors import user_errors

if TYPE_CHECKING:
    import numpy as np

    from keymps.primitives.dictionary import Primitive
    from keymps.primitives.dmp import DMP


def _search_dirs(extra: tuple[Path, ...]) -> list[Path]:
    from keymps.primitives.dictionary import default_search_dirs

    return [*(p.resolve() for p in extra), *default_search_dirs(Path.cwd())]


_dir_option = click.option(
    "--dir",
    "dirs",
    multiple=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Also search this folder (first). Repeatable.",
)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def primitives() -> None:
    """The primitive dictionary: DMPs fitted to demonstrations, chosen by the planner.

    Search order: DIRs given with --dir, ../primitives and primitives/ of the current folder,
    each folder in KEYMPS_PRIMITIVES_PATH, ./primitives, then the bundled dictionary."""


@primitives.command("list")
@_dir_option
@user_errors
def list_command(dirs: tuple[Path, ...]) -> None:
    """List every primitive found, first match of a name winning."""
    from keymps.primitives.dictionary import find_primitive_files, load_primitive

    found = find_primitive_files(_search_dirs(dirs))
    if not found:
        click.echo("no primitives found")
        return
    rows = [("NAME", "FAMILY", "MODE", "SPEED m/s", "FIT RMSE mm", "FILE")]
    for name, path in sorted(found.items()):
        p = load_primitive(path)
        rows.append(
            (name, p.family, p.mode, f"{p.nominal_speed:.3f}", f"{p.fit_rmse * 1e3:.3f}", str(path))
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        padded = [cell.ljust(width) for cell, width in zip(row[:-1], widths, strict=True)]
        click.echo("  ".join([*padded, row[-1]]))


@primitives.command()
@click.argument("name")
@_dir_option
@user_errors
def show(name: str, dirs: tuple[Path, ...]) -> None:
    """Show one primitive: what the planner reads, its DMP and its demonstration."""
    import numpy as np

    from keymps.primitives.demos import load_demo_csv
    from keymps.primitives.dictionary import load_primitives

    p = load_primitives([name], _search_dirs(dirs))[name]
    dmp = p.dmp
    rollout = dmp.rollout(dmp.demo_start, dmp.demo_goal)
    extent = np.ptp(rollout.y, axis=0) * 1000
    flat = _flat_for_blade(dmp.demo_delta)
    lines = [
        f"name:          {p.name}",
        f"file:          {p.path}",
        f"family:        {p.family}",
        f"mode:          {p.mode}"
        + (f" (re-targets as axial: {flat})" if p.mode == "blade" and flat else ""),
        f"nominal speed: {p.nominal_speed:.3f} m/s (average along the path)",
        f"description:   {p.description}",
        f"DMP:           {dmp.n_basis} basis functions per axis, alpha_z {dmp.alpha_z:g}, "
        f"beta_z {dmp.beta_z:g}, alpha_s {dmp.alpha_s:g}",
        f"demo start:    {_mm(dmp.demo_start)} mm",
        f"demo goal:     {_mm(dmp.demo_goal)} mm",
        f"demo duration: {dmp.demo_duration:.3f} s",
        f"path:          {rollout.length_m * 1000:.1f} mm long, extent x {extent[0]:.1f} "
        f"y {extent[1]:.1f} z {extent[2]:.1f} mm",
        f"fit RMSE:      {p.fit_rmse * 1000:.4f} mm",
    ]
    if p.demo is not None:
        if p.demo.is_file():
            t, _ = load_demo_csv(p.demo)
            lines.append(f"demo:          {p.demo} ({len(t)} samples)")
        else:
            lines.append(f"demo:          {p.demo} (missing)")
    if p.source:
        lines.append(f"learned from:  {p.source}")
    if p.source_preprocessing:
        applied = ", ".join(f"{k} {v}" for k, v in p.source_preprocessing.to_dict().items())
        lines.append(f"cleaned with:  {applied}")
    click.echo("\n".join(lines))


def _flat_for_blade(demo_delta: Any) -> str | None:
    """Why `blade` re-targets this demo as `axial` (too little vertical travel), or None."""
    import numpy as np

    from keymps.primitives.retarget import BLADE_MIN_SLOPE, blade_applies

    if blade_applies(demo_delta):
        return None
    vertical_mm = abs(float(demo_delta[2])) * 1000
    length_mm = float(np.linalg.norm(demo_delta)) * 1000
    return (
        f"the demo moves only {vertical_mm:.1f} mm vertically over {length_mm:.1f} mm, "
        f"under the {BLADE_MIN_SLOPE:.0%} blade needs"
    )


def _mm(point: Any) -> str:
    return "[" + ", ".join(f"{1000 * v:.1f}" for v in point) + "]"


def _point(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"{text!r} is not three numbers A,B,C (metres)") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise click.BadParameter(f"{text!r} is not three finite numbers A,B,C (metres)")
    return values[0], values[1], values[2]


@primitives.command()
@click.argument("demo", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--name", required=True, help="Primitive name (lower case, e.g. my-saw).")
@click.option("--basis", default=50, show_default=True, help="Basis functions per axis.")
@click.option("--description", help="What the planner reads when choosing (say when to use it).")
@click.option(
    "--family", type=click.Choice(["cutting", "icing"]), default="cutting", show_default=True
)
@click.option(
    "--mode",
    type=click.Choice(["similarity", "axial", "blade", "translate"]),
    help="How the demo is re-targeted to a keypoint pair (default: blade for cutting, axial "
    "for icing).",
)
@click.option("--speed", default=0.03, show_default=True, help="Nominal tool speed, m/s.")
@click.option("--rate", type=float, help="Resample to this rate, Hz (default: keep, or median).")
@click.option("--smooth", default=0.0, show_default=True, help="Smoothing window, s (0: off).")
@click.option("--trim", default=0.5, show_default=True, help="Trim still ends within this, mm.")
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    default=Path("primitives"),
    show_default=True,
    help="Folder for NAME.yaml and the prepared NAME.csv.",
)
@user_errors
def learn(
    demo: Path,
    name: str,
    basis: int,
    description: str | None,
    family: str,
    mode: str | None,
    speed: float,
    rate: float | None,
    smooth: float,
    trim: float,
    out: Path,
) -> None:
    """Fit a primitive to DEMO.csv (header t,x,y,z; seconds, metres) and write OUT/NAME.yaml.

    A robot log is cleaned first: resampled to a uniform rate, smoothed (with --smooth:
    Savitzky-Golay, cubic) and trimmed of the still samples at both ends; pauses in the middle
    are kept."""
    from keymps.primitives.demos import Preprocessing
    from keymps.primitives.dictionary import (
        DEFAULT_MODES,
        MAX_FIT_RMSE,
        PrimitiveError,
        learn_primitive,
    )

    if (rate is not None and rate <= 0) or smooth < 0 or trim < 0:
        raise PrimitiveError("--rate must be positive, --smooth and --trim not negative")
    primitive = learn_primitive(
        name,
        demo,
        description=description or f"Learned from {demo.name}.",
        family=family,
        mode=mode,
        nominal_speed=speed,
        n_basis=basis,
        preprocessing=Preprocessing(rate_hz=rate, smooth_s=smooth, trim_mm=trim),
        out_dir=out,
    )
    click.echo(
        f"wrote {primitive.path}: {primitive.dmp.n_basis} basis functions, "
        f"{primitive.dmp.demo_duration:.2f} s, fit RMSE {primitive.fit_rmse * 1000:.3f} mm, "
        f"mode {primitive.mode}"
    )
    flat = _flat_for_blade(primitive.dmp.demo_delta)
    if (mode or DEFAULT_MODES.get(family)) == "blade" and flat:
        click.echo(f"note: {flat}, so it re-targets as axial", err=True)
    if primitive.fit_rmse > MAX_FIT_RMSE:
        click.echo(
            f"warning: fit RMSE above {MAX_FIT_RMSE * 1000:.1f} mm; try more --basis or --smooth",
            err=True,
        )


@primitives.command()
@click.argument("name")
@click.option(
    "--to",
    "targets",
    multiple=True,
    help="Re-target to the goal A,B,C, metres in the demo's frame (the path starts at the "
    "demo's start, or --from). Repeatable.",
)
@click.option("--from", "start", help="Start A,B,C in metres (default: the demo's start).")
@click.option("--mode", type=click.Choice(["similarity", "axial", "blade", "translate"]))
@click.option("--out", type=click.Path(path_type=Path, dir_okay=False), help="PNG (NAME.png).")
@_dir_option
@user_errors
def plot(
    name: str,
    targets: tuple[str, ...],
    start: str | None,
    mode: str | None,
    out: Path | None,
    dirs: tuple[Path, ...],
) -> None:
    """Draw the demonstration and re-targeted rollouts in 3D, red -> green -> blue over time.

    Without --to: the fit, the segment turned 90 degrees about z, and 1.5 times longer."""
    plt = _pyplot()
    out = _writable_by_matplotlib(out or Path(f"{name}.png"))
    import numpy as np

    from keymps.primitives.dictionary import load_primitives

    primitive = load_primitives([name], _search_dirs(dirs))[name]
    origin = np.array(_point(start)) if start else primitive.dmp.demo_start
    goals, labels = _plot_goals(primitive.dmp, origin, targets)
    figure = plt.figure(figsize=(7, 6))
    axes = figure.add_subplot(projection="3d")
    _plot_demo(axes, primitive, origin)
    _plot_rollouts(axes, primitive, origin, goals, labels, mode)
    _finish_axes(axes, primitive, origin, goals, mode)
    figure.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(figure)
    click.echo(f"wrote {out}")


def _pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend; one line of error when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise click.ClickException("plot needs matplotlib: pip install matplotlib") from None
    return plt


def _writable_by_matplotlib(out: Path) -> Path:
    """`out`, unless matplotlib writes no files of its suffix (a usage error then)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    suffix = out.suffix.lstrip(".").lower()
    supported = FigureCanvasAgg.get_supported_filetypes()
    if suffix and suffix not in supported:
        known = ", ".join(sorted(supported))
        raise click.BadParameter(
            f"{out}: matplotlib writes no .{suffix} files (one of: {known})", param_hint="'--out'"
        )
    return out


def _plot_goals(
    dmp: DMP, origin: np.ndarray, targets: tuple[str, ...]
) -> tuple[list[np.ndarray], list[str]]:
    """The goals (3,) to roll out to, metres, and their legend labels: those of --to, or three
    that show how the demonstration re-targets."""
    import numpy as np

    if targets:
        goals = [np.array(_point(text)) for text in targets]
        return goals, [f"to ({', '.join(f'{v:g}' for v in goal)})" for goal in goals]
    c, s = 0.0, 1.0
    turned = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ dmp.demo_delta
    goals = [origin + dmp.demo_delta, origin + turned, origin + 1.5 * dmp.demo_delta]
    labels = [
        "fit: the demonstration's own goal",
        "goal turned 90 degrees about z",
        "1.5 times longer",
    ]
    return goals, labels


def _plot_demo(axes: Any, primitive: Primitive, origin: np.ndarray) -> None:
    """The demonstration in grey, moved to start at origin (when its file is there)."""
    from keymps.primitives.demos import load_demo_csv

    if primitive.demo is None or not primitive.demo.is_file():
        return
    _, demo_y = load_demo_csv(primitive.demo)
    demo_y = demo_y - primitive.dmp.demo_start + origin
    axes.plot(*demo_y.T, color="0.6", linewidth=3, alpha=0.5, label="demonstration")


def _plot_rollouts(
    axes: Any,
    primitive: Primitive,
    origin: np.ndarray,
    goals: list[np.ndarray],
    labels: list[str],
    mode: str | None,
) -> None:
    """Each rollout from origin, coloured by time, its goal marked and numbered."""
    import numpy as np
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    colors = _time_colors(np)
    markers = "x^sdvP*"
    for number, (goal, label) in enumerate(zip(goals, labels, strict=True), start=1):
        y = primitive.rollout(origin, goal, mode=mode, spacing=0.0005).y
        pieces = np.stack([y[:-1], y[1:]], axis=1)
        axes.add_collection(
            Line3DCollection(pieces, colors=colors(np.linspace(0, 1, len(pieces))), linewidth=2)
        )
        # the rollouts share the time colours: each goal's marker and number tell them apart
        marker = markers[(number - 1) % len(markers)]
        axes.scatter(*goal, marker=marker, color="k", s=40, label=f"{number}: {label}")
        axes.text(*goal, f" {number}", color="k")


def _finish_axes(
    axes: Any, primitive: Primitive, origin: np.ndarray, goals: list[np.ndarray], mode: str | None
) -> None:
    """The start marked, the axes labelled and equally scaled, the title and the legend."""
    import numpy as np

    axes.scatter(*origin, marker="o", color="k", s=20, label="start")
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_zlabel("z [m]")
    axes.set_title(f"{primitive.name} ({primitive.mode}): time red -> green -> blue")
    axes.legend(loc="upper left")
    points = np.vstack([origin, *goals])
    _equal_axes(axes, np, points, [primitive.rollout(origin, g, mode=mode).y for g in goals])


def _time_colors(np: Any) -> Callable[[Any], Any]:
    """Red at the start, green halfway, blue at the end."""

    def colors(fraction: Any) -> Any:
        red = np.clip(1 - 2 * fraction, 0, 1)
        blue = np.clip(2 * fraction - 1, 0, 1)
        green = 1 - red - blue
        return np.stack([red, green, blue], axis=1)

    return colors


def _equal_axes(axes: Any, np: Any, points: Any, paths: list[Any]) -> None:
    every = np.vstack([points, *paths])
    center = (every.max(axis=0) + every.min(axis=0)) / 2
    half = max(float((every.max(axis=0) - every.min(axis=0)).max()) / 2, 1e-3)
    axes.set_xlim(center[0] - half, center[0] + half)
    axes.set_ylim(center[1] - half, center[1] + half)
    axes.set_zlim(center[2] - half, center[2] + half)
