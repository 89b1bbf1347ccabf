"""Imported once by the fork server that starts `keymps eval`'s worker processes (keymps.eval.pool).

Its whole job is importing what a run needs, so that each forked worker starts with it loaded
instead of spending a second or more importing. litellm is not among them: the workers hand
their VLM calls to the parent's event loop (keymps.eval.broker), which alone imports it; the
litellm backend's own module is preloaded beside this one only when the runs use it
(keymps.eval.pool). Nothing else imports this module. A module missing from the list costs only
time: the worker's first run imports it.
"""

import contextlib
import importlib
import os

# Runs are the unit of parallelism: BLAS helper threads would only spin on the other core.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from keymps._memory import keep_freed_memory  # noqa: E402

keep_freed_memory()  # inherited by every worker the fork server starts

import cv2  # noqa: E402, F401
import numpy  # noqa: E402, F401
import pinocchio  # noqa: E402, F401

import keymps.eval.methods  # noqa: E402, F401
import keymps.eval.runner  # noqa: E402, F401
import keymps.eval.truth  # noqa: E402, F401
import keymps.pipeline.engine  # noqa: E402, F401
import keymps.planning.planner  # noqa: E402, F401
import keymps.scenes.render  # noqa: E402, F401
from keymps.perception.board_model import lab_tables_ready, prepare_lab_tables  # noqa: E402

LAZY_MODULES = (
    # what a run's stages and the default plugins import when first used
    "keymps.default_plugins.board_detector",
    "keymps.default_plugins.file_executor",
    "keymps.default_plugins.image_sources",
    "keymps.default_plugins.offline",
    "keymps.default_plugins.rerun.recorder",
    "keymps.default_plugins.replay_backend",
    "keymps.default_plugins.sim.executor",
    "keymps.default_plugins.threshold_detector",
    "keymps.primitives.retarget",
    "keymps.eval.parts",
    "keymps.eval.metric",
    "keymps.perception.frames",
    "keymps.pipeline.overlay",
    "keymps.planning.prompt",
    "keymps.planning.session",
    "keymps.primitives.dictionary",
    "keymps.planning.cache",
    "keymps_ur_rtde",
    "keymps.eval.broker",
)


def _preload() -> None:
    for name in LAZY_MODULES:
        # a plugin that is not installed is imported by nobody
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    # what every worker's first run would otherwise pay: OpenCV's Lab tables (about 100 ms) and
    # the board and noise field of the default 0.30 x 0.18 m board at 2000 px/m (25 ms). (Not
    # OpenCV's fonts: they are set up per thread, and a worker starts its own text thread.)
    prepare_lab_tables()
    lab_tables_ready()
    keymps.scenes.render.render_scene(keymps.scenes.render.SceneSpec.from_kinds(["round_cake"]))


_preload()
