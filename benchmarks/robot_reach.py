"""How much of the paper's boards each built-in arm reaches with the knife pointing down.

    python benchmarks/robot_reach.py [--step 0.02] [--quick]

For the simulation board (0.30 x 0.18 m) and the real one (0.38 x 0.24 m), each arm stands at
its default place (ArmSpec.base_for) with the knife (tip 10 cm from the tool mount); a grid of
board points (every `--step` metres) at the board surface and 10 cm above it is solved with the
tool pointing down at yaws 0 and 90 degrees. Printed: the share of points reached at both yaws,
per height, as docs/robot.md's table shows it.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

ARMS = ("ur3", "ur3e", "ur5", "ur5e", "ur10", "ur10e", "ur16e", "ur20", "panda", "so101")
BOARDS = {"sim 0.30 x 0.18": (0.30, 0.18), "real 0.38 x 0.24": (0.38, 0.24)}
HEIGHTS = (0.0, 0.10)


def reached(name: str, board: tuple[float, float], step: float) -> list[float]:
    """Per height, the share of grid points reachable at yaw 0 and 90 degrees."""
    from keymps.robot.description import BUILTIN_TOOLS
    from keymps.robot.model import RobotModel

    robot = RobotModel(name, tool=BUILTIN_TOOLS["knife"], board_size=board)
    xs = np.arange(0.0, board[0] + 1e-9, step)
    ys = np.arange(0.0, board[1] + 1e-9, step)
    shares = []
    for z in HEIGHTS:
        hits = [
            all(robot.reachable(np.array([x, y, z]), yaw) for yaw in (0.0, np.pi / 2))
            for x in xs
            for y in ys
        ]
        shares.append(float(np.mean(hits)))
    return shares


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--step", type=float, default=0.02, help="grid spacing, metres")
    parser.add_argument("--quick", action="store_true", help="two arms, a 10 cm grid")
    args = parser.parse_args()
    arms = ("ur3", "so101") if args.quick else ARMS
    step = 0.10 if args.quick else args.step
    header = " | ".join(f"{board}: z {', '.join(f'{h * 100:.0f}' for h in HEIGHTS)} cm"
                        for board in BOARDS)  # fmt: skip
    print(f"| arm | {header} |")
    for name in arms:
        cells = []
        for board in BOARDS.values():
            shares = reached(name, board, step)
            cells.append(", ".join(f"{share * 100:.0f} %" for share in shares))
        print(f"| {name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
