"""The plugin manager: built-ins, fixture-registered plugins and real entry-point packages."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from keymps.errors import KeympsError
from keymps.plugin.hookspecs import hookimpl
from keymps.plugin.manager import DEFAULT_PLUGINS, build_manager, components, plugin_infos

BUILT_IN_COMPONENTS = {
    "detector": {"board", "threshold"},
    "vlm_backend": {"offline", "litellm", "replay"},
    "executor": {"sim", "file"},
    "image_source": {"file", "synthetic", "opencv"},
}


@pytest.mark.parametrize("kind", sorted(BUILT_IN_COMPONENTS))
def test_built_in_components_are_registered_through_the_manager(kind: str) -> None:
    assert BUILT_IN_COMPONENTS[kind] <= set(components(kind, build_manager()))


def test_every_built_in_plugin_loads_without_warnings(recwarn: pytest.WarningsRecorder) -> None:
    manager = build_manager()
    assert {name for name, _ in manager.list_name_plugin()} >= set(DEFAULT_PLUGINS)
    assert not [w for w in recwarn if "failed to load" in str(w.message)]


class _EchoDetector:
    def __init__(self, options: dict) -> None:
        self.options = options


class _FixturePlugin:
    @hookimpl
    def register_detectors(self, register):
        register("echo", _EchoDetector)

    @hookimpl
    def register_executors(self, register):
        register("echo-executor", _EchoDetector)

    @hookimpl
    def register_image_sources(self, register):
        register("echo-source", _EchoDetector)

    @hookimpl
    def register_vlm_backends(self, register):
        register("echo-backend", _EchoDetector)


def test_fixture_registered_plugin_provides_every_kind(keymps_plugins) -> None:
    keymps_plugins.register(_FixturePlugin(), name="fixture-plugin")
    detector = keymps_plugins.create("detector", "echo", {"threshold": 7})
    assert isinstance(detector, _EchoDetector) and detector.options == {"threshold": 7}
    assert "echo-executor" in keymps_plugins.names("executor")
    assert "echo-source" in keymps_plugins.names("image_source")
    assert "echo-backend" in keymps_plugins.names("vlm_backend")
    info = next(i for i in plugin_infos(keymps_plugins.manager) if i.name == "fixture-plugin")
    assert "detector echo" in info.provides


def test_unknown_component_lists_the_available_ones(keymps_plugins) -> None:
    with pytest.raises(KeympsError, match=r"unknown detector 'nope' \(available: .*threshold"):
        keymps_plugins.create("detector", "nope")


def _keymps(*args: str, env_extra: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, **(env_extra or {})}
    return subprocess.run(
        [sys.executable, "-c", "from keymps.cli import main; main()", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


@pytest.fixture(scope="module")
def installed_plugin_packages(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Tiny plugin distributions really installed with pip into a target folder: one that
    works, one broken on import, and two with a stranger's mistakes."""
    root = tmp_path_factory.mktemp("plugin-packages")
    target = root / "site"
    for dist, module, body in [
        (
            "keymps-hello",
            "keymps_hello",
            """
            from keymps.plugin.hookspecs import hookimpl

            class HelloExecutor:
                def __init__(self, options):
                    self.options = options

            @hookimpl
            def register_executors(register):
                register("hello", HelloExecutor)
            """,
        ),
        (
            "keymps-broken",
            "keymps_broken",
            "raise RuntimeError('this plugin is broken on purpose')",
        ),
        (
            "keymps-mischief",
            "keymps_mischief",
            """
            from keymps.plugin.hookspecs import hookimpl

            print("mischief loaded")  # on stdout, as it is imported

            class Replacement:
                def __init__(self, options):
                    self.options = options

            @hookimpl
            def register_executors(register):
                register("sim", Replacement)

            @hookimpl
            def register_executor(register):  # a typo: the hook is register_executors
                register("never", Replacement)
            """,
        ),
        (
            "keymps-wrongargs",
            "keymps_wrongargs",
            """
            from keymps.plugin.hookspecs import hookimpl

            @hookimpl
            def register_detectors(register):
                register("half-registered", object)

            @hookimpl
            def keymps_stage_done(stage, result, run, extra):
                pass
            """,
        ),
    ]:
        source = root / dist
        (source / module).mkdir(parents=True)
        (source / module / "__init__.py").write_text(textwrap.dedent(body))
        (source / "pyproject.toml").write_text(
            textwrap.dedent(
                f"""
                [build-system]
                requires = ["setuptools"]
                build-backend = "setuptools.build_meta"
                [project]
                name = "{dist}"
                version = "0.3.1"
                [project.entry-points.keymps]
                {module} = "{module}"
                """
            )
        )
        subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "install",
                "--quiet",
                "--no-deps",
                "--no-index",
                "--no-build-isolation",
                "--target",
                str(target),
                str(source),
            ],
            check=True,
            capture_output=True,
            timeout=300,
        )
    return target


def test_entry_point_plugin_is_listed_and_a_broken_one_only_warns(
    installed_plugin_packages: Path,
) -> None:
    result = _keymps("plugins", "--json", env_extra={"PYTHONPATH": str(installed_plugin_packages)})
    assert result.returncode == 0, result.stderr
    listed = {item["name"]: item for item in json.loads(result.stdout)}
    assert listed["keymps_hello"]["distribution"] == "keymps-hello"
    assert listed["keymps_hello"]["version"] == "0.3.1"
    assert listed["keymps_hello"]["provides"] == ["executor hello"]
    assert "threshold_detector" in listed
    # listed with its error, providing nothing
    assert listed["keymps_broken"]["provides"] == []
    assert listed["keymps_broken"]["error"] == "RuntimeError: this plugin is broken on purpose"
    warning = [line for line in result.stderr.splitlines() if "keymps_broken" in line]
    assert warning == [
        "warning: keymps: plugin 'keymps_broken' failed to load and was skipped: "
        "RuntimeError: this plugin is broken on purpose"
    ]
    assert "Traceback" not in result.stderr


def test_a_strangers_plugin_mistakes_are_named_not_silent(installed_plugin_packages: Path) -> None:
    """A plugin printing as it loads, a misspelled hook, a component named as a built-in one,
    a hook with an argument keymps does not pass: each said once, in one line."""
    check = (
        "import warnings; warnings.simplefilter('always')\n"
        "from keymps.plugin.manager import components\n"
        "print(components('executor')['sim'].__name__)\n"
        "print('half-registered' in components('detector'))\n"
    )
    env = {"PYTHONPATH": str(installed_plugin_packages)}
    listing = _keymps("plugins", "--json", env_extra=env)
    assert listing.returncode == 0, listing.stderr
    listed = {item["name"]: item for item in json.loads(listing.stdout)}  # the print on stderr
    assert "mischief loaded" in listing.stderr
    assert [item["name"] for item in json.loads(listing.stdout)].count("keymps_wrongargs") == 1
    assert listed["keymps_wrongargs"]["provides"] == []
    assert "PluginValidationError" in listed["keymps_wrongargs"]["error"]
    assert (
        "warning: keymps: plugin 'keymps_mischief' implements 'register_executor', which is no "
        "keymps hook (did you mean 'register_executors'?): it is never called"
    ) in listing.stderr.splitlines()
    done = subprocess.run(
        [sys.executable, "-c", check],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split()[-2:] == ["Replacement", "False"]  # the plugin's sim is used
    replaced = (
        "executor 'sim' of plugin 'keymps_mischief' replaces the one of plugin 'sim_executor'"
    )
    assert sum(replaced in line for line in done.stderr.splitlines()) == 1


def test_load_plugins_env_selects_packages(installed_plugin_packages: Path) -> None:
    result = _keymps(
        "plugins",
        "--json",
        env_extra={
            "PYTHONPATH": str(installed_plugin_packages),
            "KEYMPS_LOAD_PLUGINS": "keymps-hello, threshold_detector",
        },
    )
    assert result.returncode == 0, result.stderr
    assert sorted(item["name"] for item in json.loads(result.stdout)) == [
        "keymps_hello",
        "threshold_detector",
    ]
    assert "keymps_broken" not in result.stderr


def test_trace_plugins_prints_each_hook_call() -> None:
    result = _keymps("plugins", env_extra={"KEYMPS_TRACE_PLUGINS": "1", "KEYMPS_LOAD_PLUGINS": ""})
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""  # no plugin loaded, the listing calls no hook
    manager_env = {"KEYMPS_TRACE_PLUGINS": "1", "KEYMPS_LOAD_PLUGINS": "threshold_detector"}
    code = "from keymps.plugin.manager import components; print(sorted(components('detector')))"
    traced = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**os.environ, **manager_env},
        timeout=60,
    )
    assert traced.stdout.strip() == "['threshold']"
    assert "keymps: hook register_detectors() -> 1 plugin(s)" in traced.stderr


def _distribution(folder: Path, name: str, entry_points: str) -> None:
    """An installed distribution as pip leaves one: a dist-info folder with entry points."""
    info = folder / f"{name}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))


def test_pydantic_is_spared_its_plugin_scan_only_when_no_distribution_has_a_plugin(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from keymps.plugin.manager import skip_pydantic_plugin_scan

    monkeypatch.delenv("PYDANTIC_DISABLE_PLUGINS", raising=False)
    assert skip_pydantic_plugin_scan()
    assert os.environ["PYDANTIC_DISABLE_PLUGINS"] == "__all__"

    monkeypatch.setenv("PYDANTIC_DISABLE_PLUGINS", "my_plugin")  # the user's own choice wins
    assert not skip_pydantic_plugin_scan()
    assert os.environ["PYDANTIC_DISABLE_PLUGINS"] == "my_plugin"

    monkeypatch.delenv("PYDANTIC_DISABLE_PLUGINS")
    _distribution(tmp_path, "pydantic_logging", "[pydantic]\nlog = pydantic_logging:plugin\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert not skip_pydantic_plugin_scan()
    assert "PYDANTIC_DISABLE_PLUGINS" not in os.environ
    build_manager()  # uses up the read


def test_the_entry_points_read_ahead_serve_one_manager_and_a_later_one_reads_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from keymps.plugin.manager import skip_pydantic_plugin_scan

    monkeypatch.delenv("PYDANTIC_DISABLE_PLUGINS", raising=False)
    skip_pydantic_plugin_scan()
    _distribution(tmp_path, "keymps_late", "[keymps]\nlate = keymps_late_plugin\n")
    (tmp_path / "keymps_late_plugin.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert not build_manager().has_plugin("late")  # installed after the read it was given
    assert build_manager().has_plugin("late")


# -- a broken plugin is one warning naming it, in every command --

REPO = Path(__file__).resolve().parents[2]
BROKEN = {
    "register raises": "@hookimpl\ndef register_detectors(register):\n    raise RuntimeError('x')\n",
    "register exits": "@hookimpl\ndef register_executors(register):\n    raise SystemExit(4)\n",
    "exit at import": "raise SystemExit(3)\n",
    "own Ctrl-C at import": "raise KeyboardInterrupt\n",
    "name no string": "@hookimpl\ndef register_detectors(register):\n    register(42, dict)\n",
    "factory no callable": "@hookimpl\ndef register_executors(register):\n    register('e', 7)\n",
    "observer exits": "@hookimpl\ndef keymps_stage_done(stage, result, run):\n    raise SystemExit(5)\n",
}


def _entry_point_plugin(site: Path, code: str) -> dict[str, str]:
    """A plugin distribution `evil-plugin` (entry point `evil`) on PYTHONPATH: a module and a
    .dist-info folder, as pip would leave them."""
    (site / "evil_plugin.py").write_text("from keymps.plugin import hookimpl\n" + code)
    info = site / "evil_plugin-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: evil-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[keymps]\nevil = evil_plugin\n")
    return {"PYTHONPATH": str(site)}


@pytest.mark.parametrize("warnings_as_errors", [False, True], ids=["", "PYTHONWARNINGS=error"])
@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_plugin_is_one_warning_in_plugins_validate_and_run(
    case: str, warnings_as_errors: bool, tmp_path: Path
) -> None:
    """Was: tracebacks (a raising or SystemExit hook, a non-string name, PYTHONWARNINGS=error),
    or a silent exit 3, 4, 5 or 130 naming no plugin."""
    env = _entry_point_plugin(tmp_path, BROKEN[case])
    if warnings_as_errors:
        env["PYTHONWARNINGS"] = "error"
    task = str(REPO / "tasks/object_cutting.yaml")
    out = str(tmp_path / "run")
    for command in (
        ["plugins"],
        ["validate", task],
        ["run", task, "--backend", "offline", "--rerun", "off", "--out", out],
    ):
        done = _keymps(*command, env_extra=env)
        said = [line for line in done.stderr.splitlines() if "'evil'" in line]
        assert done.returncode == 0, (command, done.stderr[-2000:])
        assert "Traceback" not in done.stderr, done.stderr[-3000:]
        if command[0] == "run" and case == "observer exits":
            assert said == [  # once, at the first stage: it is not called again
                "warning: keymps: plugin 'evil' failed in keymps_stage_done(stage='image') and "
                "was unregistered: SystemExit: 5"
            ], done.stderr
        elif case != "observer exits":
            assert len(said) == 1 and said[0].startswith("warning: keymps: plugin 'evil' fail")
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["status"] == "ok"


def test_a_factory_that_raises_is_one_line_naming_its_plugin(tmp_path: Path) -> None:
    """Was: a traceback in `keymps validate` for a task that uses the component."""
    env = _entry_point_plugin(
        tmp_path,
        "@hookimpl\ndef register_detectors(register):\n    register('evil', make)\n"
        "def make(options):\n    raise ZeroDivisionError('in the factory')\n",
    )
    task = tmp_path / "task.yaml"
    text = (REPO / "tasks/object_cutting.yaml").read_text()
    text = text.replace("scenes/pizza.png", str(REPO / "tasks/scenes/pizza.png"))
    text = text.replace("prompt: ../prompts/", f"prompt: {REPO}/prompts/")
    task.write_text(text.replace("detector: {name: board}", "detector: {name: evil}"))
    done = _keymps("validate", str(task), env_extra=env)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.stderr.splitlines() == [
        f"{task}:8:11: detector: detector 'evil' of plugin 'evil' could not be built: "
        "ZeroDivisionError: in the factory"
    ]


def test_a_ctrl_c_while_a_plugin_loads_stops_the_command_and_names_it(tmp_path: Path) -> None:
    """The user's Ctrl-C (a real SIGINT) during a plugin's import is no broken plugin."""
    env = _entry_point_plugin(
        tmp_path, "import os, signal, time\nos.kill(os.getpid(), signal.SIGINT)\ntime.sleep(5)\n"
    )
    done = _keymps("plugins", env_extra=env)
    assert done.returncode == 130, done.stderr
    assert done.stderr.splitlines() == [
        "warning: keymps: interrupted while plugin 'evil' was loading",
        "error: interrupted (Ctrl-C)",
    ]
