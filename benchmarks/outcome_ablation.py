"""What the outcome check buys with an imprecise VLM: Appendix F with and without verify-and-repair.

A scripted imprecise VLM (keymps.eval.imprecise_vlm: the exact design, every keypoint moved by a
normal error of sigma times the image's longer side) answers over real HTTP through litellm.
Each sigma runs the cake_six suite (six equal parts of a round and a square cake, 50 scenes
each) twice: plans as answered and executed (the paper's KeyMPs; the outcome stage predicts but
accepts every plan), and with verify-and-repair (a plan whose predicted pieces are wrong goes
back once for repair, one still wrong is refused). Success is Appendix F's, judged by the same
verifier on the cake's true outline: of the planned lines (the paper's design success) and of
what the knife cuts through (the edge reaches past a cut's start); a refused plan cuts nothing
and is no success. Prints a markdown table beside the paper's numbers.

    python benchmarks/outcome_ablation.py [--repeats 50] [--sigmas 0.0025 0.005 0.01] [--quick]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

PAPER = {"round": "100 %", "square": "64 %"}
"""KeyMPs in the paper's Appendix F (GPT-4o, 50 designs each)."""


def run(sigma: float, verify: bool, repeats: int, out: Path, api_base: str) -> list[dict]:
    from keymps.eval.imprecise_vlm import MODEL
    from keymps.eval.runner import EvalOptions, run_suite
    from keymps.eval.suites import load_suite

    options = EvalOptions(
        out=out / f"sigma{sigma:g}-{'verify' if verify else 'plain'}",
        methods=("keymps",),
        repeats=repeats,
        backend="litellm",
        model=MODEL,
        api_base=api_base,
        no_cache=True,
        outcome="repair" if verify else "predict",
        processes=1,
    )
    return run_suite(load_suite("cake_six"), options)


def rates(records: list[dict], case: str) -> dict[str, float]:
    """Fractions of one case's runs: design success (the paper's: the planned lines on the
    true outline), success (what the knife cuts through, on the true outline), refused, and
    executed but wrong."""
    mine = [r for r in records if r["case"] == case]
    count = len(mine)
    success = sum(bool(r.get("success")) for r in mine)
    refused = sum((r.get("error") or "").startswith("outcome:") for r in mine)
    return {
        "design": sum(bool(r.get("design_success")) for r in mine) / count,
        "success": success / count,
        "refused": refused / count,
        "wrong": (count - success - refused) / count,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.0025, 0.005, 0.01])
    parser.add_argument("--out", type=Path)
    parser.add_argument("--quick", action="store_true", help="2 scenes per cake, one sigma")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.sigmas = 2, [0.005]
    os.environ.setdefault("OPENAI_API_KEY", "sk-local-imprecise-vlm")  # sent to 127.0.0.1 only
    from keymps.eval.imprecise_vlm import ErrorModel, ImpreciseVlm

    out = args.out or Path(tempfile.mkdtemp(prefix="outcome-ablation-"))
    print(
        "| sigma | case | paper | as answered: lines | as answered: cut | verified: cut | "
        "refused | wrong, executed |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for sigma in args.sigmas:
        with ImpreciseVlm(ErrorModel(sigma)) as vlm:
            plain = run(sigma, False, args.repeats, out, vlm.api_base)
            verified = run(sigma, True, args.repeats, out, vlm.api_base)
        for case in ("round", "square"):
            before, after = rates(plain, case), rates(verified, case)
            cells = [before["design"], before["success"], after["success"], after["refused"]]
            cells.append(after["wrong"])
            shown = " | ".join(f"{100 * value:.0f} %" for value in cells)
            print(f"| {100 * sigma:g} % | {case} | {PAPER[case]} | {shown} |", flush=True)
    print(f"\nresults: {out}")


if __name__ == "__main__":
    main()
