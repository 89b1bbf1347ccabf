"""The plan stage: backend choice, prompts, answers, the planning session (repair, cache, cassettes)."""
