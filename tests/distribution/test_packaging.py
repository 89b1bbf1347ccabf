"""A plain (non-editable) install carries the primitive dictionary, the prompts and the suites.

The wheel is built from a copy of the repository and installed with --target into a temporary
folder; a fresh Python, started in an empty folder far from the checkout, then finds the bundled
files inside the installed package.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from keymps.bundled import SOURCE_FOLDERS

ROOT = Path(__file__).resolve().parents[2]


def _setuptools_config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_python_package_under_keymps_is_listed_in_pyproject() -> None:
    """pyproject.toml lists packages by hand (it maps the data folders): a new subpackage that
    is not listed would be missing from wheels."""
    listed = set(_setuptools_config()["packages"])
    found = {
        ".".join(init.parent.relative_to(ROOT).parts)
        for init in (ROOT / "keymps").rglob("__init__.py")
    }
    assert found <= listed, f"add to [tool.setuptools] packages: {sorted(found - listed)}"


def test_each_bundled_folder_is_mapped_into_the_package() -> None:
    mapped = _setuptools_config()["package-dir"]
    for name, folder in SOURCE_FOLDERS.items():
        assert mapped[f"keymps.bundled.{name}"] == folder
        assert (ROOT / folder).is_dir()


@pytest.fixture(scope="module")
def installed_keymps(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """keymps built as a wheel and installed, without dependencies, into a fresh folder."""
    work = tmp_path_factory.mktemp("wheel")
    source = work / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("keymps", *SOURCE_FOLDERS.values()):
        shutil.copytree(ROOT / folder, source / folder, ignore=ignore)
    target = work / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index"]
        + ["--no-build-isolation", "--target", str(target), str(source)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return target


def test_installed_package_finds_its_bundled_files(installed_keymps: Path, tmp_path: Path) -> None:
    probe = """
import json
from pathlib import Path
import keymps
from keymps.eval.suites import load_suite
from keymps.eval.vlm import PROMPTS_DIR
from keymps.primitives.dictionary import default_search_dirs, find_primitive_files
from keymps.planning.prompt import find_prompt
here = Path.cwd()
print(json.dumps({
    "package": keymps.__file__,
    "primitives": {k: str(v) for k, v in find_primitive_files(default_search_dirs(here)).items()},
    "prompt": str(find_prompt(None, here, "icing")),
    "methods": sorted(p.name for p in PROMPTS_DIR.glob("*.md")),
    "suite_cases": len(load_suite("cake_six").cases),
}))
"""
    environment = {**os.environ, "PYTHONPATH": str(installed_keymps)}
    environment.pop("KEYMPS_PRIMITIVES_PATH", None)
    environment.pop("KEYMPS_PROMPTS_PATH", None)
    result = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tmp_path,
        env=environment,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    package = installed_keymps / "keymps"
    assert Path(found["package"]).parent == package
    assert sorted(found["primitives"]) == ["downward", "forward", "line", "sawing", "straight"]
    for path in found["primitives"].values():
        assert Path(path).parent == package / "bundled" / "primitives"
    assert Path(found["prompt"]) == package / "bundled" / "prompts" / "icing.md"
    assert found["methods"] == sorted(p.name for p in (ROOT / "prompts" / "methods").glob("*.md"))
    assert found["suite_cases"] > 0
