"""`keymps eval`: offline through the real pipeline, resuming, interruption, and every method
against a real local OpenAI-compatible server (127.0.0.1) answering with canned designs."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from typing import Any

import cv2
import pytest
from click.testing import CliRunner
from helpers.vlm_server import Recorded, VlmServer

from keymps.cli.app import cli
from keymps.eval.runner import read_results


def _eval(*args: str) -> Any:
    return CliRunner().invoke(cli, ["eval", *args, "--quiet"], catch_exceptions=False)


def _records(out: Path) -> list[dict[str, Any]]:
    return read_results(out / "results.jsonl")


@pytest.fixture(autouse=True)
def _isolated(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("KEYMPS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


@pytest.fixture(scope="module")
def offline_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Cases 5 and 7 of Table I (eggplant, 2 and 4 slices), keymps and vlm-keypoint, offline."""
    out = tmp_path_factory.mktemp("eval") / "offline"
    result = _eval(
        "cutting_sim", "--case", "5", "--case", "7", "--repeats", "1",
        "--method", "keymps", "--method", "vlm-keypoint", "--out", str(out),
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out


def test_offline_eval_scores_the_real_pipeline(offline_run: Path) -> None:
    records = _records(offline_run)
    assert {(r["case"], r["method"]) for r in records} == {
        ("5", "keymps"),
        ("5", "vlm-keypoint"),
        ("7", "keymps"),
        ("7", "vlm-keypoint"),
    }
    for record in records:
        assert record["ok"], record
        assert record["backend"] == "offline"
        assert record["keyword"] == record["truth_keyword"] == "straight"
        assert record["pieces"] == record["truth_pieces"]  # as many cuts as the ground truth
        # the offline planner places the slices within millimetres of the ground truth
        assert 0 < record["d_mm"] < 5
        assert record["d_optimal_mm"] <= record["d_mm"] + 1e-9
        run = offline_run / record["folder"]
        assert (run / "run.json").is_file()
        # JPEG images by default: a tenth of a PNG's size and time, for hundreds of runs
        assert record["images"]["plan"] == str((run / "plan.jpg").relative_to(offline_run))
        assert cv2.imread(str(run / "plan.jpg")).shape == (360, 600, 3)
        assert not list(run.glob("*.png"))


FORKING_EVAL = """
import multiprocessing, sys
real = multiprocessing.get_context
def spy(method=None):
    print("start method", method, file=sys.stderr, flush=True)
    return real(method)
multiprocessing.get_context = spy
import gc, os
real_fork = os.fork
def fork():  # the worker never scans (nor copies the pages of) what this process made
    print("frozen at fork", gc.get_freeze_count() > 10_000, file=sys.stderr, flush=True)
    return real_fork()
os.fork = fork
from keymps.cli.app import main
sys.argv = ["keymps", *sys.argv[1:]]
main()
"""


def test_a_worker_forked_from_the_eval_process_scores_the_same(
    offline_run: Path, tmp_path: Path
) -> None:
    """`keymps eval` alone in its process forks its offline worker from itself (no fork
    server); the records are the in-process run's, timings apart."""
    import os
    import subprocess
    import sys

    out = tmp_path / "forked"
    arguments = ["eval", "cutting_sim", "--case", "5", "--case", "7", "--repeats", "1"]
    arguments += ["--method", "keymps", "--method", "vlm-keypoint", "--processes", "2"]
    done = subprocess.run(
        [sys.executable, "-c", FORKING_EVAL, *arguments, "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=120, env={**os.environ},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "start method fork\n" in done.stderr
    assert "frozen at fork True\n" in done.stderr

    def timeless(records: list[dict[str, Any]]) -> dict[tuple[Any, ...], dict[str, Any]]:
        return {
            (r["case"], r["method"], r["repeat"]): {k: v for k, v in r.items() if k != "seconds"}
            for r in records
        }

    assert timeless(_records(out)) == timeless(_records(offline_run))


def test_eval_writes_png_images_when_asked(tmp_path: Path) -> None:
    out = tmp_path / "png"
    result = _eval(
        "cake_six", "--case", "round", "--repeats", "1", "--image-format", "png", "--out", str(out)
    )
    assert result.exit_code == 0, result.output
    (record,) = _records(out)
    plan = out / record["images"]["plan"]
    assert plan.name == "plan.png" and plan.read_bytes().startswith(b"\x89PNG")
    assert "plan.png" in (out / "gallery.html").read_text()


def test_an_eval_in_this_process_leaves_its_garbage_collector_as_it_was(
    offline_run: Path,
) -> None:
    import gc

    assert offline_run.is_dir()  # (an eval has run in this process)
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_offline_eval_writes_the_summary_files(offline_run: Path) -> None:
    summary = (offline_run / "summary.md").read_text()
    assert "| case | method | runs |" in summary
    assert re.search(r"\| 7 \| keymps \| 1 \| 1/1 \(100 %\) \| \d+\.\d \+- 0\.0 \|", summary)
    rows = list(csv.DictReader((offline_run / "summary.csv").open()))
    assert {(r["case"], r["method"]) for r in rows} == {
        ("5", "keymps"),
        ("5", "vlm-keypoint"),
        ("7", "keymps"),
        ("7", "vlm-keypoint"),
    }
    assert all(0 < float(r["d_mean_mm"]) < 5 for r in rows)
    gallery = (offline_run / "gallery.html").read_text()
    images = re.findall(r"src='([^']+)'", gallery)
    assert len(images) == 4 and all((offline_run / i).is_file() for i in images)
    assert (offline_run / "d_boxplot.png").stat().st_size > 1000
    task = offline_run / "tasks" / "keymps" / "7-r0.yaml"
    assert "source: synthetic" in task.read_text()  # a task file `keymps run` can replay


def test_vlm_keypoint_uses_straight_pieces(offline_run: Path) -> None:
    import numpy as np

    from keymps.primitives.dictionary import load_primitive

    zeroed = load_primitive(offline_run / "tasks" / "vlm-keypoint" / "primitives" / "sawing.yaml")
    assert not np.any(zeroed.dmp.weights)
    path = zeroed.rollout([0, 0, 0.05], [0.1, 0.0, 0.0]).y
    direction = np.array([0.1, 0.0, -0.05]) / np.linalg.norm([0.1, 0.0, -0.05])
    relative = path - [0, 0, 0.05]
    off_line = relative - np.outer(relative @ direction, direction)
    assert np.abs(off_line).max() < 1e-9  # a straight piece from start to goal


def test_rerunning_resumes_and_an_interrupted_line_is_redone(offline_run: Path) -> None:
    results = offline_run / "results.jsonl"
    lines = results.read_text().splitlines()
    before = len(lines)
    again = _eval(
        "cutting_sim", "--case", "5", "--case", "7", "--repeats", "1",
        "--method", "keymps", "--method", "vlm-keypoint", "--out", str(offline_run),
    )  # fmt: skip
    assert again.exit_code == 0, again.output
    assert len(results.read_text().splitlines()) == before  # nothing run twice
    # an interruption while writing the last record: that line is cut short
    cut = lines[-1][: len(lines[-1]) // 2]
    results.write_text("\n".join(lines[:-1]) + "\n" + cut)
    lost = json.loads(lines[-1])
    resumed = _eval(
        "cutting_sim", "--case", "5", "--case", "7", "--repeats", "1",
        "--method", "keymps", "--method", "vlm-keypoint", "--out", str(offline_run),
    )  # fmt: skip
    assert resumed.exit_code == 0, resumed.output
    records = _records(offline_run)
    assert len(records) == before  # the three finished ones kept, the cut one redone
    redone = [r for r in records if (r["case"], r["method"]) == (lost["case"], lost["method"])]
    assert len(redone) == 1 and redone[0]["ok"]


def test_vlm_methods_need_a_vlm_offline(tmp_path: Path) -> None:
    result = _eval("cutting_sim", "--method", "vlm-dmp", "--out", str(tmp_path / "x"))
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [result.output.strip().splitlines()[0]]  # one line
    assert "method vlm-dmp needs a VLM" in result.output and "--model" in result.output
    assert not (tmp_path / "x" / "results.jsonl").exists()


def test_bad_suite_and_case_are_one_line_errors(tmp_path: Path) -> None:
    missing = _eval(str(tmp_path / "nope.yaml"))
    assert missing.exit_code == 1 and "suite file not found" in missing.output
    case = _eval("cutting_sim", "--case", "99", "--out", str(tmp_path / "y"))
    assert case.exit_code == 1 and "no case '99'" in case.output
    assert "Traceback" not in missing.output + case.output


def test_cake_six_offline_reports_equal_parts(tmp_path: Path) -> None:
    out = tmp_path / "six"
    result = _eval("cake_six", "--repeats", "2", "--out", str(out), "--concurrency", "2")
    assert result.exit_code == 0, result.output
    records = _records(out)
    assert len(records) == 4
    for record in records:
        assert record["ok"], record
        assert isinstance(record["success"], bool)
        assert record["parts_detail"]
    assert "equal parts" in (out / "summary.md").read_text()


# --------------------------------------------------------------------------- against a VLM

BOARD = re.compile(
    r"x = (-?[\d.]+) to x = (-?[\d.]+).*?y = (-?[\d.]+) to\s+y = (-?[\d.]+)", re.DOTALL
)
CROP = re.compile(r"(\d+) x (\d+) pixels")
TOP = re.compile(r"object's top is (?:at\s+)?z = (\d+\.\d+)")


def _text(message: dict[str, Any]) -> str:
    content = message["content"]
    if isinstance(content, str):
        return content
    return " ".join(part.get("text", "") for part in content if part.get("type") == "text")


SEVENTHS = [k / 7 for k in range(1, 7)]


def _seventh_cuts(request: Recorded) -> str:
    """Canned designs for case 2 (a loaf in 7 slices), each method in its own answer format."""
    messages = request.body["messages"]
    system, user = _text(messages[0]), " ".join(_text(m) for m in messages[1:])
    if "cutting with one DMP" in system or "cutting with several DMPs" in system:
        x0, x1, y0, y1 = (float(v) for v in BOARD.search(system).groups())  # type: ignore[union-attr]
        top = float(TOP.search(system).group(1))  # type: ignore[union-attr]
        dmps = [
            {
                "start": [x0 + (x1 - x0) * f, y1, top],
                "goal": [x0 + (x1 - x0) * f, y0, 0.0],
                "weights": [[0.0, 0.0, 0.0]] * 5,
            }
            for f in SEVENTHS
        ]
        if "several DMPs" in system:
            return json.dumps({"dmps": dmps, "rationale": "six cuts"})
        return json.dumps({**dmps[0], "rationale": "one cut only"})
    if "cutting with 3D keypoints" in system:
        x0, x1, y0, y1 = (float(v) for v in BOARD.search(system).groups())  # type: ignore[union-attr]
        top = float(TOP.search(system).group(1))  # type: ignore[union-attr]
        pairs = [[[x0 + (x1 - x0) * f, y1, top], [x0 + (x1 - x0) * f, y0, 0.0]] for f in SEVENTHS]
        return json.dumps({"keyword": "straight", "pairs": pairs, "rationale": "3D"})
    schema = request.body["response_format"]["json_schema"]["schema"]["properties"]
    if "design" in schema and "pairs" not in schema:  # keymps-design: name it, keymps draws it
        design = dict.fromkeys(
            ("count", "layers", "slice_width_cm", "object_length_cm", "orientation", "text")
        )
        design.update(name="parallel", count=7, orientation="vertical")
        return json.dumps({"keyword": "straight", "design": design, "rationale": "sevenths"})
    width, height = (int(v) for v in CROP.search(system + " " + user).groups())  # type: ignore[union-attr]
    margin = 10  # the detector's crop padding: the loaf spans the rest
    inner = width - 2 * margin
    pairs = [
        [[margin + inner * f, margin], [margin + inner * f, height - margin]] for f in SEVENTHS
    ]
    # straight, not the ground truth's sawing: the sawing strokes reach past the loaf's ends
    return json.dumps({"keyword": "straight", "pairs": pairs, "rationale": "sevenths"})


@pytest.fixture(scope="module")
def vlm_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Recorded]]:
    out = tmp_path_factory.mktemp("eval") / "vlm"
    with VlmServer(responder=_seventh_cuts) as server:
        vlm = ("--model", "openai/test-vlm", "--api-base", server.openai_base, "--out", str(out))
        result = _eval(
            "cutting_sim", "--case", "2", "--repeats", "1", "--concurrency", "4",
            "--method", "keymps", "--method", "keymps-design", "--method", "keymps-text",
            "--method", "vlm-keyword",
            "--method", "vlm-dmp", "--method", "vlm-mdmp", *vlm,
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        # a method added to the same folder later: the finished runs are kept
        result = _eval(
            "cutting_sim", "--case", "2", "--repeats", "1", "--method", "vlm-keypoint", *vlm
        )
        assert result.exit_code == 0, result.output
        requests = list(server.chat_requests)
    return out, requests


def test_every_method_runs_against_a_vlm(vlm_run: tuple[Path, list[Recorded]]) -> None:
    out, requests = vlm_run
    records = _records(out)
    assert len(records) == 7  # 7 methods, one repeat
    # one call each, except that vlm-keypoint asks exactly what keymps asked (same scene, same
    # prompt): the planner's answer cache serves it
    cached = [r["method"] for r in records if r["cached"]]
    assert len(requests) == 6 and cached == ["vlm-keypoint"]
    by_method: dict[str, list[dict[str, Any]]] = {}
    for record in records:
        assert record["ok"], record
        assert record["backend"] == "litellm" and record["model"] == "openai/test-vlm"
        assert record["vlm_calls"] == 1
        assert (out / record["images"]["plan"]).is_file()  # every method draws its motion
        assert record["prompt_tokens"] == 321
        by_method.setdefault(record["method"], []).append(record)
    d = {m: max(r["d_mm"] for r in rs) for m, rs in by_method.items()}
    # the right 2D design through KeyMPs lands within millimetres (with the straight primitive,
    # not the ground truth's sawing strokes); one DMP for six cuts cannot
    assert d["keymps"] < 10 and d["keymps-text"] < 10 and d["keymps-design"] < 10
    assert d["vlm-dmp"] > 5 * d["keymps"]
    assert all(r["pieces"] == 6 for r in by_method["vlm-mdmp"])
    assert all(r["pieces"] == 1 for r in by_method["vlm-dmp"])


def test_keymps_text_never_sends_the_image(vlm_run: tuple[Path, list[Recorded]]) -> None:
    _, requests = vlm_run
    with_image = 0
    for request in requests:
        system = _text(request.body["messages"][0])
        has_image = "image_url" in json.dumps(request.body["messages"])
        if "robot food cutting (text only)" in system:
            assert not has_image
            assert "banana bread loaf" in system and "rectangular" in system
        else:
            assert has_image
            with_image += 1
    assert with_image == len(requests) - 1  # all but keymps-text


def test_a_method_that_fails_is_recorded_not_fatal(tmp_path: Path) -> None:
    def garbage_for_dmps(request: Recorded) -> str:
        system = _text(request.body["messages"][0])
        return "I would rather not." if "several DMPs" in system else _seventh_cuts(request)

    out = tmp_path / "fail"
    with VlmServer(responder=garbage_for_dmps) as server:
        result = _eval(
            "cutting_sim", "--case", "2", "--repeats", "1",
            "--method", "vlm-mdmp", "--method", "keymps",
            "--model", "openai/test-vlm", "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
    assert result.exit_code == 0, result.output
    records = {r["method"]: r for r in _records(out)}
    assert records["keymps"]["ok"]
    failed = records["vlm-mdmp"]
    assert not failed["ok"] and "no valid vlm-mdmp answer in 2 attempt(s)" in failed["error"]
    assert "\n" not in failed["error"]
    assert "no valid vlm-mdmp answer" in (out / "summary.md").read_text()


def test_no_cache_asks_the_vlm_for_every_run(tmp_path: Path) -> None:
    out = tmp_path / "fresh"
    with VlmServer(responder=_seventh_cuts) as server:
        result = _eval(
            "cutting_sim", "--case", "2", "--repeats", "1", "--no-cache",
            "--method", "keymps", "--method", "vlm-keypoint",
            "--model", "openai/test-vlm", "--api-base", server.openai_base, "--out", str(out),
        )  # fmt: skip
        requests = len(server.chat_requests)
    assert result.exit_code == 0, result.output
    records = _records(out)
    assert requests == 2 and [r["cached"] for r in records] == [0, 0]


def test_a_task_file_given_to_eval_and_a_suite_given_to_run_say_which_command_they_need() -> None:
    repo = Path(__file__).resolve().parents[2]
    task, suite = repo / "tasks/cake_icing.yaml", repo / "benchmarks/suites/cutting_sim.yaml"
    runner = CliRunner()
    done = runner.invoke(cli, ["eval", str(task)])
    assert done.exit_code == 1
    assert done.output.splitlines() == [
        f"error: {task}:1:1: a task file (it has an instruction and no cases), not an eval "
        f"suite: run it with `keymps run {task}`, or make it a case of a suite "
        "(docs/benchmarks.md)"
    ]
    for command in (["run", "--rerun", "off"], ["validate"]):
        done = runner.invoke(cli, [*command, str(suite)])
        assert done.exit_code == 1 and len(done.output.splitlines()) == 1, done.output
        assert (
            f"an eval suite (it lists cases), not a task file: run it with `keymps eval {suite}`"
            in (done.output)
        )


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--backend", "nope"], "--backend nope: unknown planner backend 'nope' (available: "),
        (["--api-base", "ftp://x"], "'ftp://x' is not an http(s) URL with a host"),
        (["--backend", "replay"], "--backend replay: keymps eval replays no cassette"),
    ],
)
def test_planner_options_no_run_could_use_stop_eval_before_its_first_run(
    arguments: list[str], message: str, tmp_path: Path
) -> None:
    """They once failed every run one by one, and eval exited 0."""
    out = tmp_path / "eval"
    result = CliRunner().invoke(cli, ["eval", "icing", *arguments, "--out", str(out), "--quiet"])
    assert result.exit_code == 1, result.output
    assert message in result.output and result.output.count("\n") == 1, result.output
    assert "--cassette" not in result.output  # a flag eval does not have
    assert not (out / "results.jsonl").exists() and not (out / "runs").exists()
