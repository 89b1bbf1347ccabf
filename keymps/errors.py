"""Errors a user can act on: printed as one line, never with a traceback."""


class KeympsError(Exception):
    """A user-facing problem; str(error) is a complete, one-line message."""


class TaskFileError(KeympsError):
    """A task file (or an input it names) is invalid; one message per problem."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems))


class StageError(KeympsError):
    """A pipeline stage could not produce its result; nothing after it runs."""

    def __init__(self, stage: str, message: str):
        self.stage = stage
        super().__init__(f"{stage}: {message}")
