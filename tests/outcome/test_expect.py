"""The task file's `expect:` block and `keymps run --accept-outcome`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from keymps.cli.app import cli
from keymps.config.task import load_task
from keymps.errors import TaskFileError

REPO = Path(__file__).resolve().parents[2]


def _task(tmp_path: Path, expect: str) -> Path:
    shipped = (REPO / "tasks" / "object_cutting.yaml").read_text()
    shipped = shipped.replace("scenes/pizza.png", str(REPO / "tasks" / "scenes" / "pizza.png"))
    shipped = shipped.replace("  prompt: ../prompts/cutting.md\n", "")  # the bundled one
    path = tmp_path / "task.yaml"
    path.write_text(f"{shipped}expect: {expect}\n")
    return path


@pytest.mark.parametrize(
    ("expect", "complaint"),
    [
        ("{equal: true}", "equal needs pieces"),
        ("{pieces: 0}", "pieces"),
        ("{pieces: 8, equal: 1.5}", "equal"),
        ("{pieces: 8, sharp: true}", "sharp"),
        ("{orientation: diagonal}", "orientation"),
        ("{slice_width: 20}", "slice_width"),
    ],
)
def test_a_wrong_expect_block_is_refused_at_its_place(tmp_path, expect, complaint):
    with pytest.raises(TaskFileError) as caught:
        load_task(_task(tmp_path, expect))
    line = str(caught.value)
    expect_line = _task(tmp_path, expect).read_text().splitlines().index(f"expect: {expect}") + 1
    assert f"task.yaml:{expect_line}:" in line and "expect" in line and complaint in line


def test_expect_is_checked_and_the_expert_may_run_anyway(tmp_path):
    """The sentence asks for 8 slices; `expect` asserts 7: refused with exit 1 and one line,
    executed with --accept-outcome (recorded)."""
    task = _task(tmp_path, "{pieces: 7, equal: true}")
    common = ["run", str(task), "--backend", "offline", "--rerun", "off", "-q"]
    refused = CliRunner().invoke(cli, [*common, "--out", str(tmp_path / "a")])
    assert refused.exit_code == 1
    error = [line for line in refused.stderr.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and error[0].startswith("error: outcome: the predicted outcome is")
    assert "the cuts leave 8 pieces" in error[0] and "the intent is 7 pieces" in error[0]
    accepted = CliRunner().invoke(cli, [*common, "--out", str(tmp_path / "b"), "--accept-outcome"])
    assert accepted.exit_code == 0, accepted.output
    record = json.loads((tmp_path / "b" / "run.json").read_text())
    assert record["ok"] and record["outcome"]["verdict"] == "accepted"
    assert record["outcome"]["accept_outcome"] is True
    assert record["outcome"]["intent"][0]["pieces"] == 7
    assert record["outcome"]["intent"][0]["source"] == "expect"
    right = _task(tmp_path, "{pieces: 8, equal: 0.05}")
    fine = CliRunner().invoke(cli, ["run", str(right), "--backend", "offline", "--rerun", "off",
                                    "-q", "--out", str(tmp_path / "c")])  # fmt: skip
    assert fine.exit_code == 0, fine.output
    assert json.loads((tmp_path / "c" / "run.json").read_text())["outcome"]["verdict"] == "pass"
