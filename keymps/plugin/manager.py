"""The plugin manager: built-in plugins and entry-point plugins, loaded the same way."""

from __future__ import annotations

import functools
import importlib
import inspect
import os
import sys
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import metadata
from typing import Any, cast

import pluggy

from keymps.errors import KeympsError
from keymps.interrupts import handling_signals, signals_received
from keymps.plugin import hookspecs
from keymps.plugin.components import (
    Arm,
    BackendAbilities,
    BackendBase,
    Detector,
    Executor,
    ImageSource,
    VlmBackend,
)

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
    "robots": "keymps.default_plugins.robots",
}
"""Built-in plugin name -> module. KEYMPS_LOAD_PLUGINS can name these too."""

COMPONENT_HOOKS: dict[str, str] = {
    "detector": "register_detectors",
    "vlm_backend": "register_vlm_backends",
    "executor": "register_executors",
    "image_source": "register_image_sources",
    "robot": "register_robots",
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


def _warn_plugin(message: str) -> None:
    """A warning about a plugin, a warning even under `-W error` / PYTHONWARNINGS=error: a
    broken plugin must not break unrelated commands ('ignore' still silences it)."""
    try:
        warnings.warn(message, PluginLoadWarning, stacklevel=4)
    except PluginLoadWarning:
        with warnings.catch_warnings():
            warnings.simplefilter("default", PluginLoadWarning)
            warnings.warn(message, PluginLoadWarning, stacklevel=4)


def _warn_broken(name: str, error: BaseException) -> str:
    """Warn about a plugin that failed to load; returns the error as one line."""
    detail = " ".join(f"{type(error).__name__}: {error}".split()) or type(error).__name__
    _warn_plugin(f"keymps: plugin {name!r} failed to load and was skipped: {detail}")
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
        if _selected(name, None):
            _load(manager, name, functools.partial(importlib.import_module, module_name))
    for entry_point in _keymps_entry_points():
        dist = entry_point.dist
        if not _selected(entry_point.name, dist) or manager.has_plugin(entry_point.name):
            continue
        if dist is not None:
            manager.sources[entry_point.name] = dist
        _load(manager, entry_point.name, entry_point.load)
    _warn_unknown_hooks(manager)
    if os.environ.get("KEYMPS_TRACE_PLUGINS"):
        _trace_hook_calls(manager)
    return manager


def _load(manager: KeympsPluginManager, name: str, load: Callable[[], object]) -> None:
    """Import and register one plugin; a broken one (whatever it raises: SystemExit too) is
    skipped with one warning naming it, and the rest of keymps keeps working."""
    signals_before = signals_received()
    try:
        manager.register(load(), name=name)
    except BaseException as error:
        _forget(manager, name)
        if _a_real_interrupt(error, signals_before):  # the user's Ctrl-C stops the command
            _warn_plugin(f"keymps: interrupted while plugin {name!r} was loading")
            raise
        manager.failures[name] = _warn_broken(name, error)


def _a_real_interrupt(error: BaseException, signals_before: int) -> bool:
    """A KeyboardInterrupt from the user, not one a plugin raised itself: with the keymps
    command's handler, only one that came with a signal (without it, any one)."""
    if not isinstance(error, KeyboardInterrupt):
        return False
    return not handling_signals() or signals_received() > signals_before


def _disable(manager: pluggy.PluginManager, name: str, error: BaseException, where: str) -> str:
    """Unregister a plugin whose hook raised; the one warning naming it, returned too."""
    detail = " ".join(f"{type(error).__name__}: {error}".split())
    message = f"keymps: plugin {name!r} failed in {where} and was unregistered: {detail}"
    if manager.has_plugin(name):
        manager.unregister(name=name)
    failures = getattr(manager, "failures", None)
    if failures is not None:
        failures[name] = detail
    _warn_plugin(message)
    return message


def call_each(manager: pluggy.PluginManager, hook_name: str, **kwargs: Any) -> list[str]:
    """Call a hook on each plugin on its own, in pluggy's order (the last registered first),
    so that one that raises hides nothing from the others. A plugin that raises anything
    (SystemExit, its own KeyboardInterrupt) is unregistered with one warning naming it; the
    user's Ctrl-C goes on once every plugin has been called. Returns the warnings."""
    impls = getattr(manager.hook, hook_name).get_hookimpls()
    problems: list[str] = []
    pressed: BaseException | None = None
    for impl in reversed(impls):
        try:
            problem = _call_one(manager, hook_name, impl, impls, kwargs)
        except KeyboardInterrupt as interrupt:  # the others still hear of it (the recorder
            pressed = interrupt  # closes run.rrd at "finished"); the Ctrl-C then goes on
            continue
        if problem:
            problems.append(problem)
    if pressed is not None:
        raise pressed
    return problems


def _call_one(
    manager: pluggy.PluginManager, hook_name: str, impl: Any, impls: list[Any], kwargs: Any
) -> str | None:
    """Call one plugin's implementation of a hook; the warning if it raised (and was
    unregistered). The user's Ctrl-C is raised."""
    others = [other.plugin for other in impls if other.plugin is not impl.plugin]
    only = manager.subset_hook_caller(hook_name, remove_plugins=others)
    signals_before = signals_received()
    try:
        only(**kwargs)
    except BaseException as error:
        if _a_real_interrupt(error, signals_before):
            raise
        return _disable(manager, impl.plugin_name, error, f"{hook_name}({_shown(kwargs)})")
    return None


def _shown(kwargs: dict[str, Any]) -> str:
    """A hook call's arguments worth naming in a warning (the stage of keymps_stage_done)."""
    return f"stage={kwargs['stage']!r}" if "stage" in kwargs else ""


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
            _warn_plugin(
                f"keymps: plugin {impl.plugin_name!r} implements {name!r}, which is no keymps "
                f"hook{hint}: it is never called"
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


@contextmanager
def manager_in_use(manager: pluggy.PluginManager) -> Iterator[pluggy.PluginManager]:
    """Make `manager` the process-wide one inside the block, the previous one after it."""
    global _manager
    previous, _manager = _manager, manager
    try:
        yield manager
    finally:
        _manager = previous


def registrations(
    kind: str, manager: pluggy.PluginManager | None = None
) -> dict[str, list[tuple[str, Callable[..., Any]]]]:
    """Plugin name -> the (name, factory) pairs it registers of one kind, in pluggy's order.

    Each plugin's hook is called on its own: one that raises, or registers a name that is no
    non-empty string or a factory that cannot be called, is unregistered with one warning and
    registers nothing."""
    manager = manager or get_manager()
    hook_name = COMPONENT_HOOKS[kind]
    impls = getattr(manager.hook, hook_name).get_hookimpls()
    found: dict[str, list[tuple[str, Callable[..., Any]]]] = {}
    for impl in reversed(impls):
        own: list[tuple[str, Callable[..., Any]]] = []

        def register(name: str, factory: Callable[..., Any], own: list[Any] = own) -> None:
            if not isinstance(name, str) or not name.strip():
                raise TypeError(f"register({name!r}, ...): a component's name is a string")
            if not callable(factory):
                raise TypeError(f"register({name!r}, {factory!r}): the factory is not callable")
            own.append((name, factory))

        if _call_one(manager, hook_name, impl, impls, {"register": register}) is None:
            found[impl.plugin_name] = own
    return found


def components(
    kind: str, manager: pluggy.PluginManager | None = None
) -> dict[str, Callable[..., Any]]:
    """Every registered factory of one kind ('detector', 'vlm_backend', ...), by name."""
    return _merged(kind, registrations(kind, manager))


def _merged(
    kind: str, registered: dict[str, list[tuple[str, Callable[..., Any]]]]
) -> dict[str, Callable[..., Any]]:
    """One factory per name; a replaced one is said once per process."""
    found: dict[str, Callable[..., Any]] = {}
    owners: dict[str, list[str]] = {}
    # pluggy's order, the plugin registered last first: an installed plugin's component
    # replaces a built-in of the same name (what docs/plugins.md promises)
    for plugin, pairs in registered.items():
        for name, factory in pairs:
            found.setdefault(name, factory)
            owners.setdefault(name, []).append(plugin)
    for name, plugins in owners.items():
        used, *others = plugins
        for other in others:
            if (kind, name, other) in _replaced or other == used:
                continue
            _replaced.add((kind, name, other))
            _warn_plugin(
                f"keymps: {kind.replace('_', ' ')} {name!r} of plugin {used!r} replaces the one "
                f"of plugin {other!r}"
            )
    return found


_replaced: set[tuple[str, str, str]] = set()
"""The replacements already reported in this process."""


def create_component(
    kind: str,
    name: str,
    options: dict[str, Any] | None = None,
    manager: pluggy.PluginManager | None = None,
) -> Any:
    """The untyped primitive under the typed `create_*` functions: build the named component of
    any kind, unchecked. Prefer `create_detector`, `create_vlm_backend` ... which say what they
    return and refuse a factory's wrong result."""
    return _build(kind, name, options, manager)[0]


def _build(
    kind: str,
    name: str,
    options: dict[str, Any] | None,
    manager: pluggy.PluginManager | None,
) -> tuple[object, str]:
    """(the component, the plugin that registered it); a KeympsError listing the choices for an
    unknown name. A factory that raises anything but a KeympsError is one line naming its
    plugin."""
    found = registrations(kind, manager)
    factories = _merged(kind, found)
    if name not in factories:
        choices = ", ".join(sorted(factories)) or "none installed"
        raise KeympsError(f"unknown {kind.replace('_', ' ')} {name!r} (available: {choices})")
    factory = factories[name]
    plugin = next((p for p, pairs in found.items() if (name, factory) in pairs), "?")
    signals_before = signals_received()
    try:
        return factory(dict(options or {})), plugin
    except KeympsError:
        raise
    except BaseException as error:
        if _a_real_interrupt(error, signals_before) or os.environ.get("KEYMPS_DEBUG"):
            raise
        detail = " ".join(f"{type(error).__name__}: {error}".split())
        raise KeympsError(
            f"{kind.replace('_', ' ')} {name!r} of plugin {plugin!r} could not be built: {detail}"
        ) from None


def _create_checked(
    kind: str,
    name: str,
    options: dict[str, Any] | None,
    manager: pluggy.PluginManager | None,
    protocol: type,
) -> object:
    """Build a component; a result lacking what keymps uses of `protocol` (None, a wrong
    object) is refused in one line naming the plugin."""
    built, plugin = _build(kind, name, options, manager)
    missing = _missing(built, protocol)
    if missing is None:
        return built
    wanted = protocol.__name__
    got = "None" if built is None else f"a {type(built).__name__} without {missing}"
    article = "an" if wanted[0] in "AEIOU" else "a"
    raise KeympsError(
        f"{kind.replace('_', ' ')} {name!r} of plugin {plugin!r}: its factory returned {got}, "
        f"not {article} {wanted} (keymps.plugin.{wanted})"
    )


def _missing(built: object, protocol: type) -> str | None:
    """The first thing keymps uses of `protocol` that `built` lacks; None when it has all.
    An Arm is checked whole (every field is read); other kinds only for their methods: a
    `name` attribute, which keymps never reads from the object, is not demanded."""
    if built is None:
        return "anything"
    if protocol is Arm:
        return next((m for m in _members(Arm) if not hasattr(built, m)), None)
    methods = [m for m in _members(protocol) if callable(getattr(protocol, m, None))]
    return next((f"{m}()" for m in methods if not callable(getattr(built, m, None))), None)


def _members(protocol: type) -> list[str]:
    """The names a Protocol declares (methods, properties, attributes)."""
    annotated = getattr(protocol, "__annotations__", {})
    declared = [m for m in vars(protocol) if not m.startswith("_")]
    return sorted(set(declared) | set(annotated))


def create_detector(
    name: str, options: dict[str, Any] | None = None, manager: pluggy.PluginManager | None = None
) -> Detector:
    """Build the detector registered as `name`.

    Args:
        name: The registered name (`detector.name`).
        options: The factory's options (`detector.options`).
        manager: The plugin manager (the process-wide one when None).

    Returns:
        The detector.

    Raises:
        keymps.errors.KeympsError: An unknown name (the choices listed), a factory that failed
            or returned no Detector (one line naming its plugin).
    """
    return cast(Detector, _create_checked("detector", name, options, manager, Detector))


def create_image_source(
    name: str, options: dict[str, Any] | None = None, manager: pluggy.PluginManager | None = None
) -> ImageSource:
    """Build the image source registered as `name` (`scene.source`); as create_detector."""
    return cast(ImageSource, _create_checked("image_source", name, options, manager, ImageSource))


def create_executor(
    name: str, options: dict[str, Any] | None = None, manager: pluggy.PluginManager | None = None
) -> Executor:
    """Build the executor registered as `name` (`executor.name`); as create_detector."""
    return cast(Executor, _create_checked("executor", name, options, manager, Executor))


def create_robot(
    name: str, options: dict[str, Any] | None = None, manager: pluggy.PluginManager | None = None
) -> Arm:
    """Build the arm registered as `name` (`robot.model`); as create_detector."""
    return cast(Arm, _create_checked("robot", name, options, manager, Arm))


def create_vlm_backend(
    name: str, options: dict[str, Any] | None = None, manager: pluggy.PluginManager | None = None
) -> VlmBackend:
    """Build the planner backend registered as `name` (`planner.backend`); as create_detector.
    A backend declaring `supports_async` must implement `acomplete` as a coroutine function."""
    built = _create_checked("vlm_backend", name, options, manager, VlmBackend)
    if BackendAbilities.of(built).supports_async and not _own_acomplete(built):
        raise KeympsError(
            f"vlm backend {name!r} declares supports_async but implements no async "
            "acomplete(request)"
        )
    return cast(VlmBackend, built)


def _own_acomplete(backend: object) -> bool:
    """Whether a backend implements `async def acomplete` (BackendBase's own does not count)."""
    method = getattr(type(backend), "acomplete", None)
    return method is not BackendBase.acomplete and inspect.iscoroutinefunction(method)


def _provides(kinds: dict[str, dict[str, list[tuple[str, Any]]]], plugin_name: str) -> list[str]:
    return [
        f"{kind.replace('_', ' ')} {name}"
        for kind, found in kinds.items()
        for name, _ in found.get(plugin_name, [])
    ]


def plugin_infos(manager: pluggy.PluginManager | None = None) -> list[PluginInfo]:
    """What `keymps plugins` shows: every plugin with what it provides and where it comes from.
    A plugin whose hooks raise is listed with its error (and warned about once)."""
    from keymps._version import __version__

    manager = manager or get_manager()
    kinds = {kind: registrations(kind, manager) for kind in COMPONENT_HOOKS}
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
        provides = _provides(kinds, name)
        if hasattr(plugin, "keymps_stage_done"):
            provides.append("stage observer")
        infos.append(PluginInfo(name, tuple(provides), dist, version, hooks))
    for name, error in getattr(manager, "failures", {}).items():
        dist, version = known.get(
            name, ("keymps", __version__) if name in DEFAULT_PLUGINS else ("?", "")
        )
        infos.append(PluginInfo(name, (), dist, version, (), error))
    return infos
