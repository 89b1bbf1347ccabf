"""pytest fixtures for testing keymps plugins (loaded automatically where keymps is installed).

def test_my_detector(keymps_plugins):
    keymps_plugins.register(my_plugin_module)
    detector = keymps_plugins.create("detector", "mine")
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest


class PluginHarness:
    """A fresh plugin manager, active for one test, with helpers to add and build plugins."""

    def __init__(self) -> None:
        from keymps.plugin import manager as plugins

        self._plugins = plugins
        self.manager = plugins.build_manager()

    def register(self, plugin: object, name: str | None = None) -> None:
        """Add a plugin (a module or an object with hook implementations). One the manager
        already loaded, e.g. the package under test installed with its entry point, is kept
        as it is: registering it again would be a pluggy error."""
        if self.manager.is_registered(plugin):
            return
        self.manager.register(plugin, name=name)

    def create(self, kind: str, name: str, options: dict[str, Any] | None = None) -> Any:
        return self._plugins.create_component(kind, name, options, manager=self.manager)

    def names(self, kind: str) -> list[str]:
        return sorted(self._plugins.components(kind, self.manager))


@pytest.fixture
def keymps_plugins() -> Iterator[PluginHarness]:
    """A PluginHarness installed as keymps' process-wide manager for the test's duration."""
    from keymps.plugin import manager as plugins

    harness = PluginHarness()
    with plugins.manager_in_use(harness.manager):
        yield harness
