"""Predicting what a trajectory does to the object, the plan's intent, and the verdict.

cut_sweep: what a knife's edge covers; pieces: the pieces cut lines leave (Appendix F's
equal-parts test); predict: a timed trajectory's cuts, pieces and icing deposits; verdict: the
prediction held against the intent (docs/outcome.md).
"""
