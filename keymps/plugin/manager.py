"""The plugin manager: built-in plugins and entry-point plugins, loaded the same way."""

from __future__ import annotations

import importlib
import os
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import pluggy

from keymps.errors import KeympsError
from keymps.plugin import hookspecs

ENTRY_POINT_GROUP = "keymps"

DEFAULT_PLUGINS: dict[str, str] = {
    "board_detector": "keymps.default_plugins.board_detector",
    "threshold_detector": "keymps.default_plugins.threshold_detector",
    "offline_backend": "keymps.default_plugins.offline",
    "litellm_backend": "keymps.default_plugins.litellm",
    "replay_backend": "keymps.default_plugins.replay_backend",
    "image_sources": "keymps.default_plugins.image_sources",
    "sim_executor": "keymps.default_plugins.sim.executor",
    "file_executor": "keymps.default_plugins.file_executor",
    "urscript_executor": "keymps.default_plugins.urscript",
    "rerun_recorder": "keymps.default_plugins.rerun.recorder",
}
"""Built-in plugin name -> module. KEYMPS_LOAD_PLUGINS can name these too."""

COMPONENT_HOOKS: dict[str, str] = {
    "detector": "register_detectors",
    "vlm_backend": "register_vlm_backends",
    "executor": "register_executors",
    "image_source": "register_image_sources",
}


class PluginLoadWarning(UserWarning):
    """A plugin failed to load; the rest of keymps keeps working."""


@dataclass(frozen=True)
class PluginInfo:
    """One plugin as `keymps plugins` lists it."""

    name: str
    provides: tuple[str, ...]
    """e.g. ("detector threshold", "observer")."""
    distribution: str
    version: str
    hooks: tuple[str, ...]
    error: str | None = None
    """Why the plugin failed to load (it provides nothing then); None when it loaded."""


def _selected(name: str, dist: metadata.Distribution | None) -> bool:
    allowed = os.environ.get("KEYMPS_LOAD_PLUGINS")
    if allowed is None:
        return True
    wanted = {item.strip() for item in allowed.split(",") if item.strip()}
    return name in wanted or (dist is not None and dist.name in wanted)


def _trace_hook_calls(manager: pluggy.PluginManager) -> None:
    def before(hook_name: str, hook_impls: Sequence[Any], kwargs: Mapping[str, Any]) -> None:
        shown = {k: v for k, v in kwargs.items() if k != "register"}
        print(
            f"keymps: hook {hook_name}({', '.join(shown)}) -> {len(hook_impls)} plugin(s)",
            file=sys.stderr,
        )

    def after(
        outcome: Any, hook_name: str, hook_impls: Sequence[Any], kwargs: Mapping[str, Any]
    ) -> None:
        return None

    manager.add_hookcall_monitoring(before, after)


def _warn_broken(name: str, error: BaseException) -> str:
    """Warn about a plugin that failed to load; returns the error as one line."""
    detail = " ".join(f"{type(error).__name__}: {error}".split())
    message = f"keymps: plugin {name!r} failed to load and was skipped: {detail}"
    warnings.warn(message, PluginLoadWarning, stacklevel=3)
    return detail


class KeympsPluginManager(pluggy.PluginManager):
    """A pluggy manager that also remembers which distribution each plugin came from."""

    def __init__(self) -> None:
        super().__init__("keymps")
        self.sources: dict[str, metadata.Distribution] = {}
        """Plugin name -> the distribution of an entry-point plugin (its metadata file is read
        only when asked for: parsing it costs every command a few milliseconds)."""
        self.failures: dict[str, str] = {}
        """Plugin name -> the error that kept it from loading (`keymps plugins` lists them)."""

    @property
    def distributions(self) -> dict[str, tuple[str, str]]:
        """Plugin name -> (distribution name, version) for entry-point plugins."""
        return {name: (dist.name, dist.version) for name, dist in self.sources.items()}


def build_manager() -> KeympsPluginManager:
    """A fresh manager with the built-ins and every installed entry-point plugin."""
    manager = KeympsPluginManager()
    manager.add_hookspecs(hookspecs)
    for name, module_name in DEFAULT_PLUGINS.items():
        if not _selected(name, None):
            continue
        try:
            manager.register(importlib.import_module(module_name), name=name)
        except Exception as error:  # a broken plugin must not break unrelated commands
            _forget(manager, name)
            manager.failures[name] = _warn_broken(name, error)
    for entry_point in _keymps_entry_points():
        dist = entry_point.dist
        if not _selected(entry_point.name, dist) or manager.has_plugin(entry_point.name):
            continue
        if dist is not None:
            manager.sources[entry_point.name] = dist
        try:
            manager.register(entry_point.load(), name=entry_point.name)
        except Exception as error:
            _forget(manager, entry_point.name)
            manager.failures[entry_point.name] = _warn_broken(entry_point.name, error)
    _warn_unknown_hooks(manager)
    if os.environ.get("KEYMPS_TRACE_PLUGINS"):
        _trace_hook_calls(manager)
    return manager


def _forget(manager: KeympsPluginManager, name: str) -> None:
    """Unregister a plugin pluggy refused half-way (hooks before the bad one were added)."""
    if manager.has_plugin(name):
        manager.unregister(name=name)


def _warn_unknown_hooks(manager: KeympsPluginManager) -> None:
    """A @hookimpl whose name is no keymps hook (a typo: register_executor) is never called:
    say so instead of ignoring the plugin's work in silence."""
    for name, caller in vars(manager.hook).items():
        if getattr(caller, "spec", True) is not None:
            continue
        import difflib  # only for a plugin with a misspelled hook: not on every run's start

        known = [hook for hook in dir(hookspecs) if hook.startswith(("register_", "keymps_"))]
        close = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        for impl in caller.get_hookimpls():
            warnings.warn(
                f"keymps: plugin {impl.plugin_name!r} implements {name!r}, which is no keymps "
                f"hook{hint}: it is never called",
                PluginLoadWarning,
                stacklevel=3,
            )


PYDANTIC_PLUGIN_GROUP = "pydantic"

_read_ahead: dict[str, metadata.EntryPoints] | None = None


def _read_entry_points() -> dict[str, metadata.EntryPoints]:
    """keymps' and pydantic's entry points of every installed distribution, in one read (it
    opens every distribution's metadata: several milliseconds)."""
    everything = metadata.entry_points()
    return {
        group: everything.select(group=group)
        for group in (ENTRY_POINT_GROUP, PYDANTIC_PLUGIN_GROUP)
    }


def _keymps_entry_points() -> metadata.EntryPoints:
    """Read now, or the read `skip_pydantic_plugin_scan` made just before (used once: a manager
    built later reads again, and sees a plugin installed since)."""
    global _read_ahead
    found, _read_ahead = _read_ahead or _read_entry_points(), None
    return found[ENTRY_POINT_GROUP]


def skip_pydantic_plugin_scan() -> bool:
    """Spare pydantic its own read of every distribution's entry points when none declares a
    pydantic plugin: the documented PYDANTIC_DISABLE_PLUGINS, set to what pydantic would find
    (nothing). For the keymps command's own process, before its first pydantic model; a value
    the user exported wins. True when it was set."""
    global _read_ahead
    if "PYDANTIC_DISABLE_PLUGINS" in os.environ:
        return False
    _read_ahead = _read_entry_points()
    if _read_ahead[PYDANTIC_PLUGIN_GROUP]:
        return False
    os.environ["PYDANTIC_DISABLE_PLUGINS"] = "__all__"
    return True


_manager: pluggy.PluginManager | None = None


def get_manager() -> pluggy.PluginManager:
    """The process-wide manager, built on first use."""
    global _manager
    if _manager is None:
        _manager = build_manager()
    return _manager


def reset_manager() -> None:
    """Forget the process-wide manager (tests, or after installing a plugin)."""
    global _manager
    _manager = None


def components(
    kind: str, manager: pluggy.PluginManager | None = None
) -> dict[str, Callable[..., Any]]:
    """Every registered factory of one kind ('detector', 'vlm_backend', ...), by name."""
    manager = manager or get_manager()
    found: dict[str, Callable[..., Any]] = {}
    clashes: list[str] = []

    def register(name: str, factory: Callable[..., Any]) -> None:
        # pluggy calls the plugin registered last first: an installed plugin's component
        # replaces a built-in of the same name (what docs/plugins.md promises)
        if name in found and found[name] is not factory:
            clashes.append(name)
        found.setdefault(name, factory)

    hook = getattr(manager.hook, COMPONENT_HOOKS[kind])
    hook(register=register)
    if clashes:
        _warn_replaced(kind, clashes, hook)
    return found


def _warn_replaced(kind: str, names: list[str], hook: Any) -> None:
    """Say once which plugin's component replaces which (asking each plugin on its own)."""
    owners: dict[str, list[str]] = {}
    for impl in reversed(hook.get_hookimpls()):
        impl.function(
            register=lambda name, _factory, by=impl.plugin_name: owners.setdefault(name, []).append(
                by
            )
        )
    for name in names:
        used, *others = owners.get(name, ["?"])
        for other in others:
            if (kind, name, other) in _replaced or other == used:
                continue
            _replaced.add((kind, name, other))
            warnings.warn(
                f"keymps: {kind.replace('_', ' ')} {name!r} of plugin {used!r} replaces the one "
                f"of plugin {other!r}",
                PluginLoadWarning,
                stacklevel=3,
            )


_replaced: set[tuple[str, str, str]] = set()
"""The replacements already reported in this process."""


def create_component(
    kind: str,
    name: str,
    options: dict[str, Any] | None = None,
    manager: pluggy.PluginManager | None = None,
) -> Any:
    """Build the named component from its factory, or raise a KeympsError listing the choices."""
    factories = components(kind, manager)
    if name not in factories:
        choices = ", ".join(sorted(factories)) or "none installed"
        raise KeympsError(f"unknown {kind.replace('_', ' ')} {name!r} (available: {choices})")
    return factories[name](dict(options or {}))


def _registered_names(hook: Callable[..., None]) -> list[str]:
    names: list[str] = []
    hook(register=lambda name, factory: names.append(name))
    return names


def _provides(plugin: object) -> tuple[str, ...]:
    provided: list[str] = []
    for kind, hook_name in COMPONENT_HOOKS.items():
        hook = getattr(plugin, hook_name, None)
        if hook is None:
            continue
        names = _registered_names(hook)
        provided.extend(f"{kind.replace('_', ' ')} {name}" for name in names)
    if hasattr(plugin, "keymps_stage_done"):
        provided.append("stage observer")
    return tuple(provided)


def plugin_infos(manager: pluggy.PluginManager | None = None) -> list[PluginInfo]:
    """What `keymps plugins` shows: every plugin with what it provides and where it comes from."""
    from keymps._version import __version__

    manager = manager or get_manager()
    known = getattr(manager, "distributions", {})
    infos = []
    for name, plugin in manager.list_name_plugin():
        if plugin is None:
            continue
        hooks = tuple(sorted(h.name for h in manager.get_hookcallers(plugin) or []))
        if name in DEFAULT_PLUGINS:
            dist, version = "keymps", __version__
        else:
            dist, version = known.get(name, ("(registered in code)", ""))
        infos.append(PluginInfo(name, _provides(plugin), dist, version, hooks))
    for name, error in getattr(manager, "failures", {}).items():
        dist, version = known.get(
            name, ("keymps", __version__) if name in DEFAULT_PLUGINS else ("?", "")
        )
        infos.append(PluginInfo(name, (), dist, version, (), error))
    return infos
