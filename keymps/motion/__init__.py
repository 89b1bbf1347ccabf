"""From segments to a timed trajectory: the composed tool path (Eq. 6) and Ruckig timing."""
