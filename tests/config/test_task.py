"""Task files: valid ones load; broken ones give one exact located line per problem."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from keymps.config.task import load_task, parse_task
from keymps.errors import TaskFileError

REPO = Path(__file__).resolve().parents[2]

VALID = """\
name: demo
instruction: Cut it into 8 equal slices
scene:
  image: scene.png
  workspace: {size: [0.30, 0.18], shift: [0.0, 0.0]}
  object_height: 0.02
primitives: [straight, sawing]
motion:
  work_speed: 0.02
"""


def _write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "scene.png").write_bytes(
        b"\x89PNG\r\n\x1a\n placeholder: only its signature is read"
    )
    path = tmp_path / "task.yaml"
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def _problems(tmp_path: Path, text: str) -> list[str]:
    path = _write(tmp_path, text)
    with pytest.raises(TaskFileError) as caught:
        load_task(path)
    return [line.replace(str(path), "task.yaml") for line in caught.value.problems]


def test_valid_task_loads_with_defaults_and_resolves_paths(tmp_path: Path) -> None:
    task = load_task(_write(tmp_path, VALID))
    assert task.name == "demo"
    assert task.scene.workspace.size == (0.30, 0.18)
    assert task.resolve(task.scene.image) == tmp_path / "scene.png"
    assert task.planner.backend == "auto"
    assert task.robot.tool.name == "knife"
    assert task.where("motion", "work_speed").endswith("task.yaml:9:15")


@pytest.mark.parametrize("shipped", sorted((REPO / "tasks").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_tasks_load(shipped: Path) -> None:
    task = load_task(shipped)
    assert task.instruction and task.primitives


BROKEN = [
    (
        "speed zero",
        VALID.replace("work_speed: 0.02", "work_speed: 0"),
        ["task.yaml:9:15: motion.work_speed: Input should be greater than 0"],
    ),
    (
        "unknown key points at the key",
        VALID.replace("  object_height: 0.02", "  objct_height: 0.02"),
        ["task.yaml:6:3: scene.objct_height: unknown key (did you mean 'object_height'?)"],
    ),
    (
        "missing instruction",
        VALID.replace("instruction: Cut it into 8 equal slices\n", ""),
        ["task.yaml:1:1: instruction: field required"],
    ),
    (
        "negative workspace size",
        VALID.replace("size: [0.30, 0.18]", "size: [0.30, -0.18]"),
        ["task.yaml:5:28: scene.workspace.size[1]: Input should be greater than 0"],
    ),
    (
        "workspace in millimetres",
        VALID.replace("size: [0.30, 0.18]", "size: [0.30, 180]"),
        [
            "task.yaml:5:28: scene.workspace.size[1]: Input should be less than or equal to 3 "
            "(the unit is metres)"
        ],
    ),
    (
        "robot base in millimetres",
        VALID + "robot: {base: [150, -200, 0, 90]}\n",
        [
            "task.yaml:10:16: robot.base[0]: Input should be less than or equal to 3 (the unit is "
            "metres)",
            "task.yaml:10:21: robot.base[1]: Input should be greater than or equal to -3 (the unit "
            "is metres)",
        ],
    ),
    (
        "NaN height",
        VALID.replace("object_height: 0.02", "object_height: .nan"),
        ["task.yaml:6:18: scene.object_height: Input should be a finite number"],
    ),
    (
        "two problems, two lines",
        VALID.replace("work_speed: 0.02", "work_speed: fast").replace(
            "primitives: [straight, sawing]", "primitives: []"
        ),
        [
            "task.yaml:7:13: primitives: List should have at least 1 item after validation, not 0",
            "task.yaml:9:15: motion.work_speed: Input should be a valid number, "
            "unable to parse string as a number",
        ],
    ),
    (
        "height mode",
        VALID + "height: {mode: middle}\n",
        ["task.yaml:10:16: height.mode: Input should be 'both', 'start' or 'end'"],
    ),
    (
        "missing image file",
        VALID.replace("image: scene.png", "image: nowhere.png"),
        ["task.yaml:4:10: scene.image: file not found: {folder}/nowhere.png"],
    ),
    (
        "an image file that is no image (a text file named as the scene)",
        VALID.replace("image: scene.png", "image: task.yaml"),
        [
            "task.yaml:4:10: scene.image: not an image file (no PNG, JPEG, TIFF, BMP, WebP ... "
            "signature in its first bytes): task.yaml"
        ],
    ),
    (
        "YAML syntax",
        VALID.replace("primitives: [straight, sawing]", "primitives: [straight, sawing"),
        ["task.yaml:8:7: invalid YAML: expected ',' or ']', but got ':'"],
    ),
    (
        "not a mapping",
        "- just\n- a list\n",
        ["task.yaml:1:1: (task): expected a mapping of task fields"],
    ),
    (
        "duplicate key",
        VALID + "name: again\n",
        ["task.yaml:10:1: invalid YAML: duplicate key 'name'"],
    ),
    (
        "control characters in the instruction",
        VALID.replace("Cut it into 8 equal slices", '"Cut\\x07 it"'),
        [
            "task.yaml:2:14: instruction: instruction contains control characters (a line break, "
            "a tab ...): write it on one line (YAML's folded style, `instruction: >`, joins lines "
            "with spaces)"
        ],
    ),
    (
        "a misspelled key gets the nearest one (margn)",
        VALID + "height: {mode: both, margn: 0.005}\n",
        ["task.yaml:10:22: height.margn: unknown key (did you mean 'margin'?)"],
    ),
    (
        "a misspelled top-level key",
        VALID.replace("primitives:", "primitvs:"),
        [
            "task.yaml:1:1: primitives: field required",
            "task.yaml:7:1: primitvs: unknown key (did you mean 'primitives'?)",
        ],
    ),
    (
        "an unknown key like no other gets no guess",
        VALID + "motion_blur: 3\n",
        ["task.yaml:10:1: motion_blur: unknown key"],
    ),
    (
        "an object height in millimetres names the unit",
        VALID.replace("object_height: 0.02", "object_height: 60"),
        [
            "task.yaml:6:18: scene.object_height: Input should be less than or equal to 1 (the unit is metres)"
        ],
    ),
    (
        "a speed in millimetres per second names the unit",
        VALID.replace("work_speed: 0.02", "work_speed: 20"),
        [
            "task.yaml:9:15: motion.work_speed: Input should be less than or equal to 0.5 (the unit "
            "is metres per second)"
        ],
    ),
    (
        "a line break in the instruction (the docs forbid control characters)",
        VALID.replace("Cut it into 8 equal slices", '"Cut it into\\n8 equal slices"'),
        [
            "task.yaml:2:14: instruction: instruction contains control characters (a line break, "
            "a tab ...): write it on one line (YAML's folded style, `instruction: >`, joins lines "
            "with spaces)"
        ],
    ),
    (
        "booleans where numbers go",
        VALID.replace("object_height: 0.02", "object_height: true").replace(
            "work_speed: 0.02", "work_speed: 0.02\n  clearance: yes"
        )
        + "planner: {temperature: false}\n",
        [
            "task.yaml:6:18: scene.object_height: a number is needed here, not true",
            "task.yaml:10:14: motion.clearance: a number is needed here, not true",
            "task.yaml:11:24: planner.temperature: a number is needed here, not false",
        ],
    ),
    (
        "a server that is no URL",
        VALID + "planner: {api_base: localhost-8000}\n",
        [
            "task.yaml:10:21: planner.api_base: 'localhost-8000' is not an http(s) URL with a "
            "host (e.g. http://127.0.0.1:8000/v1)"
        ],
    ),
    (
        "a name leading the run folder out of runs/",
        VALID.replace("name: demo", "name: ../../../../tmp/escape"),
        [
            "task.yaml:1:7: name: the name starts the run folder's name (runs/<name>-<time>): "
            "no '/', '\\' or control characters, and no '.' first"
        ],
    ),
    (
        "a hidden run folder's name",
        VALID.replace("name: demo", "name: .hidden"),
        [
            "task.yaml:1:7: name: the name starts the run folder's name (runs/<name>-<time>): "
            "no '/', '\\' or control characters, and no '.' first"
        ],
    ),
    (
        "tool with a short TCP",
        VALID + "robot: {tool: {name: spatula, tcp: [0, 0]}}\n",
        ["task.yaml:10:36: robot.tool.tcp[2]: field required"],
    ),
    (
        "knife blade longer than 40 cm",
        VALID + "robot: {tool: {name: knife, blade_length: 0.5}}\n",
        ["task.yaml:10:43: robot.tool.blade_length: Input should be less than or equal to 0.4"],
    ),
]


@pytest.mark.parametrize(("text", "expected"), [b[1:] for b in BROKEN], ids=[b[0] for b in BROKEN])
def test_broken_task_files_give_exact_located_lines(
    tmp_path: Path, text: str, expected: list[str]
) -> None:
    expected = [line.replace("{folder}", str(tmp_path.resolve())) for line in expected]
    assert _problems(tmp_path, text) == expected


def test_missing_task_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(TaskFileError) as caught:
        load_task(tmp_path / "absent.yaml")
    assert str(caught.value).endswith("absent.yaml: task file not found")


def test_parse_task_from_text_names_the_source() -> None:
    with pytest.raises(TaskFileError) as caught:
        parse_task("name: x\n", source="inline.yaml")
    assert all(line.startswith("inline.yaml:") for line in caught.value.problems)


def test_yaml_merge_keys_take_the_anchors_keys_unless_given(tmp_path: Path) -> None:
    """`<<: *defaults` was refused with PyYAML's 'could not determine a constructor'."""
    from keymps.config.yaml_positions import load_yaml_with_positions

    data = load_yaml_with_positions(
        "a: &a {x: 1, y: 2}\nb: &b {y: 3, z: 4}\nc: {<<: [*a, *b], z: 5}\nd: {<<: *b}\n"
    ).data
    assert data["c"] == {"x": 1, "y": 2, "z": 5}  # the first named wins, the mapping's own win
    assert data["d"] == {"y": 3, "z": 4}
    text = VALID.replace("motion:\n  work_speed: 0.02\n", "motion: &m\n  work_speed: 0.02\n")
    text += "robot: {<<: {max_joint_jerk: 50.0}, max_joint_acceleration: 2.0}\n"
    task = load_task(_write(tmp_path, text))
    assert task.robot.max_joint_jerk == 50.0 and task.robot.max_joint_acceleration == 2.0
    with pytest.raises(TaskFileError, match=r"task.yaml:10:13: invalid YAML: '<<' merges mappings"):
        load_task(_write(tmp_path, VALID + "robot: {<<: 3}\n"))
