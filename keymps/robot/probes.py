"""Joint configurations spread over a robot's range, for checking one kinematics against another.

A low-discrepancy (Kronecker) sequence rather than random draws: as spread out, reproducible
without a seed, and without importing numpy.random (6 ms) on every run.
"""

from __future__ import annotations

import math

import numpy as np


def probe_configurations(count: int, joints: int) -> np.ndarray:
    """(count, joints) angles in [-pi, pi): the first `count` points of the R_d sequence."""
    # R_d (Roberts 2018): steps 1/phi_d**(j + 1), phi_d the root of x**(d + 1) = x + 1.
    phi = 2.0
    for _ in range(30):
        phi = (1.0 + phi) ** (1.0 / (joints + 1))
    steps = np.array([phi ** -(j + 1) for j in range(joints)])
    unit = (0.5 + np.arange(1, count + 1)[:, None] * steps[None, :]) % 1.0
    return (unit * 2.0 - 1.0) * math.pi
