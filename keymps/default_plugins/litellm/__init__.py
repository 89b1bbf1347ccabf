"""The `litellm` planner backend and its retry policy."""
