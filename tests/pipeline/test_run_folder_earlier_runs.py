"""An earlier run's files in a run folder: what its run.json lists, its default names and a
killed run's temporaries are removed before a new run's first stage; nothing outside the
folder, nothing through a link, nothing the record does not name (keymps.pipeline.run_folder).
The whole runs (an earlier rosbag run, then another executor) are in
plugins/keymps-ros/tests/test_rosbag.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from keymps.errors import KeympsError
from keymps.pipeline.run_folder import EARLIER_RUN_FILES, clear_earlier_run


def tree(folder: Path) -> list[str]:
    """Every path under `folder` (links not followed), relative, a folder's ending in /."""
    return sorted(
        p.relative_to(folder).as_posix() + ("/" if p.is_dir() and not p.is_symlink() else "")
        for p in folder.rglob("*")
    )


def write(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def record(folder: Path, **fields: object) -> None:
    write(folder / "run.json", json.dumps({"schema_version": "1.6", **fields}))


def test_what_the_record_lists_goes_and_nothing_outside_or_through_a_link(
    tmp_path: Path,
) -> None:
    folder, outside = tmp_path / "run", tmp_path / "outside"
    for name in ("kept.txt", "target/inner.txt", "linked/inner.txt"):
        write(outside / name)
    for name in ("a.csv", "exports/bag/x.mcap", "exports/bag/metadata.yaml", "deep/x/y.bin",
                 "deep/keep.txt", "notes.txt", "vlm/01-answer.json", ".hidden"):  # fmt: skip
        write(folder / name)
    (folder / "link").symlink_to(outside / "target")
    (folder / "linkdir").symlink_to(outside / "linked")
    write(folder / ".keymps.lock", "123")
    write(folder / ".run.json.4242-0a1b2c3d.tmp")  # a killed run's temporaries
    write(folder / ".trajectory_bag.4242-deadbeef.tmp/trajectory_bag/x.mcap")
    record(folder, files=["a.csv", "exports/bag/", "deep/x/y.bin", "link/inner.txt", "linkdir/",
                          "../outside/kept.txt", str(outside / "kept.txt"), ".", "./", "",
                          ".keymps.lock", "vlm/", "run.json", "missing.png", "gone/"])  # fmt: skip
    clear_earlier_run(folder)
    assert tree(folder) == [".hidden", ".keymps.lock", "deep/", "deep/keep.txt", "link",
                            "notes.txt", "vlm/"]  # fmt: skip
    assert tree(outside) == ["kept.txt", "linked/", "linked/inner.txt", "target/",
                             "target/inner.txt"]  # fmt: skip


def test_a_record_before_1_6_names_its_executors_files_by_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """run.json 1.5 had no `files`: its `execution.files` are paths as its run named them,
    relative to the working directory of the day (`--out run`) or absolute."""
    monkeypatch.chdir(tmp_path)
    folder = Path("run")
    for name in ("custom.json", "exports/bag/x.mcap", "trajectory_bag/x.mcap", "mine.txt"):
        write(folder / name)
    files = ["run/custom.json", str(tmp_path / "run/exports/bag"), "elsewhere/mine.txt"]
    write(folder / "run.json", json.dumps({"schema_version": "1.5", "execution": {"files": files}}))
    clear_earlier_run(folder)
    assert tree(folder) == ["mine.txt"]


@pytest.mark.parametrize(
    "text", ["{not json", "[1, 2]", '{"files": "a.csv"}', '{"status": "unfinished"}', "\xff"]
)
def test_a_record_without_a_list_of_files_leaves_the_default_names(
    tmp_path: Path, text: str
) -> None:
    """A killed run's placeholder (or a record written by hand) lists nothing: the names
    keymps and its bundled plugins write by default still go."""
    folder = tmp_path / "run"
    for name in EARLIER_RUN_FILES:
        write(folder / name.rstrip("/") / ("x.mcap" if name.endswith("/") else ""))
    write(folder / "a.csv")
    write(folder / "run.json", text)
    clear_earlier_run(folder)
    assert tree(folder) == ["a.csv"]


def test_a_listed_folder_that_cannot_be_removed_stops_with_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "run"
    write(folder / "plan.png")
    (folder / "plan.png").rename(folder / "saved")
    (folder / "plan.png").mkdir()  # a file the earlier run wrote is a folder now
    write(folder / "plan.png" / "mine.txt")
    record(folder, files=["plan.png"])
    with pytest.raises(KeympsError) as caught:
        clear_earlier_run(folder)
    assert (
        str(caught.value) == f"{folder}: cannot remove the earlier run's plan.png: Is a directory"
    )
    assert (folder / "run.json").exists() and (folder / "plan.png" / "mine.txt").exists()
