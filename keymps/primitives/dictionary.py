"""The primitive dictionary: one YAML file per primitive (a fitted DMP) next to its demo CSV."""

from __future__ import annotations

import math
import os
import re
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from keymps.bundled import bundled_dir
from keymps.config.trust import MAX_PRIMITIVE_BYTES, readable_file_problem
from keymps.errors import KeympsError
from keymps.primitives.demos import (
    Preprocessing,
    fit_rmse,
    load_demo_csv,
    prepare_demo,
    write_demo_csv,
)
from keymps.primitives.dmp import DMP, RETARGET_MODES, DmpError, Rollout
from keymps.primitives.retarget import blade_applies

Family = Literal["cutting", "icing"]
FAMILIES: tuple[str, ...] = ("cutting", "icing")
FORMAT = "keymps-primitive/1"
NAME_PATTERN = re.compile(r"[a-z][a-z0-9_-]{0,63}")
DEFAULT_MODES = {"cutting": "blade", "icing": "axial"}
"""Re-targeting mode of a learned primitive when none is given, by family."""
MAX_FIT_RMSE = 0.0005
"""Bundled primitives fit their demonstrations at least this well (metres); `learn` warns above."""


class PrimitiveError(KeympsError):
    """A primitive file or demonstration is invalid, or a primitive does not exist."""


@dataclass(frozen=True)
class Primitive:
    """A named, described, fitted motion primitive the planner can choose."""

    name: str
    """The keyword the planner answers with; the file is NAME.yaml."""
    description: str
    """What the planner (VLM) reads when choosing: what the motion is and when to use it."""
    family: Family
    """`cutting` or `icing`: which tools the primitive fits (a plan of the other is refused)."""
    mode: str
    """Default re-targeting mode: one of RETARGET_MODES (see `retarget_map`)."""
    nominal_speed: float
    """Average tool speed along the path the primitive was designed for, m/s."""
    dmp: DMP
    """The fitted DMP (its weights are in the YAML file)."""
    demo: Path | None = None
    """The demonstration CSV (t, x, y, z) the weights were fitted from."""
    fit_rmse: float = 0.0
    """Root-mean-square distance between the fitted rollout and the demonstration, metres."""
    preprocessing: Preprocessing = field(default_factory=Preprocessing)
    """What refitting applies to `demo` (a learned demo is saved prepared: nothing more)."""
    source: str | None = None
    """Where the demonstration came from before preprocessing (free text, e.g. a log file)."""
    source_preprocessing: Preprocessing | None = None
    """How `source` was cleaned into `demo` when the primitive was learned."""
    path: Path | None = field(default=None, compare=False)
    """The YAML file this primitive was loaded from."""

    def rollout(
        self,
        start: Sequence[float] | np.ndarray,
        goal: Sequence[float] | np.ndarray,
        *,
        speed: float | None = None,
        spacing: float = 0.001,
        mode: str | None = None,
        heading: float | None = None,
    ) -> Rollout:
        """The primitive re-targeted to a start and goal, timed for an average speed.

        Args:
            start: (3,) where the motion starts, board frame, metres.
            goal: (3,) where it ends at rest, metres.
            speed: Average tool speed along the path, m/s; None takes `nominal_speed`.
            spacing: The largest distance between neighbouring samples, metres (about).
            mode: One of RETARGET_MODES; None takes the primitive's `mode`.
            heading: Radians about z: orients the demo when the segment is vertical.

        Returns:
            Times (num,) seconds, positions (num, 3) metres, velocities and accelerations; num
            is rounded up to a bin of 12.5 % so that similar segments share a cached rollout.

        Raises:
            DmpError: For a start or goal that is not a finite [x, y, z], a speed that is not
                positive, or an unknown mode.
        """
        start_arr, goal_arr = np.asarray(start, float), np.asarray(goal, float)
        mode = mode or self.mode
        tau = self.dmp.tau_for_speed(start_arr, goal_arr, speed or self.nominal_speed, mode)
        # Point spacing scales with 1/(num - 1): size num from a reference rollout, then round it
        # up to a bin so that segments of similar length share one cached canonical rollout.
        reference = self.dmp.rollout(
            start_arr, goal_arr, num=_REFERENCE_NUM, mode=mode, heading=heading
        ).y
        widest = float(np.linalg.norm(np.diff(reference, axis=0), axis=1).max())
        num = _sample_bin((_REFERENCE_NUM - 1) * widest / spacing + 1)
        rollout = self.dmp.rollout(
            start_arr, goal_arr, tau=tau, num=num, mode=mode, heading=heading
        )
        widest = float(np.linalg.norm(np.diff(rollout.y, axis=0), axis=1).max())
        while widest > spacing and num < _MAX_SAMPLES:
            num = _sample_bin(num * widest / spacing + 1)
            rollout = self.dmp.rollout(
                start_arr, goal_arr, tau=tau, num=num, mode=mode, heading=heading
            )
            widest = float(np.linalg.norm(np.diff(rollout.y, axis=0), axis=1).max())
        return rollout


_REFERENCE_NUM = 1000
_MAX_SAMPLES = 200_000


def _sample_bin(needed: float) -> int:
    """The smallest of 50 * 1.125**k (rounded) that is at least `needed`, at most 200 000."""
    k = max(0, math.ceil(math.log(max(needed, 1.0) / 50.0) / math.log(1.125) - 1e-9))
    return int(min(math.ceil(50 * 1.125**k - 1e-9), _MAX_SAMPLES))


def default_mode(family: str, demo_delta: np.ndarray) -> str:
    """The family's re-targeting mode; a cutting demo too flat for `blade` gets `axial`."""
    mode = DEFAULT_MODES.get(family, "similarity")
    return "axial" if mode == "blade" and not blade_applies(demo_delta) else mode


def learn_primitive(
    name: str,
    demo: Path,
    *,
    description: str,
    family: str = "cutting",
    mode: str | None = None,
    nominal_speed: float = 0.03,
    n_basis: int = 50,
    preprocessing: Preprocessing | None = None,
    out_dir: Path | None = None,
) -> Primitive:
    """Fit a primitive to a demonstration CSV (`keymps primitives learn`).

    Args:
        name: The primitive's name: lower-case letters, digits, - or _, a letter first.
        demo: The demonstration CSV (t,x,y,z in seconds and metres).
        description: What the planner reads when choosing it.
        family: `cutting` or `icing`.
        mode: The re-targeting mode; None takes the family's (blade for cutting when the demo
            descends enough, else axial).
        nominal_speed: Average tool speed it is run at, m/s.
        n_basis: Gaussian basis functions per axis.
        preprocessing: How the recording is cleaned first; None takes the defaults.
        out_dir: When given, the prepared demonstration is written there as NAME.csv (unless
            it is already that file) and the primitive as NAME.yaml.

    Returns:
        The fitted primitive (`path` set when it was saved).

    Raises:
        PrimitiveError: For a bad name, family, mode or speed.
        DemoError: For a demonstration that cannot be read or used.
        DmpError: When the fit is refused (too few samples, n_basis out of range).
    """
    _check_name(name, "name")
    demo = Path(demo)
    settings = preprocessing or Preprocessing()
    t, y = prepare_demo(*load_demo_csv(demo), settings, str(demo))
    dmp = DMP.fit(t, y, n_basis=n_basis)
    primitive = Primitive(
        name=name,
        description=description.strip(),
        family=_check_choice(family, FAMILIES, "family", str(demo)),  # type: ignore[arg-type]
        mode=_check_choice(
            mode or default_mode(family, dmp.demo_delta), RETARGET_MODES, "mode", str(demo)
        ),
        nominal_speed=_positive(nominal_speed, "nominal_speed", str(demo)),
        dmp=dmp,
        demo=demo,
        fit_rmse=fit_rmse(dmp, t, y),
        preprocessing=settings,
        source=None,
    )
    return primitive if out_dir is None else _save_learned(primitive, demo, t, y, Path(out_dir))


def _save_learned(
    primitive: Primitive, demo: Path, t: np.ndarray, y: np.ndarray, out_dir: Path
) -> Primitive:
    """Write a primitive learned from `demo` as out_dir/NAME.yaml, with the prepared
    demonstration (times t (n,) seconds, positions y (n, 3) metres) as NAME.csv beside it
    unless `demo` is that file; returns the primitive as saved."""
    out_dir.mkdir(parents=True, exist_ok=True)
    demo_out = out_dir / f"{primitive.name}.csv"
    if demo_out.resolve() != demo.resolve():
        write_demo_csv(demo_out, t, y)
        # The saved demo is already prepared: refitting it needs no further preprocessing.
        primitive = replace(
            primitive,
            preprocessing=Preprocessing(trim_mm=0.0),
            source=str(demo),
            source_preprocessing=primitive.preprocessing,
        )
    primitive = replace(primitive, demo=demo_out)
    save_primitive(primitive, out_dir / f"{primitive.name}.yaml")
    return replace(primitive, path=out_dir / f"{primitive.name}.yaml")


# --------------------------------------------------------------------------- primitive files


def primitive_to_dict(primitive: Primitive, relative_to: Path | None = None) -> dict[str, Any]:
    demo: str | None = None
    if primitive.demo is not None:
        demo = str(primitive.demo)
        if relative_to is not None:
            try:
                demo = os.path.relpath(primitive.demo.resolve(), relative_to.resolve())
            except ValueError:
                demo = str(primitive.demo.resolve())
    return {
        "format": FORMAT,
        "name": primitive.name,
        "description": primitive.description,
        "family": primitive.family,
        "mode": primitive.mode,
        "nominal_speed": primitive.nominal_speed,
        "demo": demo,
        "source": primitive.source,
        "source_preprocessing": primitive.source_preprocessing.to_dict()
        if primitive.source_preprocessing
        else None,
        "fit_rmse_m": primitive.fit_rmse,
        "preprocessing": primitive.preprocessing.to_dict(),
        "dmp": primitive.dmp.to_dict(),
    }


def save_primitive(primitive: Primitive, path: Path) -> None:
    """Write a primitive file (YAML; floats written to round-trip exactly).

    Args:
        primitive: The primitive to write.
        path: The YAML file; the demo path is stored relative to its folder.
    """
    import yaml

    class _Dumper(yaml.SafeDumper):
        pass

    def _flow_rows(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
        flow = bool(data) and all(isinstance(v, float) for v in data)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)

    _Dumper.add_representer(list, _flow_rows)
    path = Path(path)
    text = yaml.dump(
        primitive_to_dict(primitive, relative_to=path.parent),
        Dumper=_Dumper,
        sort_keys=False,
        width=100,
        allow_unicode=True,
    )
    path.write_text(text, encoding="utf-8")


_LOADED: dict[tuple[str, int, int], Primitive] = {}
"""Primitives already read in this process, by (resolved path, mtime, size): an eval worker
reads each file once, not once per run (a primitive's YAML holds its weights)."""
_LOADED_LOCK = threading.Lock()


def load_primitive(path: Path) -> Primitive:
    """Read and validate a primitive file.

    A file unchanged since it was last read in this process is not read again.

    Args:
        path: The primitive's YAML file.

    Returns:
        The primitive, `path` set.

    Raises:
        PrimitiveError: For a missing or unreadable file, invalid YAML, an unknown or missing
            field or a bad value, naming the file (and line for YAML errors) and the field.
    """
    path = Path(path)
    try:
        status = path.stat()
        key = (str(path.resolve()), status.st_mtime_ns, status.st_size)
    except OSError:
        key = None
    with _LOADED_LOCK:
        cached = _LOADED.get(key) if key else None
    if cached is not None:
        return cached
    primitive = _read_primitive(path)
    if key is not None:
        with _LOADED_LOCK:
            _LOADED[key] = primitive
    return primitive


def _read_primitive(path: Path) -> Primitive:
    """The primitive in a YAML file, each field checked; an error names the file and field."""
    data = _load_yaml(path)
    where = str(path)
    _check_fields(data, where)
    name = _check_name(data["name"], f"{where}: name")
    description = data["description"]
    if not isinstance(description, str) or not description.strip():
        raise PrimitiveError(f"{where}: description must be a non-empty text")
    family = _check_choice(data["family"], FAMILIES, "family", where)
    mode = _check_choice(data.get("mode", "similarity"), RETARGET_MODES, "mode", where)
    speed = _positive(data.get("nominal_speed", 0.03), "nominal_speed", where)
    rmse = data.get("fit_rmse_m", 0.0)
    if not isinstance(rmse, (int, float)) or not math.isfinite(rmse) or rmse < 0:
        raise PrimitiveError(f"{where}: fit_rmse_m must be a non-negative number")
    try:
        dmp = DMP.from_dict(data["dmp"], where)
    except DmpError as error:
        raise PrimitiveError(str(error)) from None
    demo = data.get("demo")
    if demo is not None and not isinstance(demo, str):
        raise PrimitiveError(f"{where}: demo must be a file name")
    source, source_preprocessing = data.get("source"), data.get("source_preprocessing")
    return Primitive(
        name=name,
        description=description.strip(),
        family=family,  # type: ignore[arg-type]
        mode=mode,
        nominal_speed=speed,
        dmp=dmp,
        demo=(path.parent / demo) if demo else None,
        fit_rmse=float(rmse),
        preprocessing=_preprocessing(data.get("preprocessing") or {}, where),
        source=str(source) if source is not None else None,
        source_preprocessing=None
        if source_preprocessing is None
        else _preprocessing(source_preprocessing, where),
        path=path,
    )


def _load_yaml(path: Path) -> Any:
    """The data of a YAML file; a missing, unreadable or invalid one is a PrimitiveError
    naming it (and the line and column of a YAML error)."""
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: the same data, 10x faster
    try:
        return yaml.load(path.read_text(encoding="utf-8"), Loader=loader)
    except FileNotFoundError:
        raise PrimitiveError(f"{path}: primitive file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise PrimitiveError(f"{path}: cannot read primitive ({error})") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        raise PrimitiveError(
            f"{where}: invalid YAML ({getattr(error, 'problem', error)})"
        ) from None


_FIELDS = frozenset(
    {
        "format", "name", "description", "family", "mode", "nominal_speed", "demo", "source",
        "source_preprocessing", "fit_rmse_m", "preprocessing", "dmp",
    }
)  # fmt: skip
"""The fields a primitive file may have (name, description, family and dmp it must)."""


def _check_fields(data: Any, where: str) -> None:
    """Refuse anything but a mapping of known fields in FORMAT with the required ones."""
    if not isinstance(data, dict):
        raise PrimitiveError(f"{where}: expected a mapping of primitive fields")
    unknown = sorted(set(data) - _FIELDS, key=str)  # YAML keys may be numbers too
    if unknown:
        raise PrimitiveError(f"{where}: unknown field {unknown[0]!r}")
    if data.get("format", FORMAT) != FORMAT:
        raise PrimitiveError(f"{where}: format {data.get('format')!r} is not {FORMAT!r}")
    for key in ("name", "description", "family", "dmp"):
        if key not in data:
            raise PrimitiveError(f"{where}: field {key!r} is missing")


def _preprocessing(data: Any, where: str) -> Preprocessing:
    if not isinstance(data, dict) or set(data) - {"rate_hz", "smooth_s", "trim_mm"}:
        raise PrimitiveError(f"{where}: preprocessing takes rate_hz, smooth_s and trim_mm")
    try:
        rate = data.get("rate_hz")
        return Preprocessing(
            rate_hz=None if rate is None else float(rate),
            smooth_s=float(data.get("smooth_s", 0.0)),
            trim_mm=float(data.get("trim_mm", 0.5)),
        )
    except (TypeError, ValueError):
        raise PrimitiveError(f"{where}: preprocessing values must be numbers") from None


def _check_name(name: Any, where: str) -> str:
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise PrimitiveError(
            f"{where}: primitive name {name!r} must be lower-case letters, digits, - or _ "
            "(starting with a letter)"
        )
    return name


def _check_choice(value: Any, choices: Sequence[str], key: str, where: str) -> str:
    if value not in choices:
        raise PrimitiveError(f"{where}: {key} {value!r} is not one of {', '.join(choices)}")
    return str(value)


def _positive(value: Any, key: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PrimitiveError(f"{where}: {key} must be a number")
    if not math.isfinite(value) or value <= 0:
        raise PrimitiveError(f"{where}: {key} must be positive, got {value}")
    return float(value)


# --------------------------------------------------------------------------- the dictionary

BUNDLED_DIR = bundled_dir("primitives")
"""The dictionary shipped with keymps (found last)."""


def default_search_dirs(task_folder: Path) -> list[Path]:
    """Where primitives are looked for, first match wins.

    The task folder's ../primitives and primitives/, each folder in KEYMPS_PRIMITIVES_PATH,
    ./primitives, then the bundled dictionary. ../primitives and ./primitives are left out when
    other users may write them (a task in /tmp/x would otherwise read /tmp/primitives:
    docs/security.md). Those three are not followed when they are links themselves (a shared
    folder's `primitives -> /` is no search folder at `/`); the user's own folders are.

    Args:
        task_folder: The task file's folder.

    Returns:
        The folders, without repeats, in search order.
    """
    from keymps.config.trust import anchored, real_path, shared_folders_left_out

    task_folder = Path(task_folder)
    own = [
        *shared_folders_left_out([task_folder / ".." / "primitives"]),
        task_folder / "primitives",
    ]
    env = os.environ.get("KEYMPS_PRIMITIVES_PATH", "")
    chosen = [real_path(Path(part)) for part in env.split(os.pathsep) if part.strip()]
    dirs = [*map(anchored, own), *chosen]
    dirs += [*map(anchored, shared_folders_left_out([Path.cwd() / "primitives"]))]
    dirs.append(real_path(BUNDLED_DIR))
    return list(dict.fromkeys(dirs))


def find_primitive_files(search_dirs: Sequence[Path]) -> dict[str, Path]:
    """The primitive files in some folders.

    Args:
        search_dirs: Folders in search order (missing ones are skipped).

    Returns:
        Primitive name -> its NAME.yaml, the first folder holding a name winning.
    """
    found: dict[str, Path] = {}
    for folder in search_dirs:
        folder = Path(folder)
        if not folder.is_dir():
            continue
        for file in sorted(folder.glob("*.yaml")):
            found.setdefault(file.stem, file)
    return found


def load_primitives(names: Sequence[str], search_dirs: Sequence[Path]) -> dict[str, Primitive]:
    """Load the named primitives from the first search folder that has each (NAME.yaml).

    Args:
        names: The primitives to load (a task's `primitives`).
        search_dirs: Folders in search order (`default_search_dirs`).

    Returns:
        Name -> Primitive, in the order of `names`.

    Raises:
        PrimitiveError: For a name no folder has (listing the ones there are), a file that
            may not be read (a link out of the search folders, too large) or is invalid, or a
            file whose `name` is not its file name.
    """
    available = find_primitive_files(search_dirs)
    result: dict[str, Primitive] = {}
    for name in names:
        if name not in available:
            listing = ", ".join(sorted(available)) or "none"
            searched = ", ".join(str(d) for d in search_dirs)
            raise PrimitiveError(
                f"unknown primitive {name!r}; available: {listing} (searched {searched})"
            )
        # a shared task folder's primitives/x.yaml may be a link to /dev/zero or a secret
        wrong = readable_file_problem(available[name], search_dirs, MAX_PRIMITIVE_BYTES)
        if wrong:
            raise PrimitiveError(f"primitive {name!r}: {wrong}")
        primitive = load_primitive(available[name])
        if primitive.name != name:
            raise PrimitiveError(
                f"{available[name]}: name {primitive.name!r} does not match the file name {name!r}"
            )
        result[name] = primitive
    return result
