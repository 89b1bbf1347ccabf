"""Grid cuts on a square cake follow the cake's measured orientation (issue 19 item 10): a cake
turned a few degrees used to get an image-aligned grid and pieces 5 % off an equal share."""

from __future__ import annotations

import random

import pytest
from helpers.synthetic_crops import make_scene, piece_areas, plan_for


@pytest.mark.parametrize("seed", range(24))
def test_a_turned_square_cake_is_cut_into_equal_pieces(seed: int) -> None:
    rng = random.Random(seed)
    side = rng.uniform(120, 200)
    sides = (side, side * rng.uniform(0.92, 1.0))  # square cakes are not perfect squares
    angle = rng.choice([-1, 1]) * rng.uniform(1.0, 40.0)
    parts = rng.choice([4, 6, 9])
    scene = make_scene("rect", sides, angle_deg=angle)
    plan, _ = plan_for(f"Cut the cake into {parts} equal parts", scene)
    areas = piece_areas(scene, plan)
    assert len(areas) == parts, (angle, parts, areas)
    share = sum(areas) / parts
    assert max(abs(a - share) / share for a in areas) < 0.03, (angle, parts, areas)


def test_an_aligned_square_cake_keeps_an_image_aligned_grid() -> None:
    scene = make_scene("rect", (180, 180))
    plan, _ = plan_for("Cut the cake into 4 equal parts", scene)
    for start, end in plan.pairs_px:
        assert abs(start[0] - end[0]) < 1e-6 or abs(start[1] - end[1]) < 1e-6
