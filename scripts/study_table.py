"""Regenerate the README's Monte-Carlo table from `coplanar sim` runs.

    .venv/bin/python scripts/study_table.py            # runs both sequences (30 runs each)
    .venv/bin/python scripts/study_table.py --no-run   # only rebuild the table from docs/study/

Writes docs/study/sim_{a,b}.json and .png, docs/hessian/*.png (sequence b), and replaces the
text between the study-table markers in README.md.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import subprocess
import sys

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


def table(results: dict[str, dict], solver: str) -> str:
    name = {"gn": "Gauss-Newton (`--solver gn`, the default and DESIGN §4's solver)", "lm": "Levenberg-Marquardt (`--solver lm`)"}[solver]
    lines = [
        f"**{name}**, at most 10 iterations. Medians over {results['b']['runs']} runs per sequence",
        f"(`coplanar sim --sequence a|b --runs {results['b']['runs']} --solver {solver}`, run by `scripts/study_table.py`)",
        f"on this project's 2-core machine ({platform.machine()}, single-threaded BLAS).",
        "RMSE: translational RMSE over all poses without alignment (cm); ATE: after Sim(3)",
        "alignment (cm); time: the solver loop (ms).",
        "",
        "| variant | items (b) | params (b) | RMSE a | ATE a | time a | RMSE b | ATE b | time b |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    a, b = results["a"]["variants"], results["b"]["variants"]
    for v in VARIANTS:
        lines.append(
            f"| {v} | {b[v]['items']} | {b[v]['params']} | {a[v]['rmse_cm_median']:.2f} | {a[v]['ate_sim3_cm_median']:.2f} | {a[v]['time_ms_median']:.0f} "
            f"| {b[v]['rmse_cm_median']:.2f} | {b[v]['ate_sim3_cm_median']:.2f} | {b[v]['time_ms_median']:.0f} |"
        )
    lines += ["", "The paper's claims beside what we measure (time saving of -w relative to -r, per sequence):", ""]
    lines.append("| claim (paper §IV-B) | sequence a | sequence b |")
    lines.append("|---|---|---|")
    for w, r, paper in (("P-w", "P-r", "31%"), ("PL-w", "PL-r", "33%")):
        lines.append(f"| {w} faster than {r} by {paper} | {pct(a[w]['time_ms_median'], a[r]['time_ms_median'])} | {pct(b[w]['time_ms_median'], b[r]['time_ms_median'])} |")
    for kind in ("P", "PL"):
        cells = []
        for seq, res in (("a", a), ("b", b)):
            w, r, wo = (res[f"{kind}-{m}"] for m in ("w", "r", "wo"))
            cells.append(
                f"RMSE {w['rmse_cm_median']:.2f} vs {r['rmse_cm_median']:.2f} / {wo['rmse_cm_median']:.2f}; "
                f"ATE {w['ate_sim3_cm_median']:.2f} vs {r['ate_sim3_cm_median']:.2f} / {wo['ate_sim3_cm_median']:.2f}"
            )
        lines.append(f"| {kind}-w more accurate than {kind}-r / {kind}-wo | {cells[0]} | {cells[1]} |")
    cells = [f"ATE PL-w {res['PL-w']['ate_sim3_cm_median']:.2f} vs P-w {res['P-w']['ate_sim3_cm_median']:.2f}" for res in (a, b)]
    lines.append(f"| PL more accurate than P | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--no-run", action="store_true")
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
    readme = ROOT / "README.md"
    text = readme.read_text()
    start, end = "<!-- study-table:start -->", "<!-- study-table:end -->"
    i, j = text.index(start) + len(start), text.index(end)
    body = "\n\n".join(tables)
    readme.write_text(text[:i] + "\n" + body + "\n" + text[j:])
    print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
