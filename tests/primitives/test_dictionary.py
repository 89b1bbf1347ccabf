"""keymps.primitives.dictionary: the bundled dictionary, the file format, learning, bad input."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from keymps.errors import KeympsError
from keymps.primitives.demos import (
    Preprocessing,
    fit_rmse,
    load_demo_csv,
    prepare_demo,
    write_demo_csv,
)
from keymps.primitives.dictionary import (
    BUNDLED_DIR,
    default_search_dirs,
    learn_primitive,
    load_primitive,
    load_primitives,
    save_primitive,
)
from keymps.primitives.dmp import DMP

NAMES = ["straight", "sawing", "downward", "forward", "line"]


@pytest.fixture(scope="module")
def bundled() -> dict:
    return load_primitives(NAMES, [BUNDLED_DIR])


def test_all_five_primitives_ship_with_demo_and_weights(bundled: dict) -> None:
    for name in NAMES:
        primitive = bundled[name]
        assert primitive.name == name
        assert primitive.description.strip()
        assert primitive.family == ("icing" if name == "line" else "cutting")
        assert primitive.demo is not None and primitive.demo.is_file()
        assert primitive.dmp.n_basis == 50
        assert 0 < primitive.fit_rmse <= 0.0005
        assert 0.005 <= primitive.nominal_speed <= 0.1


@pytest.mark.parametrize("name", NAMES)
def test_shipped_weights_are_the_fit_of_the_shipped_demo(bundled: dict, name: str) -> None:
    primitive = bundled[name]
    t, y = prepare_demo(*load_demo_csv(primitive.demo), primitive.preprocessing)
    refit = DMP.fit(t, y, n_basis=primitive.dmp.n_basis)
    # Weights are compared through what they do (they are ill-conditioned at the 1e-5 level).
    for goal in ([0.1, 0.0, 0.0], [0.0, 0.2, -0.05]):
        a = refit.rollout([0, 0, 0.05], goal).y
        b = primitive.dmp.rollout([0, 0, 0.05], goal).y
        assert np.abs(a - b).max() < 1e-6
    assert fit_rmse(refit, t, y) == pytest.approx(primitive.fit_rmse, rel=1e-3, abs=1e-8)
    rollout = primitive.dmp.rollout(y[0], y[-1], num=len(t))
    assert np.sqrt(((rollout.y - y) ** 2).sum(axis=1).mean()) <= 0.0005


def test_demos_have_realistic_shapes(bundled: dict) -> None:
    t, y = load_demo_csv(bundled["straight"].demo)
    assert np.abs(y[:, :2]).max() < 1e-9 and y[0, 2] - y[-1, 2] == pytest.approx(0.05)
    t, y = load_demo_csv(bundled["sawing"].demo)
    assert y[0, 2] - y[-1, 2] == pytest.approx(0.05)
    velocity = np.diff(y[:, 0])
    reversals = np.count_nonzero(np.diff(np.sign(velocity[np.abs(velocity) > 1e-7])) != 0)
    assert 6 <= reversals <= 8  # 3-4 forward-backward strokes
    detrended = y[:, 0] - 0.10 * (
        10 * (t / t[-1]) ** 3 - 15 * (t / t[-1]) ** 4 + 6 * (t / t[-1]) ** 5
    )
    assert 0.015 <= np.abs(detrended).max() <= 0.025
    t, y = load_demo_csv(bundled["line"].demo)
    assert y[:, 2].min() == pytest.approx(-0.004)
    assert y[-1] == pytest.approx([0.05, 0.0, 0.0])


def test_save_and_load_round_trip_exactly(bundled: dict, tmp_path: Path) -> None:
    for primitive in bundled.values():
        copy = replace(primitive, demo=tmp_path / f"{primitive.name}.csv")
        save_primitive(copy, tmp_path / f"{primitive.name}.yaml")
        again = load_primitive(tmp_path / f"{primitive.name}.yaml")
        assert np.array_equal(again.dmp.weights, primitive.dmp.weights)
        for key in ("name", "description", "family", "mode", "nominal_speed", "fit_rmse"):
            assert getattr(again, key) == getattr(primitive, key)
        assert again.demo == tmp_path / f"{primitive.name}.csv"
        assert again.dmp.demo_duration == primitive.dmp.demo_duration
        save_primitive(again, tmp_path / "again.yaml")
        first = (tmp_path / f"{primitive.name}.yaml").read_text()
        assert (tmp_path / "again.yaml").read_text() == first


def test_rollout_at_speed_is_dense_and_timed(bundled: dict) -> None:
    sawing = bundled["sawing"]
    rollout = sawing.rollout([0.1, 0.05, 0.055], [0.1, 0.17, 0.0], speed=0.05)
    steps = np.linalg.norm(np.diff(rollout.y, axis=0), axis=1)
    assert steps.max() <= 0.001
    assert rollout.length_m / rollout.t[-1] == pytest.approx(0.05, rel=1e-3)
    assert np.allclose(rollout.y[-1], [0.1, 0.17, 0.0], atol=1e-6)


def test_unknown_primitive_lists_what_exists(tmp_path: Path) -> None:
    with pytest.raises(KeympsError, match="unknown primitive 'chop'; available: downward, forward"):
        load_primitives(["chop"], [BUNDLED_DIR])


def test_first_search_dir_wins_and_env_path_is_searched(
    bundled: dict, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    task_folder = tmp_path / "tasks"
    (task_folder / "primitives").mkdir(parents=True)
    own = replace(bundled["line"], description="My own line.", demo=None)
    save_primitive(own, task_folder / "primitives" / "line.yaml")
    extra = tmp_path / "extra"
    extra.mkdir()
    save_primitive(replace(bundled["sawing"], name="saw2", demo=None), extra / "saw2.yaml")
    monkeypatch.setenv("KEYMPS_PRIMITIVES_PATH", str(extra))
    monkeypatch.chdir(tmp_path)
    dirs = default_search_dirs(task_folder)
    assert dirs[:3] == [tmp_path / "primitives", task_folder / "primitives", extra]
    assert dirs[-1] == BUNDLED_DIR
    found = load_primitives(["line", "saw2", "sawing"], dirs)
    assert found["line"].description == "My own line."
    assert found["saw2"].name == "saw2"
    assert found["sawing"].path == BUNDLED_DIR / "sawing.yaml"


def test_name_must_match_file(bundled: dict, tmp_path: Path) -> None:
    save_primitive(replace(bundled["line"], demo=None), tmp_path / "dots.yaml")
    with pytest.raises(KeympsError, match="does not match the file name 'dots'"):
        load_primitives(["dots"], [tmp_path])


def _demo(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "demo.csv"
    path.write_text(text)
    return path


GOOD_ROWS = "".join(f"{i * 0.1},{i * 0.01},0,0\n" for i in range(12))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,x,y\n" + GOOD_ROWS, r"demo.csv:1: expected columns t,x,y,z"),
        ("t,x,y,z\n" + GOOD_ROWS.replace("0.05,0,0", "nan,0,0"), r"demo.csv:7: NaN"),
        ("t,x,y,z\n" + "".join(f"{i},0,0,0\n" for i in range(5)), "at least 10 samples, got 5"),
        ("t,x,y,z\n" + GOOD_ROWS + "0.5,0,0,0\n", r"demo.csv:14: time must increase"),
        ("t,x,y,z\n" + GOOD_ROWS + "2.0,abc,0,0\n", r"demo.csv:14: not a number"),
        ("t,x,y,z\n" + GOOD_ROWS + "2.0,0,0\n", r"demo.csv:14: expected 4 values"),
        ("", "empty demonstration"),
    ],
)
def test_bad_demo_files_give_one_line_naming_the_file(
    tmp_path: Path, text: str, message: str
) -> None:
    with pytest.raises(KeympsError, match=message) as info:
        load_demo_csv(_demo(tmp_path, text))
    assert "\n" not in str(info.value)
    assert str(tmp_path / "demo.csv") in str(info.value)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["dmp"].pop("weights"), "dmp.weights is missing"),
        (
            lambda d: d["dmp"].update(weights=d["dmp"]["weights"][:-3]),
            "has 47 rows but dmp.n_basis",
        ),
        (lambda d: d["dmp"].update(weights=[[1, 2]] * 50), "row 1 is 2 values; each row is"),
        (lambda d: d["dmp"].update(weights="none"), r"list of \[wx, wy, wz\] rows"),
        (
            lambda d: d["dmp"]["weights"][4].append(0.5),
            r"dmp.weights row 5 is 4 values; each row is \[wx, wy, wz\]",
        ),
        (lambda d: d["dmp"]["weights"].__setitem__(0, 7), "dmp.weights row 1 is 7; each row"),
        (lambda d: d["dmp"]["weights"][3].__setitem__(1, float("nan")), "NaN"),
        (lambda d: d.pop("dmp"), "field 'dmp' is missing"),
        (lambda d: d.update(family="baking"), "family 'baking' is not one of cutting, icing"),
        (lambda d: d.update(mode="mirror"), "mode 'mirror'"),
        (lambda d: d.update(nominal_speed=-1), "nominal_speed must be positive"),
        (lambda d: d.update(speed=1), "unknown field 'speed'"),
        (lambda d: d.update({1: 2, "speed": 1}), "unknown field 1"),
    ],
)
def test_bad_primitive_files_give_one_line_naming_the_file(
    tmp_path: Path, edit, message: str
) -> None:
    data = yaml.safe_load((BUNDLED_DIR / "line.yaml").read_text())
    edit(data)
    path = tmp_path / "line.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(KeympsError, match=message) as info:
        load_primitive(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_invalid_yaml_names_line(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text("name: x\ndmp: [1, 2\n")
    with pytest.raises(KeympsError, match=r"x.yaml:\d+:\d+: invalid YAML"):
        load_primitive(path)


def robot_log(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The sawing demo as a 125 Hz robot would log it: jittered clock, 0.2 mm noise, 1 s still
    at both ends and a 0.4 s pause in the middle."""
    t_demo, y_demo = load_demo_csv(BUNDLED_DIR / "sawing.csv")
    motion_time = np.concatenate([np.zeros(125), np.linspace(0, 2.5, 313),
                                  np.full(50, 2.5), np.linspace(2.5, 5.0, 313)[1:],
                                  np.full(125, 5.0)])  # fmt: skip
    t = np.arange(len(motion_time)) / 125.0 + rng.uniform(-0.002, 0.002, len(motion_time))
    clean = np.stack([np.interp(motion_time, t_demo, y_demo[:, k]) for k in range(3)], axis=1)
    return t + 1000.0, clean + rng.normal(0, 0.0002, clean.shape), clean, motion_time


def test_learning_from_a_noisy_robot_log_with_pauses(tmp_path: Path) -> None:
    t, noisy, clean, _ = robot_log(np.random.default_rng(3))
    log = tmp_path / "robot_log.csv"
    write_demo_csv(log, t, noisy)
    settings = Preprocessing(rate_hz=100.0, smooth_s=0.08, trim_mm=1.0)
    primitive = learn_primitive(
        "saw-log", log, description="Sawing learned from a log.", preprocessing=settings,
        out_dir=tmp_path / "out",
    )  # fmt: skip
    assert primitive.path == tmp_path / "out" / "saw-log.yaml"
    # Still ends trimmed: the 1 s waits at both ends are gone, the mid pause stays.
    assert 5.0 <= primitive.dmp.demo_duration <= 5.5
    assert np.linalg.norm(primitive.dmp.demo_start - clean[0]) < 0.0015
    assert np.linalg.norm(primitive.dmp.demo_goal - clean[-1]) < 0.0015
    assert primitive.fit_rmse < 0.0005
    # The learned path follows the clean motion within 1 mm.
    rollout = primitive.dmp.rollout(primitive.dmp.demo_start, primitive.dmp.demo_goal, num=4000)
    distances = np.linalg.norm(rollout.y[:, None, :] - clean[None, ::4, :], axis=2)
    assert distances.min(axis=0).max() < 0.001
    again = load_primitive(tmp_path / "out" / "saw-log.yaml")
    assert again.demo == tmp_path / "out" / "saw-log.csv"
    assert again.source is not None and "robot_log.csv" in again.source
    refit = learn_primitive(
        "saw-log", again.demo, description="x", preprocessing=again.preprocessing
    )
    a = refit.dmp.rollout([0, 0, 0], [0.1, 0, 0]).y
    assert np.abs(a - again.dmp.rollout([0, 0, 0], [0.1, 0, 0]).y).max() < 1e-8


def test_the_default_trim_finds_the_still_ends_of_a_raw_noisy_log(tmp_path: Path) -> None:
    """No smoothing asked for: 0.2 mm of noise takes single samples past the 0.5 mm trim
    distance, which used to leave both 1 s waits in the primitive (7.4 s instead of 5.4 s)."""
    t, noisy, clean, _ = robot_log(np.random.default_rng(4))
    write_demo_csv(tmp_path / "raw.csv", t, noisy)
    primitive = learn_primitive("raw", tmp_path / "raw.csv", description="Raw log.")
    assert primitive.preprocessing == Preprocessing()  # the CLI's defaults: trim 0.5 mm only
    assert 5.0 <= primitive.dmp.demo_duration <= 5.6
    assert np.linalg.norm(primitive.dmp.demo_start - clean[0]) < 0.0015
    assert np.linalg.norm(primitive.dmp.demo_goal - clean[-1]) < 0.0015


@pytest.mark.parametrize(
    ("column", "message"),
    [
        (slice(1, 4), r"moves over 130\.\d+ m; positions must be metres \(a log in millimetres"),
        (slice(0, 1), r"lasts 5000 s; time must be seconds \(a log in milliseconds"),
    ],
)
def test_a_log_in_millimetres_or_milliseconds_is_one_error_line(
    tmp_path: Path, column: slice, message: str
) -> None:
    """Both used to be learned: a 130 m sawing stroke, or an 83-minute one."""
    t, y = load_demo_csv(BUNDLED_DIR / "sawing.csv")
    values = np.column_stack([t, y])
    values[:, column] *= 1000.0
    write_demo_csv(tmp_path / "log.csv", values[:, 0], values[:, 1:])
    with pytest.raises(KeympsError, match=message) as info:
        learn_primitive("log", tmp_path / "log.csv", description="x")
    assert "\n" not in str(info.value) and "log.csv" in str(info.value)


def test_a_log_where_nothing_moves_is_refused(tmp_path: Path) -> None:
    log = tmp_path / "still.csv"
    write_demo_csv(log, np.arange(50) / 10, np.zeros((50, 3)))
    with pytest.raises(KeympsError, match="never moves"):
        learn_primitive("still", log, description="x")


@pytest.mark.parametrize("name", NAMES)
def test_every_primitive_is_sampled_at_least_every_millimetre(bundled: dict, name: str) -> None:
    primitive = bundled[name]
    for goal in ([0.25, 0.0, 0.0], [0.0, 0.02, 0.05], [0.0, 0.0, 0.05]):
        rollout = primitive.rollout([0.0, 0.0, 0.05], goal, speed=0.05)
        assert np.linalg.norm(np.diff(rollout.y, axis=0), axis=1).max() <= 0.001


@pytest.mark.parametrize("name", ["straight", "sawing", "downward", "forward"])
def test_cuts_never_go_below_the_board_whatever_the_slope(bundled: dict, name: str) -> None:
    """Blade re-targeting keeps strokes level and scales only the depth: a cut from the top to
    the board (z = 0) never goes below it, whatever the segment's length and direction."""
    primitive = bundled[name]
    assert primitive.mode == "blade"
    for length, angle, height in [(0.03, 0.3, 0.06), (0.2, 2.0, 0.02), (0.1, -1.2, 0.08)]:
        start = np.array([0.1, 0.1, height])
        goal = start + [length * np.cos(angle), length * np.sin(angle), -height]
        y = primitive.rollout(start, goal, speed=0.03).y
        # The demos only ever descend; the fit may ripple by micrometres, strokes add nothing.
        assert y[:, 2].min() >= -1e-5
        assert (np.maximum.accumulate(y[::-1, 2])[::-1] - y[:, 2]).max() < 1e-5
        assert np.linalg.norm(y[-1] - goal) < 1e-6
