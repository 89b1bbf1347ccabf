"""Author the bundled demonstrations (CSV t,x,y,z) and fit the primitives to them.

Run from the repository root: `python primitives/author_demos.py`. Every demo is a smooth,
hand-designed 3D tool-tip path sampled at 100 Hz, in metres, starting at rest and ending at
rest. Cutting demos go from the top of a 5 cm object at one end of a 10 cm cut to the board
surface (z = 0) at the other end, the blade along +x, like a grounded cutting pair; they are
re-targeted in `blade` mode (strokes keep their length and stay level, the depth scales). The
icing demo starts and ends at the nozzle's travel height (`axial` mode).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from keymps.primitives.demos import Preprocessing, write_demo_csv
from keymps.primitives.dictionary import learn_primitive

HERE = Path(__file__).resolve().parent
RATE_HZ = 100.0
CUT_LENGTH = 0.10
CUT_DEPTH = 0.05


def min_jerk(x: np.ndarray) -> np.ndarray:
    """0 -> 1 with zero velocity and acceleration at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return 10 * x**3 - 15 * x**4 + 6 * x**5


def window(x: np.ndarray, start: float, end: float) -> np.ndarray:
    """A min-jerk ramp that runs from 0 to 1 between normalized times start and end."""
    return min_jerk((x - start) / (end - start))


def samples(duration: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(round(duration * RATE_HZ)) + 1) / RATE_HZ
    return t, t / t[-1]


def straight() -> tuple[np.ndarray, np.ndarray]:
    """Straight down through 5 cm, no horizontal motion."""
    t, x = samples(2.0)
    return t, np.stack([0 * x, 0 * x, CUT_DEPTH * (1 - min_jerk(x))], axis=1)


def sawing() -> tuple[np.ndarray, np.ndarray]:
    """Four forward-backward strokes of +-2 cm along the blade while descending 5 cm and
    advancing 10 cm along the cut."""
    t, x = samples(5.0)
    envelope = window(x, 0.0, 0.12) * (1 - window(x, 0.88, 1.0))
    stroke = 0.02 * np.sin(2 * np.pi * 4 * x) * envelope
    return t, np.stack(
        [CUT_LENGTH * min_jerk(x) + stroke, 0 * x, CUT_DEPTH * (1 - min_jerk(x))], axis=1
    )


def downward() -> tuple[np.ndarray, np.ndarray]:
    """Press down through most of the object first, then draw the blade along the board."""
    t, x = samples(3.0)
    return t, np.stack(
        [CUT_LENGTH * window(x, 0.35, 1.0), 0 * x, CUT_DEPTH * (1 - window(x, 0.0, 0.65))],
        axis=1,
    )


def forward() -> tuple[np.ndarray, np.ndarray]:
    """Push the blade forward along the cut while it descends: one forward slicing stroke."""
    t, x = samples(3.0)
    return t, np.stack(
        [CUT_LENGTH * window(x, 0.0, 0.75), 0 * x, CUT_DEPTH * (1 - window(x, 0.2, 1.0))], axis=1
    )


def line() -> tuple[np.ndarray, np.ndarray]:
    """Descend 4 mm to the drawing height, move 5 cm laterally, lift 4 mm."""
    t, x = samples(3.0)
    dip = 0.004 * (window(x, 0.0, 0.2) - window(x, 0.8, 1.0))
    return t, np.stack([0.05 * window(x, 0.2, 0.8), 0 * x, -dip], axis=1)


PRIMITIVES = {
    "straight": dict(
        demo=straight,
        family="cutting",
        mode="blade",
        nominal_speed=0.02,
        description=(
            "Straight cut: the blade moves in one smooth straight line from the top of the "
            "object to the board, without any back-and-forth motion. For soft objects that a "
            "single straight cut goes through (cake, bread crumb, banana, cucumber, cheese)."
        ),
    ),
    "sawing": dict(
        demo=sawing,
        family="cutting",
        mode="blade",
        nominal_speed=0.04,
        description=(
            "Sawing cut: four forward-backward strokes of about 2 cm along the blade while the "
            "knife descends through the object to the board. For hard or crusty objects (crusty "
            "bread, baguette, pineapple, squash, cabbage, frozen food)."
        ),
    ),
    "downward": dict(
        demo=downward,
        family="cutting",
        mode="blade",
        nominal_speed=0.02,
        description=(
            "Downward cut: press the blade down through the object first, then draw it along "
            "the board to finish the cut. For soft objects that should not be pushed sideways "
            "(tomato, soft fruit, sponge cake, tofu)."
        ),
    ),
    "forward": dict(
        demo=forward,
        family="cutting",
        mode="blade",
        nominal_speed=0.03,
        description=(
            "Forward cut: push the blade forward along the cut while it descends, in one "
            "slicing stroke. For firmer objects that need the blade to travel (carrot, potato, "
            "apple, firm vegetables) where back-and-forth sawing would move them."
        ),
    ),
    "line": dict(
        demo=line,
        family="icing",
        mode="axial",
        nominal_speed=0.02,
        description=(
            "Icing line: lower the nozzle to the drawing height, pipe a line from the start "
            "point to the end point, lift the nozzle. A pair whose start equals its end pipes "
            "a dot (rosette). For every icing or decorating design: lines, outlines, letters, "
            "dots."
        ),
    ),
}


def main() -> None:
    for name, spec in PRIMITIVES.items():
        t, y = spec["demo"]()  # type: ignore[operator]
        demo = HERE / f"{name}.csv"
        write_demo_csv(demo, t, y)
        primitive = learn_primitive(
            name,
            demo,
            description=str(spec["description"]),
            family=str(spec["family"]),
            mode=str(spec["mode"]),
            nominal_speed=float(spec["nominal_speed"]),  # type: ignore[arg-type]
            preprocessing=Preprocessing(trim_mm=0.0),
            out_dir=HERE,
        )
        print(f"{name:9s} {len(t):4d} samples  fit RMSE {primitive.fit_rmse * 1000:.4f} mm")


if __name__ == "__main__":
    main()
