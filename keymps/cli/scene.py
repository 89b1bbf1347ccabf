"""`keymps scene`: render synthetic top-down scenes (PNG + JSON sidecar with the true geometry)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from keymps.cli.errors import user_errors
from keymps.cli.params import FiniteFloat


def _pair(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    parts = text.replace("x", ",").split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise click.BadParameter(f"expected W,H in metres (e.g. 0.30,0.18), got {text!r}") from None
    if len(values) != 2 or not all(math.isfinite(v) and v > 0 for v in values):
        raise click.BadParameter(f"expected two positive numbers W,H in metres, got {text!r}")
    return values[0], values[1]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def scene() -> None:
    """Synthetic top-down scenes with known metric geometry."""


@scene.command()
@click.argument("objects", nargs=-1, required=True, metavar="OBJECT...")
@click.option("--length", type=FiniteFloat(min=0, min_open=True), help="Length, metres.")
@click.option("--width", type=FiniteFloat(min=0, min_open=True), help="Width, metres.")
@click.option("--height", type=FiniteFloat(min=0, min_open=True), help="Height, metres.")
@click.option(
    "--rotation", type=FiniteFloat(), help="Angle of the length axis from board x, degrees."
)
@click.option("--seed", type=int, default=0, show_default=True, help="Randomization seed.")
@click.option("--board", default="0.30,0.18", show_default=True, help="Board size W,H, metres.")
@click.option(
    "--px-per-m", type=click.FloatRange(100, 20000), default=2000.0, show_default=True,
    help="Resolution: pixels per metre.",
)  # fmt: skip
@click.option(
    "--out", required=True, type=click.Path(dir_okay=False, path_type=Path),
    help="PNG to write; the sidecar is written next to it (.json).",
)  # fmt: skip
@user_errors
def render(
    objects: tuple[str, ...],
    length: float | None,
    width: float | None,
    height: float | None,
    rotation: float | None,
    seed: int,
    board: str,
    px_per_m: float,
    out: Path,
) -> None:
    """Render OBJECT (or several, left to right) on a wooden board.

    Objects: round_cake, square_cake, round_pizza, cabbage, eggplant, baguette, banana_bread,
    chiffon_cake, baumkuchen, meat_loaf, cucumber, potato, banana. Sizes not given are the
    object's defaults, varied slightly by the seed.
    """
    from keymps.scenes.render import SceneSpec, render_scene

    board_size = _pair(board)
    assert board_size is not None
    spec = SceneSpec.from_kinds(
        objects,
        seed=seed,
        length=length,
        width=width,
        height=height,
        rotation=rotation,
        board_size=board_size,
        px_per_m=px_per_m,
    )
    rendered = render_scene(spec)
    png, sidecar = rendered.save(out)
    width_px, height_px = spec.image_size_px
    for item in rendered.truth["objects"]:
        click.echo(
            f"{item['kind']}: {item['length_m'] * 100:.1f} x {item['width_m'] * 100:.1f} x "
            f"{item['height_m'] * 100:.1f} cm at ({item['centre_m'][0]:.3f}, "
            f"{item['centre_m'][1]:.3f}) m, box {item['bbox_px']} px"
        )
    click.echo(f"wrote {png} ({width_px} x {height_px} px) and {sidecar}")


@scene.command(name="list")
def list_objects() -> None:
    """The object kinds and their default sizes."""
    from keymps.scenes.render import KINDS

    for kind in KINDS.values():
        click.echo(
            f"{kind.name:14s} {kind.length * 100:5.1f} x {kind.width * 100:4.1f} x "
            f"{kind.height * 100:4.1f} cm  {kind.description}"
        )
