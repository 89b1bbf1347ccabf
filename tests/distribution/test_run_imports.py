"""What `keymps run` imports: nothing a run does not use (docs/performance.md, start-up).

Not a timed test: it lists the modules a whole offline run of the icing task has imported when
it exits, and fails on any that only other paths need (a VLM call, a viewer, MuJoCo, a real
robot, eval, scipy).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from keymps.errors import KeympsError
from keymps.plugin.manager import build_manager, components

REPO = Path(__file__).resolve().parents[2]

NOT_ON_THE_RUN_PATH = (
    "scipy",  # replaced by numpy on the run path (docs/performance.md, scipy on the run path)
    "litellm",
    "rerun",  # --rerun off
    "mujoco",
    "asyncio",  # the litellm backend's deadline; an offline run has no event loop
    "keymps.default_plugins.litellm.backend",
    "keymps.planning.warm.client",  # the warm planner is for VLM runs
    "keymps.planning.warm.wire",
    "keymps.planning.warm.server",
    "keymps_mujoco.executor",
    "keymps_mujoco.image_source",
    "keymps_ur_rtde.executor",
    "keymps_ros.rosbag",
    "keymps_ros.live",
    "rosbags",
    "roslibpy",
    "keymps.robot.identity",  # only exporters read it
    "keymps.eval",
    "keymps.scenes",  # a file scene renders nothing
    "email.parser",  # distribution metadata, read only by `keymps plugins`
    "rich",  # the progress lines are click.echo; rich draws `keymps plugins` and eval's bar
    "numpy.random",  # the kinematics self-checks use keymps.robot.probes
)

# main() leaves with os._exit after a clean run; it runs the atexit handlers first.
RUN_AND_LIST = """
import atexit, json, sys
atexit.register(lambda: print("MODULES " + json.dumps(sorted(sys.modules))))
sys.argv = ["keymps", *sys.argv[1:]]
from keymps.cli import main
main()
"""


@pytest.fixture(scope="module")
def run_modules(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """Every module an offline `keymps run` of the icing task had imported when it exited."""
    out = tmp_path_factory.mktemp("run-imports") / "run"
    task = REPO / "tasks" / "cake_icing.yaml"
    done = subprocess.run(
        [sys.executable, "-c", RUN_AND_LIST, "run", str(task), "--rerun", "off"]
        + ["--backend", "offline", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    line = next(s for s in done.stdout.splitlines() if s.startswith("MODULES "))
    modules: list[str] = json.loads(line.removeprefix("MODULES "))
    return modules


def test_the_run_imports_what_it_uses(run_modules: list[str]) -> None:
    # without these the run did not get as far as its stages, and the test below proves nothing
    for used in ("pinocchio", "cv2", "ruckig", "keymps.default_plugins.sim.executor"):
        assert used in run_modules, used


@pytest.mark.parametrize("module", NOT_ON_THE_RUN_PATH)
def test_the_run_does_not_import(module: str, run_modules: list[str]) -> None:
    imported = [m for m in run_modules if m == module or m.startswith(module + ".")]
    assert not imported, f"`keymps run --rerun off` imported {', '.join(imported)}"


def test_registered_factories_import_their_implementation_on_use() -> None:
    """The plugins' registration modules name factories that load the implementation."""
    manager = build_manager()
    executors = components("executor", manager)
    for name, implementation in (
        ("ur-rtde", "keymps_ur_rtde.executor"),
        ("mujoco", None),
        ("rosbag", "keymps_ros.rosbag"),
        ("ros2", "keymps_ros.live"),
    ):
        if name not in executors:
            continue  # that plugin package is not installed here
        with pytest.raises(KeympsError, match="no_such_option"):
            executors[name]({"no_such_option": 1})  # refused by the implementation's options
        if implementation:
            assert implementation in sys.modules
    backend = components("vlm_backend", manager)["litellm"]
    with pytest.raises(KeympsError, match="no_such_option"):
        backend({"no_such_option": 1})
