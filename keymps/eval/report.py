"""Summaries of an evaluation: summary.md, summary.csv, box plots of D and a gallery page."""

from __future__ import annotations

import csv
import html
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from keymps.eval.suites import Suite


@dataclass(frozen=True)
class Row:
    """One case x method line of the summary."""

    case: str
    method: str
    runs: int
    ok: int
    d_mm: tuple[float, ...]
    d_optimal_mm: tuple[float, ...]
    successes: int | None
    """equal_parts suites: runs whose cuts made the equal parts (None for other suites)."""
    keyword_ok: int | None
    """Runs that chose the ground truth's primitive (None without a ground truth)."""
    keyword_runs: int
    """Runs that chose a primitive at all."""
    vlm_calls: int
    cost_usd: float | None
    errors: tuple[str, ...]
    d_objects_mm: tuple[tuple[float | None, ...], ...] = ()
    """Several objects: per run, D of each object left to right (None: no work expected or
    none done there)."""
    right_objects: int | None = None
    """Several objects: runs whose work landed on exactly the objects meant."""

    @property
    def d_per_object(self) -> tuple[float | None, ...]:
        """Mean D of each object over the runs (None where no run has one)."""
        if not self.d_objects_mm:
            return ()
        columns = zip(*self.d_objects_mm, strict=False)
        return tuple(
            statistics.fmean(found) if (found := [d for d in column if d is not None]) else None
            for column in columns
        )

    @staticmethod
    def _stats(values: Sequence[float]) -> tuple[float, float, float] | None:
        if not values:
            return None
        std = statistics.pstdev(values) if len(values) > 1 else 0.0
        return statistics.fmean(values), std, statistics.median(values)

    @property
    def d_stats(self) -> tuple[float, float, float] | None:
        """(mean, std, median) of D in mm over the runs that generated a motion (including runs
        a later stage refused: their failure shows in `ok`)."""
        return self._stats(self.d_mm)

    @property
    def success_rate(self) -> float:
        count = self.successes if self.successes is not None else self.ok
        return count / self.runs if self.runs else 0.0


def summarize(records: list[dict[str, Any]], suite: Suite) -> list[Row]:
    order = {c.id: i for i, c in enumerate(suite.cases)}
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for record in records:
        groups.setdefault((record["case"], record["method"]), []).append(record)
    rows = []
    for (case, method), runs in sorted(
        groups.items(), key=lambda item: (order.get(item[0][0], 1e9), item[0][1])
    ):
        ok = [r for r in runs if r.get("ok")]
        costs = [r["cost_usd"] for r in runs if r.get("cost_usd") is not None]
        with_truth = [r for r in runs if r.get("truth_keyword") and r.get("keyword")]
        rows.append(
            Row(
                case=case,
                method=method,
                runs=len(runs),
                ok=len(ok),
                d_mm=tuple(r["d_mm"] for r in runs if r.get("d_mm") is not None),
                d_optimal_mm=tuple(
                    r["d_optimal_mm"] for r in runs if r.get("d_optimal_mm") is not None
                ),
                successes=(
                    sum(1 for r in runs if r.get("success"))
                    if suite.kind == "equal_parts"
                    else None
                ),
                keyword_ok=(
                    sum(1 for r in with_truth if r.get("keyword") == r["truth_keyword"])
                    if with_truth
                    else None
                ),
                keyword_runs=len(with_truth),
                vlm_calls=sum(int(r.get("vlm_calls") or 0) for r in runs),
                cost_usd=sum(costs) if costs else None,
                errors=tuple(sorted({r["error"] for r in runs if r.get("error")})),
                d_objects_mm=tuple(
                    tuple(r["d_objects_mm"]) for r in runs if r.get("d_objects_mm") is not None
                ),
                right_objects=(
                    sum(1 for r in runs if r.get("right_objects"))
                    if any("right_objects" in r for r in runs)
                    else None
                ),
            )
        )
    return rows


def _fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def markdown_table(rows: list[Row], suite: Suite) -> str:
    """The summary table in Markdown (what `keymps eval` prints and writes to summary.md)."""
    success_header = "equal parts" if suite.kind == "equal_parts" else "ok"
    several = any(row.right_objects is not None for row in rows)
    extra_header = " D per object mm | right objects |" if several else ""
    lines = [
        f"| case | method | runs | {success_header} | D mm (mean +- std) | D median | "
        f"D opt. mean |{extra_header} primitive ok | VLM calls | cost USD |",
        "|---|---|---|---|---|---|---|" + ("---|---|" if several else "") + "---|---|---|",
    ]
    for row in rows:
        stats = row.d_stats
        d_text = f"{stats[0]:.1f} +- {stats[1]:.1f}" if stats else "-"
        optimal = statistics.fmean(row.d_optimal_mm) if row.d_optimal_mm else None
        count = row.successes if row.successes is not None else row.ok
        keyword = f"{row.keyword_ok}/{row.keyword_runs}" if row.keyword_ok is not None else "-"
        extra = ""
        if several:
            per_object = " / ".join(_fmt(d) for d in row.d_per_object) or "-"
            right = f"{row.right_objects}/{row.runs}" if row.right_objects is not None else "-"
            extra = f" {per_object} | {right} |"
        lines.append(
            f"| {row.case} | {row.method} | {row.runs} | {count}/{row.runs} "
            f"({100 * row.success_rate:.0f} %) | {d_text} | {_fmt(stats[2] if stats else None)} "
            f"| {_fmt(optimal)} |{extra} {keyword} | {row.vlm_calls} | {_fmt(row.cost_usd, 4)} |"
        )
    return "\n".join(lines)


def _overall(rows: list[Row], suite: Suite) -> list[str]:
    lines = []
    for method in sorted({r.method for r in rows}):
        mine = [r for r in rows if r.method == method]
        runs = sum(r.runs for r in mine)
        good = sum((r.successes if r.successes is not None else r.ok) for r in mine)
        d_all = [d for r in mine for d in r.d_mm]
        text = f"- **{method}**: {good}/{runs} runs {'made the equal parts' if suite.kind == 'equal_parts' else 'ran'}"
        if d_all:
            text += f"; D over all cases {statistics.fmean(d_all):.1f} mm mean"
            text += f", {statistics.median(d_all):.1f} mm median"
        lines.append(text)
    return lines


def write_summary(records: list[dict[str, Any]], suite: Suite, out: Path) -> list[Row]:
    """summary.md, summary.csv, the box plot and gallery.html."""
    rows = summarize(records, suite)
    errors = [f"- case {r.case} / {r.method}: {e}" for r in rows for e in r.errors]
    text = [
        f"# {suite.name}: {suite.description}",
        "",
        f"{len(records)} runs. D is the paper's metric (Sec. V-B) in millimetres on the work "
        "pieces, over every run that generated a motion (also runs a later stage, e.g. the "
        "safety check, refused: those count as failures under ok); D opt. pairs the points "
        "optimally instead of greedily.",
        "",
        markdown_table(rows, suite),
        "",
        *_overall(rows, suite),
    ]
    if errors:
        text += ["", "## Failures", "", *errors]
    plots = write_box_plots(records, suite, out)
    if plots:
        text += ["", "## Box plots", "", *[f"![{p.stem}]({p.name})" for p in plots]]
    text += ["", "Plan and outcome images: [gallery.html](gallery.html).", ""]
    (out / "summary.md").write_text("\n".join(text), encoding="utf-8")
    _write_csv(rows, out / "summary.csv")
    write_gallery(records, suite, out)
    return rows


def _write_csv(rows: list[Row], path: Path) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(
            [
                "case", "method", "runs", "ok", "successes", "success_rate", "d_mean_mm",
                "d_std_mm", "d_median_mm", "d_optimal_mean_mm", "keyword_ok", "vlm_calls",
                "cost_usd",
            ]
        )  # fmt: skip
        for row in rows:
            stats = row.d_stats
            writer.writerow(
                [
                    row.case,
                    row.method,
                    row.runs,
                    row.ok,
                    row.successes if row.successes is not None else "",
                    round(row.success_rate, 4),
                    *([round(v, 3) for v in stats] if stats else ["", "", ""]),
                    round(statistics.fmean(row.d_optimal_mm), 3) if row.d_optimal_mm else "",
                    row.keyword_ok if row.keyword_ok is not None else "",
                    row.vlm_calls,
                    round(row.cost_usd, 6) if row.cost_usd is not None else "",
                ]
            )


def write_box_plots(records: list[dict[str, Any]], suite: Suite, out: Path) -> list[Path]:
    """d_boxplot.png (keymps.eval.box_plot): D per case, one box per method; none without D."""
    from keymps.eval.box_plot import write_box_plot

    values: dict[str, dict[str, list[float]]] = {}
    for record in records:
        d_mm = record.get("d_mm")
        if isinstance(d_mm, int | float) and math.isfinite(d_mm):  # (a hand-edited file's NaN)
            values.setdefault(record["method"], {}).setdefault(record["case"], []).append(d_mm)
    if not values:
        return []
    cases = [c.id for c in suite.cases if any(c.id in by_case for by_case in values.values())]
    title = f"{suite.name}: average error to the nearest unique ground-truth point"
    return [write_box_plot(values, cases, title, out / "d_boxplot.png")]


def write_gallery(records: list[dict[str, Any]], suite: Suite, out: Path) -> Path:
    """gallery.html: per case and method, the plan and outcome images of every run."""
    by_case: dict[str, list[dict[str, Any]]] = {}
    for record in records:
        by_case.setdefault(record["case"], []).append(record)
    instructions = {c.id: c.instruction for c in suite.cases}
    parts = [
        "<!doctype html><meta charset='utf-8'>",
        f"<title>{html.escape(suite.name)} gallery</title>",
        "<style>body{font-family:sans-serif}img{max-width:360px;margin:2px;border:1px solid #ccc}"
        "figure{display:inline-block;margin:4px}figcaption{font-size:12px}</style>",
        f"<h1>{html.escape(suite.name)}: {html.escape(suite.description)}</h1>",
    ]
    for case in [c.id for c in suite.cases if c.id in by_case]:
        parts.append(f"<h2>Case {html.escape(case)}: {html.escape(instructions[case])}</h2>")
        for record in sorted(by_case[case], key=lambda r: (r["method"], r["repeat"])):
            caption = f"{record['method']} r{record['repeat']}"
            if record.get("d_mm") is not None:
                caption += f", D = {record['d_mm']:.1f} mm"
            if record.get("parts_detail"):
                caption += f", {record['parts_detail']}"
            if record.get("error"):
                caption += f", failed: {record['error']}"
            images = record.get("images") or {}
            for name in ("plan", "outcome"):
                if name in images:
                    parts.append(
                        f"<figure><img src='{html.escape(images[name])}' alt='{name}'>"
                        f"<figcaption>{html.escape(caption)} ({name})</figcaption></figure>"
                    )
            if not images:
                parts.append(f"<p>{html.escape(caption)} (no image)</p>")
    path = out / "gallery.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
