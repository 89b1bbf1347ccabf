"""`keymps calibrate`: the scene.camera block from four ArUco markers at the board's corners."""

from __future__ import annotations

from pathlib import Path

import click

from keymps.cli.errors import user_errors
from keymps.cli.params import FiniteFloat, finite_numbers


@click.command(
    name="calibrate",
    context_settings={"help_option_names": ["-h", "--help"]},
    epilog="Example: keymps calibrate photo.jpg --board 0.38,0.24 --out camera.yaml; "
    "then copy its scene.camera block into the task file. See docs/perception.md.",
)
@click.argument("image", required=False, type=click.Path(path_type=Path))
@click.option("--board", help="Width,height of the board between the markers' corners, metres.")
@click.option(
    "--marker-size", type=click.FloatRange(min=1, max=300), default=40.0, show_default=True,
    help="Side of a marker's black square in mm (the printed sheet, and a check of the photo).",
)  # fmt: skip
@click.option("--intrinsics", help="fx,fy,cx,cy of a calibrated camera (pixels, OpenCV).")
@click.option("--distortion", help="k1,k2,p1,p2[,k3] of that camera (with --intrinsics).")
@click.option(
    "--mm-per-px", type=FiniteFloat(min=0.05, max=10), default=0.5, show_default=True,
    help="Rectified resolution (the task file's scene.camera.mm_per_px, 0.05-10).",
)  # fmt: skip
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), help="Write the YAML here.")
@click.option(
    "--print-markers", "sheet", type=click.Path(dir_okay=False, path_type=Path),
    help="Write the printable marker sheet (PNG, A4 at 300 dpi) and stop.",
)  # fmt: skip
@user_errors
def calibrate(
    image: Path | None,
    board: str | None,
    marker_size: float,
    intrinsics: str | None,
    distortion: str | None,
    mm_per_px: float,
    out: Path | None,
    sheet: Path | None,
) -> None:
    """Find markers 0-3 (DICT_4X4_50) at the board's corners in IMAGE; print scene.camera."""
    from keymps.perception.calibration import calibration_yaml, write_marker_sheet

    if sheet is not None:
        click.echo(write_marker_sheet(sheet, marker_size))
        return
    if image is None or board is None:
        raise click.UsageError("give IMAGE and --board W,H (or --print-markers FILE.png)")
    width, height = finite_numbers(board, (2,), "--board")
    if width <= 0 or height <= 0:
        raise click.BadParameter(f"--board: two positive sizes in metres, got {board!r}")
    camera = finite_numbers(intrinsics, (4,), "--intrinsics") if intrinsics else None
    if camera is not None and (camera[0] <= 0 or camera[1] <= 0):
        raise click.BadParameter(f"--intrinsics: fx and fy are positive pixels, got {intrinsics!r}")
    if distortion and camera is None:
        raise click.UsageError("--distortion needs --intrinsics")
    coefficients = finite_numbers(distortion, (4, 5, 8), "--distortion") if distortion else []
    text, notes = calibration_yaml(
        image, (width, height), marker_size, camera, coefficients, mm_per_px
    )
    for note in notes:
        click.echo(f"warning: {note}", err=True)
    if out is None:
        click.echo(text, nl=False)
    else:
        out.write_text(text, encoding="utf-8")
        click.echo(f"wrote {out}")
