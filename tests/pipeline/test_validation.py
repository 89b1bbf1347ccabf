"""`keymps validate` reports every independent problem of a task file in one run, not in rounds
(schema, then files, then detector options, then executor options, then primitives)."""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import pytest

from keymps.pipeline.validation import validate_task_file

REPO = Path(__file__).resolve().parents[2]

GOOD = {
    "name": "name: mistakes",
    "instruction": "instruction: Put 15 icing dots around the cake",
    "image": "  image: scenes/round_cake.png",
    "height": "  object_height: 0.06",
    "detector": "detector: {name: threshold, min_area: 50}",
    "prompt": "  prompt: prompts/icing.md",
    "primitives": "primitives: [line]",
    "motion": "motion: {clearance: 0.03, work_speed: 0.03, travel_speed: 0.15}",
    "robot": "robot: {model: ur3, tool: piping_bag}",
    "executor": "executor: {name: file, csv: out.csv}",
    "extra": "",
}
"""One line per place a mistake can go; the task built from these is valid."""

MISTAKES = {
    "image": ("  image: scenes/no_such.png", "scene.image: file not found"),
    # a typo inside scene: must not hide scene.image's problem (it did)
    "height": ("  object_heigth: 0.06", "scene.object_heigth: unknown key"),
    "detector": ("detector: {name: threshold, min_area: -5}", "option 'min_area'"),
    "prompt": ("  prompt: prompts/nope.md", "planner.prompt: file not found"),
    "primitives": ("primitives: [line, zigzag]", "unknown primitive 'zigzag'"),
    "motion": (
        "motion: {clearance: 0.03, work_speed: -0.03, travel_speed: 0.15}",
        "motion.work_speed",
    ),
    "robot": ("robot: {model: ur3, tool: piping_bag, spin: 3}", "robot.spin: unknown key"),
    "executor": ("executor: {name: file, format: xml}", "option 'format': unknown option"),
    "extra": ("colour: blue", "colour: unknown key"),
    "instruction": ("instruction: ''", "instruction"),
}
"""A mistake per place, and what its problem line says."""


def task_text(lines: dict[str, str]) -> str:
    return "\n".join(
        [
            lines["name"],
            lines["instruction"],
            lines["extra"],
            "scene:",
            lines["image"],
            "  workspace: {size: [0.30, 0.18], shift: [0.0, 0.0]}",
            lines["height"],
            lines["detector"],
            "planner:",
            "  backend: offline",
            lines["prompt"],
            lines["primitives"],
            lines["motion"],
            lines["robot"],
            lines["executor"],
            "",
        ]
    )


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    here = tmp_path_factory.mktemp("validate")
    (here / "scenes").mkdir()
    (here / "prompts").mkdir()
    shutil.copy(REPO / "tasks" / "scenes" / "round_cake.png", here / "scenes")
    shutil.copy(REPO / "prompts" / "icing.md", here / "prompts")
    return here


def test_the_clean_file_is_valid(folder: Path) -> None:
    path = folder / "good.yaml"
    path.write_text(task_text(GOOD))
    assert validate_task_file(path) == []


def test_every_mistake_of_the_report_in_one_run(folder: Path) -> None:
    path = folder / "all.yaml"
    path.write_text(task_text(GOOD | {k: v for k, (v, _) in MISTAKES.items()}))
    problems = validate_task_file(path)
    for place, (_, expected) in MISTAKES.items():
        assert sum(expected in line for line in problems) == 1, (place, problems)
    assert len(problems) == len(MISTAKES), problems
    located = [int(line.split(":")[1]) for line in problems]
    assert located == sorted(located), "problems come in the order of the file"


@pytest.mark.parametrize("seed", range(30))
def test_any_set_of_independent_mistakes_is_reported_at_once(folder: Path, seed: int) -> None:
    rng = random.Random(seed)
    chosen = rng.sample(sorted(MISTAKES), rng.randint(1, len(MISTAKES)))
    path = folder / f"some-{seed}.yaml"
    path.write_text(task_text(GOOD | {k: MISTAKES[k][0] for k in chosen}))
    problems = validate_task_file(path)
    for place in chosen:
        assert any(MISTAKES[place][1] in line for line in problems), (place, problems)
    assert len(problems) == len(chosen), (chosen, problems)
    assert all(line.startswith(f"{path.name}:") or str(path) in line for line in problems)


def _height_task(folder: Path, name: str, robot: str, height: float, objects: str = "") -> Path:
    lines = dict(GOOD, robot=f"robot: {{model: {robot}, tool: piping_bag}}")
    lines["height"] = f"  object_height: {height}" + (f"\n  objects: {objects}" if objects else "")
    path = folder / f"{name}.yaml"
    path.write_text(task_text(lines))
    return path


def test_an_object_taller_than_the_arm_reaches_is_a_height_error(folder: Path) -> None:
    """Was: object_height: 0.6 passed validate and failed at solve as 'out of the UR3's reach'."""
    problems = validate_task_file(_height_task(folder, "tall", "ur3", 0.6))
    assert len(problems) == 1, problems
    assert (
        ":7:18: scene.object_height: 0.6 m: the UR3 cannot reach 0.630 m above the board"
        in (problems[0])
    )
    assert problems[0].endswith("the unit is metres, or move robot.base")
    per_object = validate_task_file(
        _height_task(folder, "tall-object", "ur3", 0.06, "[{name: cake, height: 0.7}]")
    )
    assert len(per_object) == 1 and "scene.objects[0].height: 0.7 m: the UR3" in per_object[0]


@pytest.mark.parametrize("robot", ["ur3", "ur5e", "panda"])
def test_the_height_limit_is_one_threshold_per_arm(robot: str, folder: Path) -> None:
    """Heights from 5 cm to 1 m: every one the arm can work at passes, and once a height is
    refused every taller one is too (the check is the arm's reach, not a fixed number)."""
    verdicts = []
    for index, height in enumerate([0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]):
        problems = validate_task_file(_height_task(folder, f"{robot}-{index}", robot, height))
        assert all("scene.object_height" in p for p in problems), problems
        verdicts.append(not problems)
    assert verdicts[0] and verdicts[1], verdicts  # the shipped tasks' heights work on every arm
    assert not verdicts[-1], verdicts
    first_refused = verdicts.index(False)
    assert not any(verdicts[first_refused:]), verdicts
