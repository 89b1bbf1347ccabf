"""The API for plugin authors: import everything a keymps plugin needs from here.

```python
from keymps.plugin import RegisterDetector, hookimpl

@hookimpl
def register_detectors(register: RegisterDetector) -> None:
    register("my-detector", MyDetector)
```

See docs/plugins.md for every hook and docs/architecture.md for where plugins sit.
"""

from keymps.errors import DetectionError, ImageSourceError, KeympsError, SafetyError, StageError
from keymps.plugin.arms import DEFAULT_ACCELERATION, DEFAULT_JERK, ArmSpec, degrees
from keymps.plugin.components import (
    Arm,
    Detector,
    Executor,
    ImageSource,
    StageObserver,
    VlmBackend,
)
from keymps.plugin.hookspecs import (
    Register,
    RegisterDetector,
    RegisterExecutor,
    RegisterImageSource,
    RegisterRobot,
    RegisterVlmBackend,
    hookimpl,
)
from keymps.plugin.options import parse_options
from keymps.plugin.trajectories import require_validated

__all__ = [
    "DEFAULT_ACCELERATION",
    "DEFAULT_JERK",
    "Arm",
    "ArmSpec",
    "DetectionError",
    "Detector",
    "Executor",
    "ImageSource",
    "ImageSourceError",
    "KeympsError",
    "Register",
    "RegisterDetector",
    "RegisterExecutor",
    "RegisterImageSource",
    "RegisterRobot",
    "RegisterVlmBackend",
    "SafetyError",
    "StageError",
    "StageObserver",
    "VlmBackend",
    "degrees",
    "hookimpl",
    "parse_options",
    "require_validated",
]
