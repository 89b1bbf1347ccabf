"""Motion primitives: DMP maths, re-targeting maps, the dictionary, learning from demonstrations.

```python
from pathlib import Path

from keymps.primitives import default_search_dirs, load_primitives

knife = load_primitives(["sawing"], default_search_dirs(Path("tasks")))["sawing"]
stroke = knife.rollout(start=[0.10, 0.05, 0.06], goal=[0.10, 0.12, 0.0], speed=0.02)
stroke.y  # (num, 3) tool-tip positions, metres
```

The formulation and the primitive file format are in docs/primitives.md.
"""

from keymps.primitives.demos import (
    DemoError,
    Preprocessing,
    fit_rmse,
    load_demo_csv,
    prepare_demo,
    write_demo_csv,
)
from keymps.primitives.dictionary import (
    Primitive,
    PrimitiveError,
    default_search_dirs,
    find_primitive_files,
    learn_primitive,
    load_primitive,
    load_primitives,
    save_primitive,
)
from keymps.primitives.dmp import DMP, Rollout
from keymps.primitives.retarget import RETARGET_MODES, retarget_map
from keymps.primitives.system import DmpError

__all__ = [
    "DMP",
    "RETARGET_MODES",
    "DemoError",
    "DmpError",
    "Preprocessing",
    "Primitive",
    "PrimitiveError",
    "Rollout",
    "default_search_dirs",
    "find_primitive_files",
    "fit_rmse",
    "learn_primitive",
    "load_demo_csv",
    "load_primitive",
    "load_primitives",
    "prepare_demo",
    "retarget_map",
    "save_primitive",
    "write_demo_csv",
]
