"""A third party's robot plugin, installed for real: a package with its own URDF and mesh in a
temporary folder, pip-installed (offline) into a folder, listed by `keymps plugins` and run end
to end (plan, IK, timing, safety, sim) in a fresh process, as its author would."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.box_arm import JOINTS, stl_box, urdf_text

import keymps

REPO = Path(__file__).resolve().parents[2]

PLUGIN = """
from pathlib import Path

from keymps.plugin import ArmSpec, RegisterRobot, hookimpl

HERE = Path(__file__).parent


def boxarm(options: dict) -> ArmSpec:
    return ArmSpec(
        name="boxarm",
        urdf=HERE / "urdf" / "boxarm.urdf",
        tip_link="tool0",
        acceleration_limits=(4.0,),
        jerk_limits=(80.0,),
        home=(0.0, 0.6, 1.2, 0.0, -0.25, 0.0),
        standoff=0.25,
        package_dirs=(HERE,),
        description="a box arm of six joints",
    )


@hookimpl
def register_robots(register: RegisterRobot) -> None:
    register("boxarm", boxarm)
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The package (module, URDF, mesh) pip-installed into a folder, without the network."""
    root = tmp_path_factory.mktemp("robot-plugin")
    source = root / "keymps-boxarm"
    package = source / "keymps_boxarm"
    (package / "urdf").mkdir(parents=True)
    (package / "meshes").mkdir()
    (package / "__init__.py").write_text(PLUGIN)
    (package / "urdf" / "boxarm.urdf").write_text(urdf_text())
    (package / "meshes" / "base.stl").write_bytes(stl_box(0.06))
    (source / "pyproject.toml").write_text(
        '[project]\nname = "keymps-boxarm"\nversion = "0.3.0"\ndependencies = ["keymps"]\n\n'
        '[project.entry-points.keymps]\nboxarm = "keymps_boxarm"\n\n'
        '[tool.setuptools.package-data]\nkeymps_boxarm = ["urdf/*.urdf", "meshes/*.stl"]\n'
    )
    site = root / "site"
    command = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index"]
    command += ["--no-build-isolation", "--target", str(site), str(source)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (site / "keymps_boxarm" / "urdf" / "boxarm.urdf").is_file()
    return site


def environment(site: Path) -> dict[str, str]:
    source = str(Path(keymps.__file__).resolve().parents[1])
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), source])}


def test_keymps_plugins_lists_the_installed_robot(installed: Path) -> None:
    run = [sys.executable, "-c", "from keymps.cli.app import main; main()", "plugins", "--json"]
    listed = subprocess.run(run, capture_output=True, text=True, env=environment(installed),
                            timeout=60)  # fmt: skip
    entries = {entry["name"]: entry for entry in json.loads(listed.stdout)}
    assert entries["boxarm"]["provides"] == ["robot boxarm"]
    assert entries["boxarm"]["distribution"] == "keymps-boxarm"
    assert "robot panda" in entries["robots"]["provides"]  # the built-ins, registered alike


RUN = """
import json, sys
import numpy as np
from keymps import RunOptions, RunOverrides, load_task, run_task

task = load_task(sys.argv[1])
robot = task.robot.model_copy(update={"model": "boxarm", "tool": task.robot.tool})
task = task.model_copy(update={"robot": robot})
run = run_task(
    task,
    options=RunOptions(rerun="off", quiet=True),
    overrides=RunOverrides(out=sys.argv[2], backend="offline", executor="sim"),
)
trajectory = run.stages.check.trajectory
positions, rotations = run.robot.tool_poses(np.asarray(trajectory.q))
print(json.dumps({
    "model": run.robot.model_name,
    "joints": list(run.robot.joint_names),
    "closed_form": run.robot.closed_form is not None,
    "ok": run.stages.execute.ok,
    "off_plan_mm": float(np.abs(positions - trajectory.tool_xyz).max() * 1000),
    "tilt": float(np.abs(rotations[:, 2, 2] + 1).max()),
    "figures": run.stages.check.report.figures,
}))
"""


def test_a_task_runs_end_to_end_on_the_installed_robot(installed: Path, tmp_path: Path) -> None:
    task = REPO / "tasks" / "cake_icing.yaml"
    done = subprocess.run(
        [sys.executable, "-c", RUN, str(task), str(tmp_path / "run")],
        capture_output=True,
        text=True,
        env=environment(installed),
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["model"] == "boxarm" and result["ok"]
    assert result["joints"] == JOINTS
    assert not result["closed_form"]  # solved by the iterative IK
    assert result["off_plan_mm"] < 0.5 and result["tilt"] < 1e-4
    figures = result["figures"]
    assert figures["min_arm_board_clearance_mm"] >= 10.0
    assert figures["max_joint_velocity_ratio"] <= 1.001
    csv = (tmp_path / "run" / "trajectory.csv").read_text().splitlines()[0]
    assert csv == "t,q1,q2,q3,q4,q5,q6,x,y,z,piece,kind"
