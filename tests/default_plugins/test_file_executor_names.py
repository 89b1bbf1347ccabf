"""The `file` executor's files never overwrite the run's own (docs/security.md).

A shared task's `executor: {name: file, csv: ..., json: ...}` could name `plan.png`,
`run.json`, `.keymps.lock`, a file in `vlm/`, or the other option's file, and the run wrote the
trajectory over it; a name with a NUL passed `keymps validate`. Each is refused at its
file:line:col (the checks are keymps.plugin.RunFolderPath's: every plugin's file options have
them); generated names (the run's files in every case, in subfolders, with suffixes, hidden,
with control characters) are refused exactly when they clash, and a run with an accepted name
leaves every file of the run intact.
"""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from helpers.fuzz_support import task_copy

from keymps.cli.app import cli
from keymps.run import RunOptions, RunOverrides

RUN_FILES = ["run.json", ".keymps.lock", "run.rrd", "plan.png", "plan.jpg", "plan_photo.png"]
"""What every run writes itself, whichever executor runs (docs/run-folder.md)."""


def file_task(folder: Path, options: str) -> Path:
    return task_copy(folder, **{"executor: {name: sim}": f"executor: {{name: file, {options}}}"})


def validated(task: Path) -> list[str]:
    result = CliRunner().invoke(cli, ["validate", str(task)])
    return result.output.strip().splitlines()


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        ("csv: plan.png", "one of the run's own files"),
        ("csv: run.json", "one of the run's own files"),
        ("json: .keymps.lock", "hidden name"),
        ("json: trajectory.csv", "the run's own CSV"),
        ("csv: RUN.JSON", "one of the run's own files"),
        ("csv: vlm/crop.png", "inside vlm/"),
        ("csv: out.txt, json: out.txt", "is the csv file too"),
        ("csv: data.csv, json: DATA.csv", "is the csv file too"),
        ('csv: "a\\0b.csv"', "control character"),
        ('json: "x\\n.json"', "control character"),
    ],
)
def test_a_file_the_run_writes_itself_is_refused_at_its_line(
    options: str, expected: str, tmp_path: Path, fuzz_counter: Any
) -> None:
    task = file_task(tmp_path, options)
    lines = validated(task)
    assert len(lines) == 1 and f"{task}:" in lines[0] and expected in lines[0], lines
    assert "executor file: option " in lines[0]
    fuzz_counter.add("VLM attacks/file executor names", options, "located error")


def _name(rng: random.Random) -> tuple[str, bool]:
    """A generated csv name and whether it clashes with a file of the run."""
    kind = rng.choice(["run file", "case", "vlm", "hidden", "control", "subfolder", "plain"])
    base = rng.choice(RUN_FILES[2:])  # not hidden: those are their own kind
    if kind == "run file":
        return base, True
    if kind == "case":
        return "".join(c.upper() if rng.random() < 0.5 else c for c in base), True
    if kind == "vlm":
        return f"vlm/{rng.choice(['crop.png', 'x/y.csv', 'attempt-1.json'])}", True
    if kind == "hidden":
        return rng.choice([".keymps.lock", ".run.json.tmp", "out/.x.csv"]), True
    if kind == "control":
        return f"a{chr(rng.choice([0, 9, 10, 13, 27, 127]))}b.csv", True
    if kind == "subfolder":  # the run's names one folder down are other files
        return f"exports/{base}", False
    return f"{base}.csv", False


def test_generated_names_are_refused_exactly_when_they_clash(
    tmp_path: Path, fuzz_counter: Any
) -> None:
    from keymps.default_plugins.file_executor import FileOptions

    rng = random.Random(34)
    clashes = 0
    for case in range(400):
        name, clash = _name(rng)
        try:
            FileOptions.model_validate({"csv": name, "json": None})
            refused = False
        except ValueError:
            refused = True
        assert refused == clash, (case, name)
        clashes += clash
        fuzz_counter.add("VLM attacks/file executor names", name, "as expected")
    assert 100 < clashes < 350


def test_an_accepted_name_leaves_the_runs_files_intact(tmp_path: Path) -> None:
    import keymps

    task = file_task(tmp_path / "task", "csv: exports/plan.png, json: exports/run.json")
    run = keymps.run_task(
        task, options=RunOptions(rerun="off"), overrides=RunOverrides(out=tmp_path / "run")
    )
    record = json.loads((run.folder / "run.json").read_text())
    assert record["ok"] and (run.folder / "plan.png").read_bytes()[:4] == b"\x89PNG"
    assert (run.folder / "exports" / "plan.png").read_text().startswith("t,q1,")
    assert json.loads((run.folder / "exports" / "run.json").read_text())["joint_names"]
