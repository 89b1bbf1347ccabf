"""The `file` executor: writes the validated trajectory as CSV and as a ROS JointTrajectory JSON."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from keymps.plugin import (
    RegisterExecutor,
    RunFolderPath,
    hookimpl,
    parse_options,
    require_validated,
)
from keymps.types import ExecutionReport, ValidatedTrajectory

if TYPE_CHECKING:
    from keymps.run import Run


class FileOptions(BaseModel):
    """The executor section of a task file for `file` (every key but `name`)."""

    model_config = ConfigDict(defer_build=True, extra="forbid", frozen=True, populate_by_name=True)

    csv: RunFolderPath | None = Path("trajectory.csv")
    """A file in the run folder (subfolders allowed); null skips the file."""
    json_path: RunFolderPath | None = Field(Path("trajectory.json"), alias="json")
    """The task file's `json` key: the ROS JointTrajectory file."""

    @field_validator("json_path")
    @classmethod
    def _not_the_csv(cls, path: Path | None, info: ValidationInfo) -> Path | None:
        # RunFolderPath keeps the run's own files out; these two are this executor's
        if path is None:
            return path
        if str(path).casefold() == "trajectory.csv":
            raise ValueError("'trajectory.csv' is the run's own CSV: name another file")
        csv = info.data.get("csv")
        if csv is not None and str(csv).casefold() == str(path).casefold():
            raise ValueError(f"{str(path)!r} is the csv file too: name two files")
        return path


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
