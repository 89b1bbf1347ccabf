"""Trajectory files: the run folder's CSV and a JSON in the shape of a ROS JointTrajectory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from keymps.errors import KeympsError
from keymps.run_files import write_atomically
from keymps.types import Trajectory

CSV_HEADER = "t,q1,q2,q3,q4,q5,q6,x,y,z,piece,kind"
"""The header of a six-joint arm's trajectory; an arm of n joints has q1..qn (csv_header)."""


def csv_header(joints: int) -> str:
    """`t,q1,...,qN,x,y,z,piece,kind` for an arm of `joints` joints."""
    return ",".join(["t", *(f"q{i}" for i in range(1, joints + 1)), "x", "y", "z", "piece", "kind"])


def write_trajectory_csv(trajectory: Trajectory, path: str | Path) -> Path:
    """One row per controller sample: seconds, radians, tool tip metres (board), piece, kind."""
    path = Path(path)
    _write_text(path, trajectory_csv(trajectory))
    return path


def trajectory_csv(trajectory: Trajectory) -> bytes:
    """The CSV's bytes: what `ROW % (t, q1..q6, x, y, z, piece, kind)` gives row by row,
    formatted column by column in numpy (Python's float formatting would take most of a run's
    writing time)."""
    rows = len(np.asarray(trajectory.t).reshape(-1))
    joints = (
        int(np.shape(trajectory.q)[1])
        if np.ndim(trajectory.q) == 2
        else len(trajectory.joint_names)
    )
    header = csv_header(joints)
    if rows == 0:
        return (header + "\n").encode()
    fields = [
        _number_chars(np.asarray(trajectory.t, dtype=float).reshape(-1, 1), 6),
        _number_chars(np.asarray(trajectory.q, dtype=float).reshape(rows, joints), 9),
        _number_chars(np.asarray(trajectory.tool_xyz, dtype=float).reshape(rows, 3), 6),
        _number_chars(np.asarray(trajectory.piece_index).astype(float).reshape(-1, 1), None),
        _string_chars([str(kind) for kind in trajectory.kind])[:, None, :],
    ]
    cells = [
        np.concatenate([field, np.full((*field.shape[:2], 1), ord(","), np.uint8)], axis=2)
        for field in fields
    ]
    chars = np.concatenate([cell.reshape(rows, -1) for cell in cells], axis=1)
    chars[:, -1] = ord("\n")  # the last field's comma
    flat = chars.ravel()
    return (header + "\n").encode() + flat[flat != _PAD].tobytes()


ROW = ",".join(["%.6f"] + ["%.9f"] * 6 + ["%.6f"] * 3 + ["%d", "%s"])
"""The format of one row of a six-joint arm (what `trajectory_csv` writes, without Python's
per-value cost): one "%.9f" per joint."""
_PAD = 0
"""Fills each value's characters up to its column's widest; dropped when the rows are joined."""
_QUADS: np.ndarray | None = None


def _quads() -> np.ndarray:
    """(10000,) the ASCII digits of 0000 .. 9999, four bytes in one uint32 each."""
    global _QUADS
    if _QUADS is None:
        text = "".join(f"{i:04d}" for i in range(10_000)).encode()
        _QUADS = np.frombuffer(text, np.uint32)
    return _QUADS


def _number_chars(values: np.ndarray, decimals: int | None) -> np.ndarray:
    """(n, m, width) ASCII of `"%.<decimals>f" % v` (`"%d"` for decimals None: whole numbers)
    for values (n, m), padded with _PAD.

    |v| * 10**decimals rounded to the nearest integer is the correctly rounded decimal unless
    the product lies within its own rounding error of a half: there the exact product decides
    (half to even, as Python). Huge (2**52 and more) and non-finite values are formatted by
    Python."""
    places = decimals or 0
    with np.errstate(invalid="ignore"):
        magnitude = np.abs(values * 10.0**places)
        fraction = magnitude - np.floor(magnitude)
        exact = magnitude < 2.0**52
        near_half = exact & (np.abs(fraction - 0.5) <= magnitude * 2.0**-50)
    units = np.rint(np.where(exact, magnitude, 0.0)).astype(np.int64)
    if near_half.any():
        units[near_half] = _round_exactly(np.abs(values[near_half]), 10.0**places)
    whole = units // 10**places
    width = len(str(int(whole.max(initial=0))))
    count = np.ones(whole.shape, np.int64)  # digits of each whole part
    for exponent in range(1, width):
        count += whole >= 10**exponent
    groups = -(-(width + places) // 4)
    chunks = np.stack([(units // 10 ** (4 * k)) % 10_000 for k in range(groups - 1, -1, -1)], -1)
    digits = _quads().take(chunks).view(np.uint8).reshape(*values.shape, 4 * groups)
    digits = digits[..., 4 * groups - places - width :]
    leading = np.arange(width) < (width - count)[..., None]
    digits[..., :width][leading] = _PAD  # zeros before the whole part's first digit
    negative = np.signbit(values) if decimals is not None else values < 0  # "%d" % -0.0: "0"
    sign = np.where(negative, ord("-"), _PAD).astype(np.uint8)[..., None]
    parts = [sign, digits[..., :width]]
    if decimals is not None:
        parts += [np.full((*values.shape, 1), ord("."), np.uint8), digits[..., width:]]
    return _python_formatted(np.concatenate(parts, axis=-1), values, ~exact, decimals)


def _round_exactly(values: np.ndarray, power: float) -> np.ndarray:
    """round(values * power), half to even, from the exact product (Dekker's two-product:
    product + error, both doubles); power is a power of ten up to 10**22, values below 2**52
    / power."""
    product = values * power
    value_high, value_low = _split(values)
    power_high, power_low = _split(np.asarray(power))
    error = (
        (value_high * power_high - product) + value_high * power_low + value_low * power_high
    ) + value_low * power_low
    below = np.floor(product)
    beyond_half = (product - (below + 0.5)) + error  # the sign is exact
    odd = below % 2 == 1
    up = (beyond_half > 0) | ((beyond_half == 0) & odd)
    return (below + up).astype(np.int64)


def _split(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Veltkamp's split of doubles into two halves of 26 bits: high + low == values exactly."""
    scaled = 134217729.0 * values  # 2**27 + 1
    high = scaled - (scaled - values)
    return high, values - high


def _python_formatted(
    chars: np.ndarray, values: np.ndarray, which: np.ndarray, decimals: int | None
) -> np.ndarray:
    """`chars` with the values at `which` formatted by Python instead (right-aligned)."""
    at = list(zip(*np.nonzero(which), strict=True))
    if not at:
        return chars
    pattern = f"%.{decimals}f" if decimals is not None else "%d"
    texts = [(pattern % values[i, j]).encode() for i, j in at]
    extra = max(len(text) for text in texts) - chars.shape[-1]
    if extra > 0:
        pad = np.full((*chars.shape[:2], extra), _PAD, np.uint8)
        chars = np.concatenate([pad, chars], axis=-1)
    for (i, j), text in zip(at, texts, strict=True):
        chars[i, j] = _PAD
        chars[i, j, chars.shape[-1] - len(text) :] = np.frombuffer(text, np.uint8)
    return chars


def _string_chars(texts: list[str]) -> np.ndarray:
    """(n, width) the UTF-8 bytes of each text, padded with _PAD."""
    unique, index = np.unique(np.asarray(texts, dtype=str), return_inverse=True)
    encoded = [text.encode() for text in unique.tolist()]
    width = max((len(e) for e in encoded), default=0)
    table = np.full((len(encoded), width), _PAD, np.uint8)
    for row, text in enumerate(encoded):
        table[row, : len(text)] = np.frombuffer(text, np.uint8)
    return table[index.reshape(-1)]


def read_trajectory_csv(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a trajectory CSV: t (n,), q (n, joints), xyz (n, 3), piece (n,), kind (n,)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise KeympsError(f"{path}: cannot read: {error.strerror}") from None
    names = lines[0].strip().split(",") if lines else []
    joints = len(names) - 6
    if joints < 1 or lines[0].strip() != csv_header(joints):
        raise KeympsError(f"{path}:1: expected the header {CSV_HEADER} (q1..qN for N joints)")
    width = len(names)
    numbers, kinds = [], []
    for number, line in enumerate(lines[1:], start=2):
        fields = line.split(",")
        try:
            if len(fields) != width:
                raise ValueError(f"{len(fields)} fields instead of {width}")
            numbers.append([float(v) for v in fields[: width - 1]])
        except ValueError as error:
            raise KeympsError(f"{path}:{number}: {error}") from None
        kinds.append(fields[width - 1].strip())
    table = np.array(numbers, dtype=float).reshape(-1, width - 1)
    return {
        "t": table[:, 0],
        "q": table[:, 1 : 1 + joints],
        "xyz": table[:, 1 + joints : 4 + joints],
        "piece": table[:, 4 + joints].astype(int),
        "kind": np.array(kinds),
    }


def time_from_start_ns(t: np.ndarray) -> np.ndarray:
    """(n,) int64 nanoseconds of the times `t` (seconds), rounded to the nearest ns: a ROS
    Duration is `divmod(ns, 10**9)` of these (sec, nanosec)."""
    return np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def joint_trajectory_message(trajectory: Trajectory) -> dict[str, object]:
    """trajectory_msgs/JointTrajectory as plain data (header left for the consumer to stamp)."""
    seconds, nanoseconds = np.divmod(time_from_start_ns(trajectory.t), 1_000_000_000)
    points = [
        {
            "positions": q,
            "velocities": qd,
            "accelerations": qdd,
            "effort": [],
            "time_from_start": {"sec": sec, "nanosec": nanosec},
        }
        for q, qd, qdd, sec, nanosec in zip(
            np.asarray(trajectory.q, dtype=float).tolist(),
            np.asarray(trajectory.qd, dtype=float).tolist(),
            np.asarray(trajectory.qdd, dtype=float).tolist(),
            seconds.astype(int).tolist(),
            nanoseconds.astype(int).tolist(),
            strict=True,
        )
    ]
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "joint_names": list(trajectory.joint_names),
        "points": points,
    }


def write_joint_trajectory_json(trajectory: Trajectory, path: str | Path) -> Path:
    """The trajectory as a ROS 2 JointTrajectory message in JSON."""
    path = Path(path)
    _write_text(path, json.dumps(joint_trajectory_message(trajectory), separators=(",", ":")))
    return path


def _write_text(path: Path, text: str | bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, text)
    except OSError as error:
        raise KeympsError(f"{path}: cannot write: {error.strerror}") from None
