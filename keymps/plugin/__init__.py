"""The API for plugin authors: import everything a keymps plugin needs from here.

```python
from keymps.plugin import RegisterDetector, hookimpl

@hookimpl
def register_detectors(register: RegisterDetector) -> None:
    register("my-detector", MyDetector)
```

See docs/plugins.md for every hook and docs/architecture.md for where plugins sit.
"""

from keymps.errors import (
    DetectionError,
    ImageSourceError,
    KeympsError,
    SafetyError,
    StageError,
    interrupt_name,
)
from keymps.interrupts import interrupts_deferred
from keymps.plugin.arms import DEFAULT_ACCELERATION, DEFAULT_JERK, ArmSpec, degrees
from keymps.plugin.components import (
    Arm,
    BackendAbilities,
    BackendBase,
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
from keymps.plugin.options import RunFolderPath, parse_options
from keymps.plugin.trajectories import require_validated, trajectory_digest

__all__ = [
    "DEFAULT_ACCELERATION",
    "DEFAULT_JERK",
    "Arm",
    "ArmSpec",
    "BackendAbilities",
    "BackendBase",
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
    "RunFolderPath",
    "SafetyError",
    "StageError",
    "StageObserver",
    "VlmBackend",
    "degrees",
    "hookimpl",
    "interrupt_name",
    "interrupts_deferred",
    "parse_options",
    "require_validated",
    "trajectory_digest",
]
