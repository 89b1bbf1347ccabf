"""Supply chain: no known-malicious litellm, and a hash-pinned lock of everything CI installs.

litellm 1.82.7 and 1.82.8 on PyPI carried a credential stealer (BerriAI/litellm issues 24512
and 24521). requirements/lock.txt pins every package `.ci/run` installs, each with its sha256
hashes (docs/security.md, Supply chain).
"""

from __future__ import annotations

import os
import re
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

REPO = Path(__file__).resolve().parents[2]
KNOWN_BAD = {"litellm": {Version("1.82.7"), Version("1.82.8")}}
PLUGINS = ("keymps-ur-rtde", "keymps-mujoco", "keymps-ros")
PIN = re.compile(r"^([A-Za-z0-9_.\-]+)(?:\[([^\]]*)\])?==([^\s;\\]+)")


def _lock() -> dict[str, tuple[Version, int]]:
    """Package -> (pinned version, number of hashes) from requirements/lock.txt."""
    pins: dict[str, tuple[Version, int]] = {}
    current = None
    for line in (REPO / "requirements/lock.txt").read_text().splitlines():
        found = PIN.match(line)
        if found:
            current = canonicalize_name(found.group(1))
            pins[current] = (Version(found.group(3)), 0)
        elif current and line.strip().startswith("--hash=sha256:"):
            version, hashes = pins[current]
            pins[current] = (version, hashes + 1)
    return pins


def _locked_extras() -> dict[str, set[str]]:
    """Package -> the extras its pin names (``httpx[http2]==0.28.1`` -> {"http2"})."""
    extras: dict[str, set[str]] = {}
    for line in (REPO / "requirements/lock.txt").read_text().splitlines():
        found = PIN.match(line)
        if found:
            names = found.group(2) or ""
            extras[canonicalize_name(found.group(1))] = {
                canonicalize_name(extra) for extra in names.split(",") if extra.strip()
            }
    return extras


def _requirements(pyproject: Path, extras: tuple[str, ...] = ()) -> list[Requirement]:
    """The distribution's dependencies and those of `extras`, its own extras expanded (the
    test extra's `keymps[bench]` and `keymps[docs]` are their packages, not keymps)."""
    project = tomllib.loads(pyproject.read_text())["project"]
    names = list(project["dependencies"])
    wanted, seen = list(extras), set()
    while wanted:
        extra = wanted.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for text in project["optional-dependencies"][extra]:
            requirement = Requirement(text)
            if canonicalize_name(requirement.name) == canonicalize_name(project["name"]):
                wanted += sorted(requirement.extras)
            else:
                names.append(text)
    return [Requirement(name) for name in names]


def _ci_requirements() -> list[Requirement]:
    """What .ci/run installs: keymps with its test extra, the ur-rtde and MuJoCo plugins."""
    found = _requirements(REPO / "pyproject.toml", ("test",))
    for plugin in PLUGINS:
        found += _requirements(REPO / "plugins" / plugin / "pyproject.toml")
    return [r for r in found if canonicalize_name(r.name) not in ("keymps", *PLUGINS)]


def test_the_installed_litellm_is_not_a_known_bad_version() -> None:
    installed = Version(metadata.version("litellm"))
    assert installed not in KNOWN_BAD["litellm"], f"litellm {installed} carried a stealer"


def test_pyproject_refuses_the_bad_litellm_versions() -> None:
    (litellm,) = [r for r in _requirements(REPO / "pyproject.toml") if r.name == "litellm"]
    for bad in KNOWN_BAD["litellm"]:
        assert not litellm.specifier.contains(bad), f"{litellm} accepts {bad}"
    assert litellm.specifier.contains("1.82.9")


def test_the_lock_pins_every_package_ci_installs_with_hashes() -> None:
    pins = _lock()
    assert len(pins) > 50, "the lock covers the whole tree, not only the direct dependencies"
    for requirement in _ci_requirements():
        name = canonicalize_name(requirement.name)
        assert name in pins, f"{requirement} is not in requirements/lock.txt: regenerate it"
        version, hashes = pins[name]
        assert requirement.specifier.contains(version, prereleases=True), (requirement, version)
        assert hashes >= 1, f"{name} has no hash in the lock"
    for name, (version, hashes) in pins.items():
        assert hashes >= 1, f"{name}=={version} has no hash"
        assert version not in KNOWN_BAD.get(name, set()), f"the lock pins {name}=={version}"
    assert "mujoco" in pins  # the MuJoCo plugin's engine


def test_the_lock_pins_every_extra_a_locked_package_asks_for() -> None:
    """pip 23.2 in hash mode resolves `httpx[http2]` (asked for by litellm) on its own, takes the
    newest release from PyPI instead of the pin, and refuses the whole install as unpinned (seen
    the day httpx 0.29.0 came out): such a pin names its extras, `httpx[http2]==0.28.1`."""
    extras = _locked_extras()
    missing = []
    for name in extras:
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue  # not for this platform
        for text in requires:
            requirement = Requirement(text)
            wanted = canonicalize_name(requirement.name)
            if not requirement.extras or wanted not in extras:
                continue
            if requirement.marker and not requirement.marker.evaluate({"extra": ""}):
                continue  # only with an extra of `name` that CI does not install
            asked = {canonicalize_name(extra) for extra in requirement.extras}
            if not asked <= extras[wanted]:
                missing.append(f"{name} needs {requirement}")
    assert not missing, "write the extras into the lock's pin: " + "; ".join(missing)


def test_ci_installs_from_the_lock_with_hashes_required() -> None:
    script = (REPO / ".ci/run").read_text()
    assert "--require-hashes -r requirements/lock.txt" in script
    lines = [line for line in script.splitlines() if not line.startswith("#")]
    installs = [line for line in lines if "pip install" in line]
    assert all("--require-hashes" in line or "--no-deps" in line for line in installs), installs


@pytest.mark.skipif(
    os.environ.get("KEYMPS_LOCKED_INSTALL") != "1",
    reason="only an install from requirements/lock.txt (.ci/run sets KEYMPS_LOCKED_INSTALL=1) "
    "has the locked versions; the README's command installs the newest releases",
)
@pytest.mark.parametrize("name", ["litellm", "numpy", "opencv-python-headless", "rerun-sdk"])
def test_installed_direct_dependencies_are_the_locked_versions(name: str) -> None:
    """What CI tests against is what the lock pins: .ci/run installs from it and says so."""
    version, _ = _lock()[canonicalize_name(name)]
    assert Version(metadata.version(name)) == version, f"regenerate the lock or reinstall {name}"
