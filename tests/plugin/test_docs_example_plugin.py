"""docs/plugins.md's plugin package, installed for real (pip, offline, into a folder), and its
test example run by pytest exactly as a plugin author would; a plugin that fails to load is
listed by `keymps plugins` with its error."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import keymps

DOCS = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"
BLOCK = re.compile(r"```(\w*)\n(.*?)```", re.DOTALL)


def blocks(language: str) -> list[str]:
    return [code for lang, code in BLOCK.findall(DOCS.read_text()) if lang == language]


def documented_package() -> tuple[str, str, str]:
    """pyproject.toml, the plugin module and the test example, as the page shows them."""
    (pyproject,) = blocks("toml")
    module = next(code for code in blocks("python") if code.startswith("# keymps_myplugin.py"))
    test = next(code for code in blocks("python") if "def test_" in code)
    return pyproject, module, test


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The documented package and a broken one, pip-installed into one folder (no network)."""
    root = tmp_path_factory.mktemp("plugins")
    pyproject, module, _ = documented_package()
    documented = root / "keymps-myplugin"
    documented.mkdir()
    (documented / "pyproject.toml").write_text(pyproject)
    (documented / "keymps_myplugin.py").write_text(module)
    broken = root / "keymps-broken"
    broken.mkdir()
    (broken / "pyproject.toml").write_text(
        '[project]\nname = "keymps-broken"\nversion = "0.2.0"\n\n'
        '[project.entry-points.keymps]\nbroken = "keymps_broken"\n'
    )
    (broken / "keymps_broken.py").write_text("import keymps_no_such_dependency\n")
    site = root / "site"
    command = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index"]
    command += ["--no-build-isolation", "--target", str(site), str(documented), str(broken)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (site / "keymps_myplugin.py").is_file()
    return site


def environment(site: Path) -> dict[str, str]:
    source = str(Path(keymps.__file__).resolve().parents[1])  # the keymps under test
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), source])}


def test_the_documented_package_installs_its_entry_point(installed: Path) -> None:
    (points,) = installed.glob("keymps_myplugin-0.1.0.dist-info/entry_points.txt")
    assert points.read_text().split() == ["[keymps]", "myplugin", "=", "keymps_myplugin"]


def test_the_documented_test_example_passes_for_the_installed_plugin(
    installed: Path, tmp_path: Path
) -> None:
    _, _, test = documented_package()
    (tmp_path / "test_example.py").write_text(test)
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_example.py"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=environment(installed),
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 passed" in done.stdout


def test_keymps_plugins_lists_the_plugin_that_failed_with_its_error(installed: Path) -> None:
    code = "from keymps.cli.app import main; main()"
    run = [sys.executable, "-c", code, "plugins"]
    env = environment(installed) | {"COLUMNS": "200"}
    table = subprocess.run(run, capture_output=True, text=True, env=env, timeout=60)
    assert table.returncode == 0, table.stderr
    row = next(line for line in table.stdout.splitlines() if " broken " in line)
    assert "failed to load" in row and "ModuleNotFoundError" in row
    assert "keymps-broken" in row and "0.2.0" in row
    assert any(
        " myplugin " in line and "executor print" in line for line in table.stdout.splitlines()
    )
    listed = subprocess.run([*run, "--json"], capture_output=True, text=True, env=env, timeout=60)
    entries = {entry["name"]: entry for entry in json.loads(listed.stdout)}
    assert "keymps_no_such_dependency" in entries["broken"]["error"]
    assert entries["broken"]["provides"] == []
    assert entries["myplugin"]["error"] is None
