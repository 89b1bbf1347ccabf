"""The design catalogue: a sentence read into an intent, an intent laid out as exact keypoint pairs
on a measured object (slices, grids, rings, spirals, stars, digits)."""
