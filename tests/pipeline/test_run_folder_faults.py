"""Faults of files and folders: decode bombs, unbounded numbers, full and read-only disks, bad
paths, Ctrl-C, two runs into one folder. Each ends in one clean line (or a correct run), with
nothing executed after an error, within seconds (docs/safety.md, Resource bounds).

The full disk is real where the test may mount one (root: a 64 kB ext2 image on a loop device,
else a 64 kB tmpfs); elsewhere the run is a child process under RLIMIT_FSIZE (writes fail with
EFBIG). Which one ran is in the fuzz summary ("disks/...").
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
import typing
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from helpers.budget import Budget
from helpers.fuzz_support import RecordingExecutor, assert_clean_error, install, task_copy

import keymps
from keymps.config import task as task_module
from keymps.errors import KeympsError, TaskFileError
from keymps.pipeline.folder_lock import FolderLock
from keymps.run import RunOptions, RunOverrides
from keymps.run_files import open_atomically, write_atomically

REPO = Path(__file__).resolve().parents[2]
KEYMPS = [sys.executable, "-c", "from keymps.cli.app import main; main()"]


# -- decode bombs: every format OpenCV reads is refused from its header, before allocation --

BOMB_READER = """
import json, sys
from pathlib import Path
import keymps  # sets OPENCV_IO_MAX_IMAGE_PIXELS before cv2 is imported
from keymps.errors import KeympsError
from keymps.perception.image_io import read_image
outcomes = {}
for name in sys.argv[2:]:
    for limit in (None, 64_000_000):  # OpenCV's decoder limit alone, then keymps' header check
        try:
            read_image(Path(sys.argv[1]) / name, limit)
            outcomes[f"{name} {limit}"] = "decoded"
        except KeympsError as error:
            outcomes[f"{name} {limit}"] = str(error)
status = Path("/proc/self/status").read_text()  # VmHWM: this process' peak (ru_maxrss is not
peak = int(status.split("VmHWM:")[1].split()[0]) / 1024  # reset by exec: it is the parent's)
print(json.dumps({"outcomes": outcomes, "peak_mb": peak}))
"""


@pytest.fixture(scope="module")
def bombs(tmp_path_factory: Any) -> Path:
    """Real files of 20000 x 12000 (WebP: 16000 x 16000) pixels, each a few MB at most."""
    folder = tmp_path_factory.mktemp("bombs")
    black = np.zeros((12000, 20000), np.uint8)
    for suffix in (".png", ".tiff", ".jpg"):
        assert cv2.imwrite(str(folder / f"big{suffix}"), black)
    jpeg = (folder / "big.jpg").read_bytes()
    comment = b"\xff\xfe" + (65000).to_bytes(2, "big") + b"x" * 64998  # COM segments first
    (folder / "late-frame.jpg").write_bytes(jpeg[:2] + comment * 2 + jpeg[2:])
    del black
    assert cv2.imwrite(str(folder / "big.webp"), np.zeros((16000, 16000), np.uint8))
    bmp = cv2.imencode(".bmp", np.zeros((1, 1), np.uint8))[1].tobytes()
    header = bytearray(bmp)
    header[18:26] = (20000).to_bytes(4, "little") + (12000).to_bytes(4, "little")
    (folder / "big.bmp").write_bytes(bytes(header))  # the header claims it; the data is missing
    (folder / "big.pgm").write_bytes(b"P5\n# a comment\n20000 12000\n255\n" + b"\x00" * 1024)
    return folder


def test_decode_bombs_are_refused_before_their_pixels_exist(bombs: Path, fuzz_counter: Any) -> None:
    names = sorted(p.name for p in bombs.iterdir())
    assert len(names) == 7
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", BOMB_READER, str(bombs), *names],
        capture_output=True,
        text=True,
        timeout=120,
        env={k: v for k, v in os.environ.items() if k != "OPENCV_IO_MAX_IMAGE_PIXELS"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(done.stdout)
    for case, outcome in report["outcomes"].items():
        assert outcome != "decoded", case
        assert "\n" not in outcome and outcome.startswith("image: "), outcome
        assert "pixels" in outcome or "cannot decode" in outcome, outcome
        fuzz_counter.add("images/decode bombs (decoder limit, header)", case, "refused")
    for name in names:  # keymps' own header reader names the size of each
        assert "pixels (" in report["outcomes"][f"{name} 64000000"], name
    # Before: 0.5 to 1.5 GB for these files (11.6-14 GB for 16-bit colour ones).
    assert report["peak_mb"] < 300, f"peak RSS {report['peak_mb']:.0f} MB"
    assert time.perf_counter() - started < 60


# -- every numeric task field has a physical bound --


def _numeric_fields(model: type, prefix: str = "") -> typing.Iterator[tuple[str, Any]]:
    """(field path, pydantic FieldInfo or its metadata) of every int/float in the task model."""
    from pydantic import BaseModel

    for name, info in model.model_fields.items():
        if name == "path":
            continue
        annotation = info.annotation
        nested = [a for a in _flatten(annotation) if isinstance(a, type)]
        models = [a for a in nested if issubclass(a, BaseModel)]
        for inner in models:
            if inner is not task_module.PluginSection:
                yield from _numeric_fields(inner, f"{prefix}{name}.")
        for leaf, metadata in _numbers(annotation, list(info.metadata)):
            yield f"{prefix}{name}{leaf}", metadata


def _flatten(annotation: Any) -> list[Any]:
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is typing.Annotated:
        return _flatten(args[0])
    return [annotation] if not args else [a for arg in args for a in _flatten(arg)]


def _numbers(annotation: Any, metadata: list[Any], leaf: str = "") -> list[tuple[str, list]]:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:  # a Field(...) inside carries its bounds as metadata
        extra = [m for arg in args[1:] for m in getattr(arg, "metadata", [arg])]
        return _numbers(args[0], metadata + extra, leaf)
    if annotation in (int, float):
        return [(leaf, metadata)]
    found = []
    for index, arg in enumerate(a for a in args if a is not type(None) and a is not Ellipsis):
        found += _numbers(arg, [] if origin is tuple else metadata, f"{leaf}[{index}]")
    return found


def test_every_numeric_task_field_has_a_lower_and_an_upper_bound() -> None:
    fields = dict(_numeric_fields(task_module.Task))
    assert "scene.workspace.shift[0]" in fields and "robot.max_tool_jerk" in fields
    assert len(fields) >= 25, sorted(fields)
    unbounded = []
    for name, metadata in fields.items():
        bounds = {k for m in metadata for k in ("ge", "gt", "le", "lt") if hasattr(m, k)}
        if not (bounds & {"ge", "gt"} and bounds & {"le", "lt"}):
            unbounded.append(name)
    assert not unbounded, f"numeric task fields without a physical bound: {unbounded}"


def test_a_huge_shift_is_refused_where_it_is_written(tmp_path: Path) -> None:
    """Was: 31 GiB allocated for the travel move before the path-length check."""
    path = task_copy(tmp_path, **{"shift: [0.0, 0.0]": "shift: [1e7, 1e7]"})
    budget = Budget()
    with pytest.raises(TaskFileError) as caught:
        keymps.load_task(path)
    budget.check(2.0)
    assert "task.yaml:6:43: scene.workspace.shift[0]: " in str(caught.value)
    assert "less than or equal to 3" in str(caught.value)


# -- disks --


def _mount(kind: str, target: Path, image: Path) -> bool:
    """Mount a 64 kB filesystem of `kind` at `target`; False where this is not allowed."""
    if not sys.platform.startswith("linux") or os.geteuid() != 0:
        return False
    target.mkdir(parents=True, exist_ok=True)
    if kind == "ext2":
        if not shutil.which("mkfs.ext2"):
            return False
        with image.open("wb") as handle:
            handle.truncate(64 * 1024)
        made = subprocess.run(
            ["mkfs.ext2", "-F", "-q", "-N", "32", str(image)], capture_output=True
        )
        command = ["mount", "-o", "loop", str(image), str(target)]
        if made.returncode != 0:
            return False
    else:
        options = "size=64k" + (",ro" if kind == "read-only tmpfs" else "")
        command = ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(target)]
    return subprocess.run(command, capture_output=True, timeout=30).returncode == 0


@pytest.fixture
def full_disk(tmp_path: Path, fuzz_counter: Any) -> typing.Iterator[tuple[str, Path]]:
    """(kind, folder) of a tiny filesystem; kind 'rlimit' where none could be mounted."""
    target = tmp_path / "disk"
    for kind in ("ext2", "tmpfs"):
        if _mount(kind, target, tmp_path / "disk.img"):
            try:
                yield kind, target
            finally:
                subprocess.run(["umount", "-l", str(target)], capture_output=True, timeout=30)
            return
    target.mkdir(exist_ok=True)
    yield "rlimit", target


def _run_cli(
    args: list[str], fsize: int | None = None, **popen: Any
) -> subprocess.CompletedProcess:
    def limit() -> None:  # a child whose files cannot grow past `fsize` bytes
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of being killed
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(
        [*KEYMPS, *args],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=limit if fsize else None,
        **popen,
    )


def _one_error_line(stderr: str) -> str:
    assert "Traceback" not in stderr, stderr[-3000:]
    errors = [line for line in stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, stderr[-3000:]
    return errors[0]


def test_a_full_disk_ends_in_one_line_and_a_whole_run_json(
    full_disk: tuple[str, Path], fuzz_counter: Any
) -> None:
    """Was: 5 of 7 runs hung in the Rerun sink, the others a traceback and a 0-byte run.json."""
    kind, disk = full_disk
    outcomes = []
    for attempt in range(3):
        out = disk / f"run{attempt}"
        started = time.perf_counter()
        done = _run_cli(
            ["run", str(REPO / "tasks/cake_icing.yaml"), "--backend", "offline", "--out", str(out)],
            fsize=65536 if kind == "rlimit" else None,
        )
        assert time.perf_counter() - started < 60, "a full disk must not hang the run"
        assert done.returncode == 1, done.stderr[-2000:]
        line = _one_error_line(done.stderr)
        assert str(out) in line, line
        assert "No space left on device" in line or "File too large" in line, line
        data = json.loads((out / "run.json").read_text())  # written whole, always
        assert data["status"] == "failed" and data["execution"] is None
        assert not [p for p in out.glob(".*.tmp")], "a temporary file was left behind"
        outcomes.append(line)
        fuzz_counter.add(f"disks/full ({kind})", (attempt, line), "refused")
        shutil.rmtree(out, ignore_errors=True)
    assert len(outcomes) == 3


@pytest.mark.parametrize("size", ["16k", "64k"])
def test_a_tiny_disk_still_gets_a_whole_run_json(
    size: str, tmp_path: Path, fuzz_counter: Any
) -> None:
    """A 16 kB or 64 kB tmpfs used to leave no run.json (the images and the recording filled
    it first); the placeholder written before the first stage holds the record's space."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = sys.platform.startswith("linux") and os.geteuid() == 0
    command = ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(disk)]
    if not mounted or subprocess.run(command, capture_output=True, timeout=30).returncode:
        pytest.skip("mounting a tmpfs needs root on Linux")
    try:
        out = disk / "run"
        done = _run_cli(
            ["run", str(REPO / "tasks/object_cutting.yaml"), "--backend", "offline"]
            + ["--out", str(out)]
        )
        assert done.returncode == 1, done.stderr[-2000:]
        line = _one_error_line(done.stderr)
        assert "No space left on device" in line, line
        record = json.loads((out / "run.json").read_text())
        assert record["status"] == "failed" and record["error"] == line.removeprefix("error: ")
        assert not [p for p in out.glob(".*.tmp")], "a temporary file was left behind"
        fuzz_counter.add("disks/tiny tmpfs", size, "short record" if "short" in record else "whole")
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True, timeout=30)


def test_a_run_json_folder_is_refused_before_the_first_stage(tmp_path: Path) -> None:
    """A folder named run.json inside --out let the whole run execute, then fail."""
    out = tmp_path / "run"
    (out / "run.json").mkdir(parents=True)
    done = _run_cli(
        ["run", str(REPO / "tasks/cake_icing.yaml"), "--backend", "offline", "--out", str(out)]
    )
    assert done.returncode == 1
    line = _one_error_line(done.stderr)
    assert f"{out / 'run.json'}: Is a directory" in line, line
    assert "load image" not in done.stderr  # not one stage ran
    assert sorted(p.name for p in out.iterdir() if p.name != ".keymps.lock") == ["run.json"]


@pytest.mark.parametrize("case", ["read-only", "name too long", "symlink loop", "loop below"])
def test_bad_run_folders_are_one_line(case: str, tmp_path: Path, fuzz_counter: Any) -> None:
    from click.testing import CliRunner

    from keymps.cli.app import cli

    if case == "read-only":
        out = tmp_path / "ro"
        if not _mount("read-only tmpfs", out, tmp_path / "unused"):
            pytest.skip("mounting a read-only filesystem needs root on Linux")
        expected = "Read-only file system"
    elif case == "name too long":
        out = tmp_path / ("x" * 300) / "run"
        expected = "File name too long"
    else:
        (tmp_path / "a").symlink_to(tmp_path / "b")
        (tmp_path / "b").symlink_to(tmp_path / "a")
        out = tmp_path / "a" if case == "symlink loop" else tmp_path / "a" / "run"
        expected = "leads nowhere" if case == "symlink loop" else "Too many levels"
    try:
        result = CliRunner().invoke(
            cli,
            ["run", str(task_copy(tmp_path / "task")), "--backend", "offline", "--out", str(out)],
        )
    finally:
        if case == "read-only":
            subprocess.run(["umount", "-l", str(out)], capture_output=True, timeout=30)
    assert result.exit_code == 1, result.output
    line = _one_error_line(result.output)
    assert expected in line and str(out) in line, line
    fuzz_counter.add("disks/bad run folders", case, "refused")


@pytest.mark.parametrize("case", ["/dev/zero", "folder", "name too long", "symlink loop"])
def test_bad_image_paths_say_what_they_are(case: str, tmp_path: Path) -> None:
    from click.testing import CliRunner

    from keymps.cli.app import cli

    expected = {
        "/dev/zero": "not a regular file (a device, a pipe or a socket): /dev/zero",
        "folder": "is a folder, not a file",
        "name too long": "File name too long",
        "symlink loop": "Too many levels of symbolic links",
    }[case]
    image = {"/dev/zero": Path("/dev/zero"), "folder": tmp_path}.get(case, tmp_path / ("y" * 300))
    if case == "symlink loop":
        image = tmp_path / "loop.png"
        image.symlink_to(image)
    result = CliRunner().invoke(cli, ["run", str(task_copy(tmp_path / "t")), "--image", str(image)])
    assert result.exit_code == 1
    line = _one_error_line(result.output)
    assert line.startswith("error: --image: ") and expected in line, line


def test_atomic_writes_keep_the_old_file_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "run.json"
    write_atomically(target, "old\n")
    with pytest.raises(RuntimeError), open_atomically(target) as handle:
        handle.write("half")
        raise RuntimeError("the disk filled up here")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.json"]
    write_atomically(target, b"new")
    assert target.read_bytes() == b"new"


# -- Ctrl-C --


def _interrupted_run(
    out: Path, after_line: str, delay_s: float = 0.0, signum: int = signal.SIGINT
) -> tuple[int, str]:
    """Start `keymps run`, send `signum` `delay_s` after stderr shows `after_line`; (exit code,
    stderr)."""
    process = subprocess.Popen(
        [*KEYMPS, "run", str(REPO / "tasks/object_cutting.yaml"), "--backend", "offline"]
        + ["--out", str(out)],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert process.stderr is not None
    seen = []
    deadline = time.monotonic() + 90
    for line in process.stderr:
        seen.append(line)
        if after_line in line:
            time.sleep(delay_s)
            process.send_signal(signum)
            break
        assert time.monotonic() < deadline
    rest = process.communicate(timeout=60)[1]
    return process.returncode, "".join(seen) + rest


RANDOM_DELAYS = [round(random.Random(seed).uniform(0.0, 2.5), 2) for seed in range(3)]
SIGNALS = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP"}


@pytest.mark.parametrize("signum", list(SIGNALS), ids=list(SIGNALS.values()))
@pytest.mark.parametrize(
    ("after", "delay_s"),
    [("load image", 0.0), ("inverse kinematics", 0.0)]
    + [("load image", delay) for delay in RANDOM_DELAYS],
)
def test_ctrl_c_sigterm_sighup_record_interrupted_and_exit_128_plus_the_signal(
    after: str, delay_s: float, signum: int, tmp_path: Path, fuzz_counter: Any
) -> None:
    """SIGTERM and SIGHUP killed the run at once (no run.json); now all three stop it alike."""
    name = SIGNALS[signum]
    code, stderr = _interrupted_run(tmp_path / "run", after, delay_s, signum)
    if code == 0:
        pytest.skip("the run finished before the interrupt arrived")
    assert code == 128 + signum, stderr[-2000:]
    assert _one_error_line(stderr) == f"error: interrupted ({name})"
    record = json.loads((tmp_path / "run" / "run.json").read_text())  # written, always
    if record["status"] == "ok":  # the run had ended; the summary was printing
        assert record["execution"]["ok"]
        fuzz_counter.add(f"interrupts/{name} in a run", (after, delay_s), "after run.json")
        return
    assert record["ok"] is False and record["status"] == "interrupted"
    by = "the user (Ctrl-C)" if name == "Ctrl-C" else name
    assert record["error"].startswith(f"interrupted by {by} ")
    if "after stage 'execute'" not in record["error"]:
        assert record["execution"] is None  # nothing executed after the interrupt
    where = record["error"].split(f"{by} ")[1].split(";")[0]
    fuzz_counter.add(f"interrupts/{name} in a run", (after, delay_s), where)


def test_a_second_ctrl_c_soon_after_the_first_waits_for_the_orderly_stop(tmp_path: Path) -> None:
    """A second Ctrl-C 50 ms after the first (while run.json is written, the recording closes)
    used to kill the process; it now waits for the first one's stop."""
    for attempt, after in enumerate(["load image", "inverse kinematics", "safety check"]):
        out = tmp_path / f"run{attempt}"
        process = subprocess.Popen(
            [*KEYMPS, "run", str(REPO / "tasks/object_cutting.yaml"), "--backend", "offline"]
            + ["--out", str(out)],
            stderr=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            text=True,
        )
        assert process.stderr is not None
        for line in process.stderr:
            if after in line:
                process.send_signal(signal.SIGINT)
                time.sleep(0.05)
                process.send_signal(signal.SIGINT)
                break
        stderr = process.communicate(timeout=60)[1]
        if process.returncode == 0:
            continue  # the run ended between the two lines
        assert process.returncode == 130, stderr[-2000:]
        assert _one_error_line(stderr) == "error: interrupted (Ctrl-C)"
        assert json.loads((out / "run.json").read_text())["status"] in ("interrupted", "ok")


# -- one run at a time in a run folder --


def test_a_second_run_into_a_locked_folder_refuses_at_once(
    keymps_plugins: Any, tmp_path: Path
) -> None:
    install(keymps_plugins)
    folder = tmp_path / "run"
    folder.mkdir()
    holder = subprocess.Popen(  # another process holds the folder, as a running run does
        [
            sys.executable,
            "-c",
            "import sys, time; from pathlib import Path; "
            "from keymps.pipeline.folder_lock import FolderLock; "
            f"lock = FolderLock(Path({str(folder)!r})).acquire(); print('held', flush=True); "
            "time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        started = time.perf_counter()
        with pytest.raises(KeympsError) as caught:
            keymps.run_task(
                task_copy(tmp_path / "task"),
                overrides=RunOverrides(backend="offline", executor="recording", out=folder),
            )
        assert time.perf_counter() - started < 5
        assert_clean_error(caught.value)
        assert f"run folder {folder} is in use by another keymps run (pid {holder.pid})" in str(
            caught.value
        )
        assert RecordingExecutor.calls == [] and not (folder / "run.json").exists()
    finally:
        holder.kill()
        holder.wait(timeout=10)
    run = keymps.run_task(
        task_copy(tmp_path / "task"),
        options=RunOptions(rerun="off"),
        overrides=RunOverrides(backend="offline", executor="recording", out=folder),
    )
    assert run.stages.execute is not None and json.loads((folder / "run.json").read_text())["ok"]


def test_the_lock_is_released_after_a_run(tmp_path: Path) -> None:
    lock = FolderLock(tmp_path).acquire()
    with pytest.raises(KeympsError, match="in use by another keymps run"):
        FolderLock(tmp_path).acquire()  # another open file: flock refuses it too
    lock.release()
    FolderLock(tmp_path).acquire().release()


@pytest.fixture
def python_ctrl_c() -> typing.Iterator[None]:
    """Python's own Ctrl-C handler for the test, whatever an earlier test left installed."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


class _CtrlCWhenFinishing:
    """An observer that presses Ctrl-C (SIGINT) when the run ends.

    raise_signal delivers SIGINT to this thread and Python runs the handler before the call
    returns: os.kill to the process let the kernel pick another thread (a busy machine then ran
    the handler after the observer had returned, and the test failed once under load)."""

    @keymps.hookimpl
    def keymps_stage_done(self, stage: str, result: Any, run: Any) -> None:
        if stage == "finished":
            signal.raise_signal(signal.SIGINT)
            raise AssertionError("SIGINT did not interrupt the observer")


def test_ctrl_c_while_the_run_closes_still_writes_run_json(
    keymps_plugins: Any, tmp_path: Path, python_ctrl_c: None
) -> None:
    """A Ctrl-C after the last stage (while the recording closes) skipped run.json."""
    install(keymps_plugins)
    keymps_plugins.register(_CtrlCWhenFinishing(), name="ctrl-c")
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        keymps.run_task(
            task_copy(tmp_path / "task"),
            overrides=RunOverrides(backend="offline", executor="recording", out=out),
        )
    record = json.loads((out / "run.json").read_text())
    assert record["status"] == "interrupted" and record["execution"]["ok"]
    assert "after stage 'execute'" in record["error"]
    assert len(RecordingExecutor.calls) == 1
    # the observers after the one pressing Ctrl-C still heard "finished": the recording closed
    assert (out / "run.rrd").is_file()
