"""The Rerun recorder: one recording per run, every stage logged (docs/rerun.md)."""
