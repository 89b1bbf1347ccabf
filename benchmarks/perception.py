"""The perception benchmark (docs/perception.md): board vs threshold detector, designs on photos.

    python benchmarks/perception.py [--boards 400] [--photos 40]

Prints the Markdown table of docs/perception.md: objects found within 3 px, empty boards
refused, and the largest keypoint error (mm) of designs on photos taken at 20-45 degrees.
Exits 1 when the board detector misses a target (100 %, 100 %, 1.5 mm with intrinsics).
"""

from __future__ import annotations

import argparse
import sys
import time

from keymps.eval.perception import flat_benchmark, photo_benchmark, table


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--boards", type=int, default=400, help="generated top-down boards")
    parser.add_argument("--photos", type=int, default=40, help="photos (each tall and flat)")
    parser.add_argument("--failures", action="store_true", help="list every failed case")
    parser.add_argument(
        "--quick", action="store_true", help="20 boards and 1 photo: checks the script runs (CI)"
    )
    args = parser.parse_args()
    if args.quick:
        args.boards, args.photos = 20, 1
    started = time.perf_counter()
    flat = flat_benchmark(args.boards)
    photos = photo_benchmark(args.photos)
    print(table(flat, photos))
    print(
        f"\n{args.boards} boards, {2 * args.photos} photos in {time.perf_counter() - started:.0f} s"
    )
    board, tall = flat["board"], photos["board+intrinsics"]
    if args.failures:
        for name, tallies in {**flat, **photos}.items():
            for what, tally in tallies.items():
                for failure in tally.failures:
                    print(f"{name} {what}: {failure}")
    met = (
        board["found"].rate == 1.0
        and board["refused"].rate == 1.0
        and tall["tall"].rate == 1.0
        and tall["flat"].rate == 1.0
    )
    print("targets met" if met else "targets NOT met")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
