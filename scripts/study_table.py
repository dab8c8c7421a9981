"""Regenerate the Monte-Carlo table (docs/results/study.md) from `coplanar sim` runs.

    .venv/bin/python scripts/study_table.py            # runs both sequences (30 runs each)
    .venv/bin/python scripts/study_table.py --no-run   # only rebuild the table from docs/study/

Writes docs/study/sim_{a,b}_{gn,lm}.json and .png, docs/hessian/*.png (sequence b, Gauss-Newton),
and replaces the text between the study-table markers in docs/results/study.md.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import subprocess
import sys

from results_doc import write_block

ROOT = pathlib.Path(__file__).resolve().parents[1]
VARIANTS = ("P-wo", "P-r", "P-w", "PL-wo", "PL-r", "PL-w")


def run_sim(sequence: str, runs: int, solver: str) -> None:
    out = ROOT / "docs" / "study"
    out.mkdir(parents=True, exist_ok=True)
    cmd = [str(ROOT / ".venv" / "bin" / "coplanar"), "sim", "--sequence", sequence, "--runs", str(runs), "--solver", solver, "--json", str(out / f"sim_{sequence}_{solver}.json")]
    if sequence == "b" and solver == "gn":
        cmd += ["--hessian-dir", str(ROOT / "docs" / "hessian")]
    subprocess.run(cmd, check=True)


def pct(a: float, b: float) -> str:
    return f"{100.0 * (b - a) / b:+.0f}%"


def verdict(holds: list[bool]) -> str:
    """'holds' / 'does not hold' over sequences a and b."""
    if all(holds):
        return "**holds** (a and b)"
    if not any(holds):
        return "**does not hold** (a nor b)"
    return f"**holds in {'a' if holds[0] else 'b'} only**"


def table(results: dict[str, dict], solver: str) -> str:
    name = {"gn": "Gauss-Newton (`--solver gn`, the default and DESIGN §4's solver)", "lm": "Levenberg-Marquardt (`--solver lm`)"}[solver]
    runs = results["b"]["runs"]
    lines = [
        f"**{name}**, at most 10 iterations. Medians over {runs} runs per sequence",
        f"(`coplanar sim --sequence a|b --runs {runs} --solver {solver}`, run by `scripts/study_table.py`)",
        f"on this project's 2-core machine ({platform.machine()}, single-threaded BLAS).",
        "RMSE: translational RMSE over all poses without alignment (cm; the gauge is fixed, all 7",
        "freedoms); ATE: after Sim(3) alignment (cm); time: the solver loop (ms); lins:",
        "linearizations (a rejected trial step costs one); conv: runs that converged within 10",
        "iterations; up: runs whose final cost is above the initial one (must be 0).",
        "",
        "| variant | items (b) | params (b) | RMSE a | ATE a | time a | lins a | conv a | up a | RMSE b | ATE b | time b | lins b | conv b | up b |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    a, b = results["a"]["variants"], results["b"]["variants"]
    for v in VARIANTS:
        cells = []
        for res in (a, b):
            e = res[v]
            cells.append(
                f"{e['rmse_cm_median']:.2f} | {e['ate_sim3_cm_median']:.2f} | {e['time_ms_median']:.0f} | {e['linearizations_median']:.0f} | {e['converged_runs']}/{runs} | {e['cost_increase_runs']}"
            )
        lines.append(f"| {v} | {b[v]['items']} | {b[v]['params']} | {cells[0]} | {cells[1]} |")
    seqs = (a, b)
    rmse = lambda res, v: res[v]["rmse_cm_median"]  # noqa: E731
    time_ms = lambda res, v: res[v]["time_ms_median"]  # noqa: E731
    lines += ["", "The paper's claims (§IV-B) beside what we measure (medians; time saving of the first variant relative to the second):", ""]
    lines.append("| claim | sequence a | sequence b | verdict |")
    lines.append("|---|---|---|---|")
    for w, r, paper in (("P-w", "P-r", "31%"), ("PL-w", "PL-r", "33%")):
        lines.append(
            f"| {w} faster than {r} (paper: by {paper}) | {pct(time_ms(a, w), time_ms(a, r))} | {pct(time_ms(b, w), time_ms(b, r))} | {verdict([time_ms(x, w) < time_ms(x, r) for x in seqs])} |"
        )
    for kind in ("P", "PL"):
        w, r, wo = (f"{kind}-{m}" for m in ("w", "r", "wo"))
        lines.append(f"| {w} faster than {wo} | {pct(time_ms(a, w), time_ms(a, wo))} | {pct(time_ms(b, w), time_ms(b, wo))} | {verdict([time_ms(x, w) < time_ms(x, wo) for x in seqs])} |")
    for kind in ("P", "PL"):
        w, r, wo = (f"{kind}-{m}" for m in ("w", "r", "wo"))
        cells = [f"RMSE {rmse(x, w):.2f} vs {rmse(x, r):.2f} / {rmse(x, wo):.2f}" for x in seqs]
        lines.append(f"| {w} more accurate than {r} and {wo} | {cells[0]} | {cells[1]} | {verdict([rmse(x, w) < min(rmse(x, r), rmse(x, wo)) for x in seqs])} |")
    for kind in ("P", "PL"):
        r, wo = f"{kind}-r", f"{kind}-wo"
        cells = [f"RMSE {rmse(x, r):.2f} vs {rmse(x, wo):.2f} ({pct(rmse(x, r), rmse(x, wo))})" for x in seqs]
        lines.append(f"| {r} more accurate than {wo} | {cells[0]} | {cells[1]} | {verdict([rmse(x, r) < rmse(x, wo) for x in seqs])} |")
    for m in ("wo", "r", "w"):
        cells = [f"RMSE PL-{m} {rmse(x, 'PL-' + m):.2f} vs P-{m} {rmse(x, 'P-' + m):.2f}" for x in seqs]
        lines.append(f"| PL-{m} more accurate than P-{m} | {cells[0]} | {cells[1]} | {verdict([rmse(x, 'PL-' + m) < rmse(x, 'P-' + m) for x in seqs])} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--no-run", action="store_true", help="rebuild the table in docs/results/study.md from docs/study/*.json without running")
    parser.add_argument("--runs", type=int, default=30)
    args = parser.parse_args()
    solvers = ("gn", "lm")
    if not args.no_run:
        for solver in solvers:
            for seq in ("b", "a"):
                run_sim(seq, args.runs, solver)
    tables = []
    for solver in solvers:
        results = {s: json.loads((ROOT / "docs" / "study" / f"sim_{s}_{solver}.json").read_text()) for s in ("a", "b")}
        tables.append(table(results, solver))
    body = "\n\n".join(tables)
    write_block("study-table", body)
    print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
