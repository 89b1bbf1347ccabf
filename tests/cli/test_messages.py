"""Small output defects a new user hit (issue 19 item 8): rays described as rays, a rationale
that says what named the primitive, a legend for `primitives plot`, a learned primitive's YAML
that says how its demonstration was cleaned."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from helpers.synthetic_crops import make_scene, plan_for

from keymps.cli.primitives import primitives
from keymps.default_plugins.offline import choose_primitive
from keymps.primitives.demos import Preprocessing, write_demo_csv
from keymps.primitives.dictionary import learn_primitive, load_primitive

CUTTING = {
    "straight": "Straight cut down through the object. For soft objects (cake, banana).",
    "rocking": "Rocking cut: rock the blade forward and back while descending.",
}


@pytest.mark.parametrize("parts", [3, 5, 7, 9, 4, 6, 8])
def test_wedges_of_a_round_cake_are_described_as_what_they_are(parts: int) -> None:
    plan, _ = plan_for(f"Cut it into {parts} equal slices", make_scene("disk", (200, 200)))
    if parts % 2:
        assert (
            "rays from the centre" in plan.rationale and "through the centre" not in plan.rationale
        )
    else:
        assert "cuts through the centre" in plan.rationale


def test_the_rationale_says_whether_the_sentence_or_the_task_name_named_the_primitive() -> None:
    sentence = "Cut it into 4 slices"
    chosen, why = choose_primitive("cut", CUTTING, sentence, "rocking-eggplant")
    assert (chosen, why) == ("rocking", "the task's name (rocking-eggplant) names it")
    chosen, why = choose_primitive("cut", CUTTING, f"{sentence} with a rocking cut", "eggplant")
    assert (chosen, why) == ("rocking", "the sentence names it")


def test_primitives_plot_has_a_legend_entry_per_rollout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.figure

    saved: list[Any] = []
    original = matplotlib.figure.Figure.savefig

    def keep(self: Any, *args: Any, **kwargs: Any) -> None:
        saved.append([t.get_text() for t in self.axes[0].get_legend().get_texts()])
        original(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep)
    out = tmp_path / "plot.png"
    result = CliRunner().invoke(primitives, ["plot", "sawing", "--out", str(out)])
    assert result.exit_code == 0, result.output
    (labels,) = saved
    assert labels[0] == "demonstration" and labels[-1] == "start"
    assert labels[1:-1] == [
        "1: fit: the demonstration's own goal",
        "2: goal turned 90 degrees about z",
        "3: 1.5 times longer",
    ]
    saved.clear()
    args = ["plot", "sawing", "--to", "0.1,0.05,0", "--to", "0,0.1,0", "--out", str(out)]
    assert CliRunner().invoke(primitives, args).exit_code == 0
    assert saved[0][1:-1] == ["1: to (0.1, 0.05, 0)", "2: to (0, 0.1, 0)"]


def test_a_learned_primitive_says_how_its_demonstration_was_cleaned(tmp_path: Path) -> None:
    t = np.arange(0, 3.0, 0.002)
    y = np.stack([0.1 * t / 3, 0 * t, 0.05 * (1 - t / 3)], axis=1)
    y += np.random.default_rng(0).normal(0, 1e-4, y.shape)
    write_demo_csv(tmp_path / "log.csv", t, y)
    settings = Preprocessing(smooth_s=0.05, trim_mm=0.5)
    learn_primitive(
        "mine", tmp_path / "log.csv", description="x", preprocessing=settings, out_dir=tmp_path
    )
    data = yaml.safe_load((tmp_path / "mine.yaml").read_text())
    assert data["source"] == str(tmp_path / "log.csv")
    assert data["source_preprocessing"] == {"rate_hz": None, "smooth_s": 0.05, "trim_mm": 0.5}
    # what refitting the saved, already prepared demo applies: nothing
    assert data["preprocessing"] == {"rate_hz": None, "smooth_s": 0.0, "trim_mm": 0.0}
    again = load_primitive(tmp_path / "mine.yaml")
    assert again.source_preprocessing == settings
    shown = CliRunner().invoke(primitives, ["show", "mine", "--dir", str(tmp_path)])
    assert "cleaned with:  rate_hz None, smooth_s 0.05, trim_mm 0.5" in shown.output
