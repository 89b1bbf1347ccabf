"""The primitive dictionary: one YAML file per primitive (a fitted DMP) next to its demo CSV."""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from keymps.dmp import DMP, RETARGET_MODES, DmpError, Rollout
from keymps.errors import KeympsError

Family = Literal["cutting", "icing"]
FAMILIES: tuple[str, ...] = ("cutting", "icing")
FORMAT = "keymps-primitive/1"
DEMO_COLUMNS = ("t", "x", "y", "z")
NAME_PATTERN = re.compile(r"^[a-z][a-z0-9_-]{0,63}$")
MIN_DEMO_SAMPLES = 10
MAX_FIT_RMSE = 0.0005
"""Bundled primitives fit their demonstrations at least this well (metres); `learn` warns above."""


class PrimitiveError(KeympsError):
    """A primitive file or demonstration is invalid, or a primitive does not exist."""


@dataclass(frozen=True)
class Preprocessing:
    """How a recorded demonstration is cleaned before fitting (see docs/primitives.md)."""

    rate_hz: float | None = None
    """Resample to this uniform rate; None keeps uniform logs and resamples uneven ones to the
    median rate."""
    smooth_s: float = 0.0
    """Savitzky-Golay window (cubic) in seconds; 0 turns smoothing off."""
    trim_mm: float = 0.5
    """Drop still samples at both ends: those within this distance of the first/last position."""

    def to_dict(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "smooth_s": self.smooth_s, "trim_mm": self.trim_mm}


@dataclass(frozen=True)
class Primitive:
    """A named, described, fitted motion primitive the planner can choose."""

    name: str
    description: str
    """What the planner (VLM) reads when choosing: what the motion is and when to use it."""
    family: Family
    mode: str
    """Default re-targeting mode: similarity | axial | translate (see keymps.dmp)."""
    nominal_speed: float
    """Average tool speed along the path the primitive was designed for, m/s."""
    dmp: DMP
    demo: Path | None = None
    """The demonstration CSV (t, x, y, z) the weights were fitted from."""
    fit_rmse: float = 0.0
    """Root-mean-square distance between the fitted rollout and the demonstration, metres."""
    preprocessing: Preprocessing = field(default_factory=Preprocessing)
    source: str | None = None
    """Where the demonstration came from before preprocessing (free text, e.g. a log file)."""
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
        """The primitive re-targeted to start/goal, run at `speed` m/s on average (default: the
        nominal speed), sampled finely enough that points are at most about `spacing` apart.
        `heading` (radians about z) orients the demo when the segment is vertical."""
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


# --------------------------------------------------------------------------- demonstrations


def load_demo_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a demonstration CSV with header t,x,y,z (seconds, metres): returns t (T,), y (T, 3)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise PrimitiveError(f"{path}: demonstration file not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise PrimitiveError(f"{path}: cannot read demonstration ({error})") from None
    rows = list(csv.reader(line for line in text.splitlines() if line.strip()))
    if not rows:
        raise PrimitiveError(f"{path}: empty demonstration; expected a header t,x,y,z")
    header = tuple(cell.strip().lower() for cell in rows[0])
    if header != DEMO_COLUMNS:
        raise PrimitiveError(
            f"{path}:1: expected columns t,x,y,z (seconds, metres), got {','.join(rows[0])}"
        )
    values = np.empty((len(rows) - 1, 4))
    for index, row in enumerate(rows[1:]):
        line = index + 2
        if len(row) != 4:
            raise PrimitiveError(f"{path}:{line}: expected 4 values (t,x,y,z), got {len(row)}")
        try:
            values[index] = [float(cell) for cell in row]
        except ValueError:
            raise PrimitiveError(f"{path}:{line}: not a number in {','.join(row)}") from None
        if not np.isfinite(values[index]).all():
            raise PrimitiveError(f"{path}:{line}: NaN or infinite value in {','.join(row)}")
    if len(values) < MIN_DEMO_SAMPLES:
        raise PrimitiveError(
            f"{path}: needs at least {MIN_DEMO_SAMPLES} samples, got {len(values)}"
        )
    steps = np.diff(values[:, 0])
    if (steps <= 0).any():
        index = int(np.argmax(steps <= 0)) + 1
        raise PrimitiveError(
            f"{path}:{index + 2}: time must increase strictly "
            f"(t = {values[index, 0]:g} after {values[index - 1, 0]:g})"
        )
    return values[:, 0].copy(), values[:, 1:].copy()


def write_demo_csv(path: Path, t: np.ndarray, y: np.ndarray) -> None:
    """Write t (T,), y (T, 3) as CSV t,x,y,z with round-trip precision."""
    lines = [",".join(DEMO_COLUMNS)]
    rows = zip(np.asarray(t).tolist(), np.asarray(y).tolist(), strict=True)
    lines += [f"{ti!r},{p[0]!r},{p[1]!r},{p[2]!r}" for ti, p in rows]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def prepare_demo(
    t: np.ndarray, y: np.ndarray, settings: Preprocessing, where: str = "demonstration"
) -> tuple[np.ndarray, np.ndarray]:
    """Resample to a uniform rate, smooth, and trim still ends (in that order)."""
    t = np.asarray(t, float) - float(t[0])
    y = np.asarray(y, float)
    steps = np.diff(t)
    rate = settings.rate_hz or 1.0 / float(np.median(steps))
    uneven = np.abs(steps - np.median(steps)).max() > 0.01 * np.median(steps)
    if settings.rate_hz is not None or uneven:
        count = max(int(round(t[-1] * rate)) + 1, MIN_DEMO_SAMPLES)
        grid = np.linspace(0.0, t[-1], count)
        y = np.stack([np.interp(grid, t, y[:, axis]) for axis in range(3)], axis=1)
        t = grid
    if settings.smooth_s > 0:
        from scipy.signal import savgol_filter

        window = int(round(settings.smooth_s * rate)) | 1
        if window >= 5:
            if window > len(t):
                raise PrimitiveError(
                    f"{where}: smoothing window {settings.smooth_s} s is longer than the demo"
                )
            y = savgol_filter(y, window, 3, axis=0, mode="interp")
    if settings.trim_mm > 0:
        tolerance = settings.trim_mm / 1000.0
        moved_from_start = np.linalg.norm(y - y[0], axis=1) > tolerance
        moved_from_end = np.linalg.norm(y - y[-1], axis=1) > tolerance
        if not moved_from_start.any():
            raise PrimitiveError(
                f"{where}: the tool never moves more than {settings.trim_mm} mm; nothing to learn"
            )
        first = max(int(np.argmax(moved_from_start)) - 1, 0)
        last = min(len(t) - int(np.argmax(moved_from_end[::-1])), len(t) - 1)
        t, y = t[first : last + 1] - t[first], y[first : last + 1]
    if len(t) < MIN_DEMO_SAMPLES:
        raise PrimitiveError(f"{where}: fewer than {MIN_DEMO_SAMPLES} samples after trimming")
    return t, y


def fit_rmse(dmp: DMP, t: np.ndarray, y: np.ndarray) -> float:
    """RMS distance (metres) between the demo and the fitted rollout at the demo's time stamps."""
    fine = dmp.rollout(dmp.demo_start, dmp.demo_goal, num=max(4 * len(t), 1000))
    at = np.stack([np.interp(t - t[0], fine.t, fine.y[:, axis]) for axis in range(3)], axis=1)
    return float(np.sqrt(((at - y) ** 2).sum(axis=1).mean()))


def learn_primitive(
    name: str,
    demo: Path,
    *,
    description: str,
    family: str = "cutting",
    mode: str = "similarity",
    nominal_speed: float = 0.03,
    n_basis: int = 50,
    preprocessing: Preprocessing | None = None,
    out_dir: Path | None = None,
) -> Primitive:
    """Fit a primitive to a demonstration CSV. With out_dir, the prepared demonstration is
    written there as NAME.csv (unless it is already that file) and the primitive as NAME.yaml."""
    _check_name(name, "name")
    demo = Path(demo)
    settings = preprocessing or Preprocessing()
    t_raw, y_raw = load_demo_csv(demo)
    t, y = prepare_demo(t_raw, y_raw, settings, str(demo))
    dmp = DMP.fit(t, y, n_basis=n_basis)
    primitive = Primitive(
        name=name,
        description=description.strip(),
        family=_check_choice(family, FAMILIES, "family", str(demo)),  # type: ignore[arg-type]
        mode=_check_choice(mode, RETARGET_MODES, "mode", str(demo)),
        nominal_speed=_positive(nominal_speed, "nominal_speed", str(demo)),
        dmp=dmp,
        demo=demo,
        fit_rmse=fit_rmse(dmp, t, y),
        preprocessing=settings,
        source=None,
    )
    if out_dir is None:
        return primitive
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    demo_out = out_dir / f"{name}.csv"
    if demo_out.resolve() != demo.resolve():
        write_demo_csv(demo_out, t, y)
        applied = ", ".join(f"{k}={v}" for k, v in settings.to_dict().items())
        source = f"{demo} ({applied})"
        # The saved demo is already prepared: refitting it needs no further preprocessing.
        primitive = replace(primitive, preprocessing=Preprocessing(trim_mm=0.0), source=source)
    primitive = replace(primitive, demo=demo_out)
    save_primitive(primitive, out_dir / f"{name}.yaml")
    return replace(primitive, path=out_dir / f"{name}.yaml")


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
        "fit_rmse_m": primitive.fit_rmse,
        "preprocessing": primitive.preprocessing.to_dict(),
        "dmp": primitive.dmp.to_dict(),
    }


def save_primitive(primitive: Primitive, path: Path) -> None:
    """Write the primitive as YAML (floats written to round-trip exactly)."""
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


def load_primitive(path: Path) -> Primitive:
    """Read and validate a primitive YAML file; every problem names the file and the field."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
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
    where = str(path)
    if not isinstance(data, dict):
        raise PrimitiveError(f"{where}: expected a mapping of primitive fields")
    known = {
        "format", "name", "description", "family", "mode", "nominal_speed", "demo", "source",
        "fit_rmse_m", "preprocessing", "dmp",
    }  # fmt: skip
    unknown = sorted(set(data) - known)
    if unknown:
        raise PrimitiveError(f"{where}: unknown field {unknown[0]!r}")
    if data.get("format", FORMAT) != FORMAT:
        raise PrimitiveError(f"{where}: format {data.get('format')!r} is not {FORMAT!r}")
    for key in ("name", "description", "family", "dmp"):
        if key not in data:
            raise PrimitiveError(f"{where}: field {key!r} is missing")
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
    source = data.get("source")
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
        path=path,
    )


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
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
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

BUNDLED_DIR = Path(__file__).resolve().parent.parent / "primitives"
"""The dictionary shipped in the source tree (found last)."""


def default_search_dirs(task_folder: Path) -> list[Path]:
    """Where primitives are looked for, first match wins: the task folder's ../primitives and
    primitives/, each folder in KEYMPS_PRIMITIVES_PATH, ./primitives, the bundled dictionary."""
    task_folder = Path(task_folder)
    dirs = [task_folder / ".." / "primitives", task_folder / "primitives"]
    env = os.environ.get("KEYMPS_PRIMITIVES_PATH", "")
    dirs += [Path(part) for part in env.split(os.pathsep) if part.strip()]
    dirs += [Path.cwd() / "primitives", BUNDLED_DIR]
    unique: list[Path] = []
    for folder in dirs:
        resolved = folder.resolve()
        if resolved not in unique:
            unique.append(resolved)
    return unique


def find_primitive_files(search_dirs: Sequence[Path]) -> dict[str, Path]:
    """Primitive name -> YAML file, the first search dir holding a name winning."""
    found: dict[str, Path] = {}
    for folder in search_dirs:
        folder = Path(folder)
        if not folder.is_dir():
            continue
        for file in sorted(folder.glob("*.yaml")):
            found.setdefault(file.stem, file)
    return found


def load_primitives(names: Sequence[str], search_dirs: Sequence[Path]) -> dict[str, Primitive]:
    """Load the named primitives from the first search dir that has each (NAME.yaml)."""
    available = find_primitive_files(search_dirs)
    result: dict[str, Primitive] = {}
    for name in names:
        if name not in available:
            listing = ", ".join(sorted(available)) or "none"
            searched = ", ".join(str(d) for d in search_dirs)
            raise PrimitiveError(
                f"unknown primitive {name!r}; available: {listing} (searched {searched})"
            )
        primitive = load_primitive(available[name])
        if primitive.name != name:
            raise PrimitiveError(
                f"{available[name]}: name {primitive.name!r} does not match the file name {name!r}"
            )
        result[name] = primitive
    return result
