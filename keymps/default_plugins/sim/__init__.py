"""The `sim` executor: a kinematic replay of the validated trajectory and its outcome image."""
