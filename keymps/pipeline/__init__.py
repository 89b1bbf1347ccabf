"""The engine that runs a task stage by stage, the run folder it writes, plan.png, `keymps validate`."""
