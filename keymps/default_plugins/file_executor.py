"""The `file` executor: writes the validated trajectory as CSV and as a ROS JointTrajectory JSON."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from keymps.plugin import RegisterExecutor, hookimpl, parse_options, require_validated
from keymps.run import EARLIER_RUN_FILES
from keymps.types import ExecutionReport, ValidatedTrajectory

if TYPE_CHECKING:
    from keymps.run import Run


class FileOptions(BaseModel):
    """The executor section of a task file for `file` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, populate_by_name=True)

    csv: Path | None = Path("trajectory.csv")
    """A file in the run folder (subfolders allowed); null skips the file."""
    json_path: Path | None = Field(Path("trajectory.json"), alias="json")
    """The task file's `json` key: the ROS JointTrajectory file."""

    @field_validator("csv", "json_path")
    @classmethod
    def _a_file_of_its_own(cls, path: Path | None, info: ValidationInfo) -> Path | None:
        # A task file may come from a stranger: it writes nothing outside the run folder, and
        # overwrites none of the run's own files there (run.json, plan.png, the lock ...).
        if path is None:
            return path
        if path.is_absolute() or ".." in path.parts or not path.name:
            raise ValueError(
                f"{str(path)!r} leads out of the run folder: name a file in it "
                "(--out chooses the folder)"
            )
        problem = run_file_clash(path, own=DEFAULT_NAMES[info.field_name or ""])
        other = info.data.get("csv") if info.field_name == "json_path" else None
        if problem is None and other is not None and _same_file(path, other):
            problem = f"{str(path)!r} is the csv file too: name two files"
        if problem:
            raise ValueError(problem)
        return path


DEFAULT_NAMES = {"csv": "trajectory.csv", "json_path": "trajectory.json"}
"""Each option's default: the one run file it may name (the run writes the same CSV itself)."""
RUN_FILES = frozenset({"run.json", ".keymps.lock", *EARLIER_RUN_FILES})
"""The files a run and the bundled plugins write in its folder (docs/run-folder.md)."""


def run_file_clash(path: Path, own: str) -> str | None:
    """Why an executor option may not name `path` in the run folder (None when it may): a
    control character in it, one of the run's own files or its vlm/ records, or a hidden name
    (the lock, the temporary files every file is written through). `own`: the run file the
    option is for."""
    text = str(path)
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        return f"{text!r} holds a control character (a NUL or a newline): name a plain file"
    if path.parts[0].casefold() == "vlm":
        return f"{text!r} is inside vlm/, the run's VLM records: name another file"
    if any(part.startswith(".") for part in path.parts):
        return f"{text!r} is a hidden name, as the run's lock and temporary files are"
    taken = {name.casefold() for name in RUN_FILES - {own}}
    if len(path.parts) == 1 and text.casefold() in taken:
        return f"{text!r} is one of the run's own files (docs/run-folder.md): name another file"
    return None


def _same_file(a: Path, b: Path) -> bool:
    return str(a).casefold() == str(b).casefold()  # a case-insensitive disk has one file


class FileExecutor:
    """Exports the trajectory; moves nothing."""

    name = "file"

    def __init__(self, options: FileOptions):
        self.options = options

    def execute(self, validated: ValidatedTrajectory, run: Run) -> ExecutionReport:
        from keymps.motion.trajectory_io import write_joint_trajectory_json, write_trajectory_csv

        trajectory = require_validated(validated, self.name)
        files = []
        if self.options.csv is not None:
            target = self._target(run, self.options.csv)
            if not self._written_by_run(validated, run, target):
                write_trajectory_csv(trajectory, target)
            files.append(target)
        if self.options.json_path is not None:
            files.append(
                write_joint_trajectory_json(trajectory, self._target(run, self.options.json_path))
            )
        names = ", ".join(str(f) for f in files) or "nothing (csv and json are both null)"
        return ExecutionReport(
            self.name,
            True,
            f"wrote {names}",
            tuple(str(f) for f in files),
            {"duration_s": trajectory.duration_s, "samples": float(trajectory.samples)},
        )

    @staticmethod
    def _target(run: Run, path: Path) -> Path:
        return run.path(str(path))

    @staticmethod
    def _written_by_run(validated: ValidatedTrajectory, run: Run, target: Path) -> bool:
        """The run folder's trajectory.csv of this very trajectory: a pipeline run writes it
        after the check, before any executor runs (docs/run-folder.md), so not twice."""
        return (
            run.stages.check is validated
            and target == run.folder / "trajectory.csv"
            and target.is_file()
        )


def make_file_executor(options: dict[str, Any]) -> FileExecutor:
    return FileExecutor(parse_options(FileOptions, options, "executor file"))


@hookimpl
def register_executors(register: RegisterExecutor) -> None:
    register("file", make_file_executor)
