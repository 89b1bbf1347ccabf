"""The API for plugin authors: import everything a keymps plugin needs from here.

```python
from keymps.plugin import hookimpl, Register

@hookimpl
def register_detectors(register: Register) -> None:
    register("my-detector", MyDetector)
```

See docs/plugins.md for every hook and docs/architecture.md for where plugins sit.
"""

from keymps.plugin.components import Detector, Executor, ImageSource, VlmBackend
from keymps.plugin.hookspecs import Register, hookimpl
from keymps.plugin.options import parse_options

__all__ = [
    "Detector",
    "Executor",
    "ImageSource",
    "Register",
    "VlmBackend",
    "hookimpl",
    "parse_options",
]
