"""`coplanar sim`: the paper's Monte-Carlo study (DESIGN §4, §7)."""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import sys
from collections.abc import Sequence

from backend.optim.variant import VARIANT_NAMES, VARIANTS, Variant


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import path, seed

    p = sub.add_parser("sim", help="run the Monte-Carlo study of the six variants")
    p.add_argument("--sequence", required=True, choices=("a", "b"), help="a: four walls, 150 poses; b: one wall, 50 poses")
    p.add_argument("--runs", type=int, default=30, help="number of noise draws (default 30)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the world and the noise (default 0)")
    p.add_argument("--variants", default="all", help=f"'all' or a comma list of {','.join(VARIANT_NAMES)}")
    p.add_argument("--json", required=True, type=path, help="write the medians here (JSON)")
    p.add_argument("--plot", type=path, default=None, help="PNG of RMSE and time per variant (default: the --json path with .png)")
    p.add_argument("--solver", choices=("gn", "lm"), default="gn", help="gn: Gauss-Newton (the paper's study, default); lm: Levenberg-Marquardt")
    p.add_argument("--sigma-rel", type=float, default=None, help="σ of the -r plane residuals as a fraction of the anchor's distance to the plane (default 0.01)")
    p.add_argument("--hessian-dir", type=path, default=None, help="write one Hessian sparsity PNG per variant for the first run")
    p.set_defaults(run=run)


def _check_writable_file(path: pathlib.Path, option: str) -> None:
    """Fail early (before hours of work) if `path` cannot be written; leaves no file behind."""
    from app.errors import UsageError

    try:
        if path.is_dir() or path.name in ("", ".", ".."):
            raise UsageError(f"cannot write {option} {path}: Is a directory")
        existed = path.exists()
        with open(path, "a"):
            pass
    except OSError as e:
        raise UsageError(f"cannot write {option} {path}: {e.strerror or e}") from None
    if not existed:
        path.unlink()


def _check_plot_format(path: pathlib.Path) -> None:
    """The plot's file extension must be an image format matplotlib writes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from app.errors import UsageError

    formats = sorted(FigureCanvasAgg.get_supported_filetypes())
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in formats:
        raise UsageError(f"--plot {path}: unknown image format {suffix!r} (use one of {', '.join(formats)})")


def _parse_variants(text: str) -> list[Variant]:
    from app.errors import UsageError

    if text == "all":
        return list(VARIANTS)
    names = [v.strip() for v in text.split(",") if v.strip()]
    bad = [v for v in names if v not in VARIANT_NAMES]
    if bad or not names:
        raise UsageError(f"--variants: unknown variant(s) {', '.join(bad) or '(none)'}; expected 'all' or some of {', '.join(VARIANT_NAMES)}")
    return [Variant.parse(v) for v in names]


def format_table(sequence: str, runs: int, summary: dict) -> str:
    head = (
        f"{'variant':8s} {'items':>5s} {'params':>6s} {'RMSE cm':>8s} {'ATE-sim3':>8s} {'time ms':>8s} {'iters':>5s} {'lins':>5s} "
        f"{'lin ms':>7s} {'solve ms':>8s} {'setup ms':>8s} {'conv':>5s} {'cost up':>7s}"
    )
    lines = [
        f"sequence {sequence}, {runs} runs (medians; RMSE without alignment (the gauge is fixed), ATE after Sim(3) alignment, both cm;",
        "lins: linearizations; conv: runs that converged; cost up: runs whose final cost is above the initial one)",
        head,
        "-" * len(head),
    ]
    for name, s in summary.items():
        lines.append(
            f"{name:8s} {s.items:5d} {s.params:6d} {s.rmse_cm_median:8.2f} {s.ate_sim3_cm_median:8.2f} {s.time_ms_median:8.1f} {s.iterations_median:5.1f} {s.linearizations_median:5.1f}"
            f" {s.linearize_ms_median:7.1f} {s.solve_ms_median:8.1f} {s.setup_ms_median:8.1f} {s.converged_runs:5d} {s.cost_increase_runs:7d}"
        )
    return "\n".join(lines)


def write_plot(path: pathlib.Path, sequence: str, runs: int, results: list, variants: Sequence[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_r, ax_a) = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    colors = ["#888888", "#e69f00", "#009e73", "#555555", "#d55e00", "#0072b2"]
    for i, v in enumerate(variants):
        rs = [x for x in results if x.variant == v]
        for ax, values in ((ax_t, [x.report.time_ms for x in rs]), (ax_r, [x.rmse_cm for x in rs]), (ax_a, [x.ate_sim3_cm for x in rs])):
            ax.boxplot([values], positions=[i], widths=0.6, patch_artist=True, boxprops={"facecolor": colors[i % len(colors)], "alpha": 0.6}, medianprops={"color": "black"}, showfliers=False)
    ax_t.set_ylabel("optimization time (ms)")
    ax_r.set_ylabel("translational RMSE (cm)")
    ax_a.set_ylabel("ATE after Sim(3) (cm)")
    ax_a.set_xticks(range(len(variants)), variants)
    ax_t.set_title(f"Monte-Carlo sequence {sequence}: {runs} runs, ≤ 10 iterations")
    for ax in (ax_t, ax_r, ax_a):
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from app.errors import UsageError
    from backend.eval import montecarlo, sequences
    from backend.optim.problem import build_problem
    from backend.optim.structure import hessian_structure

    if args.runs < 1:
        raise UsageError(f"--runs must be at least 1, got {args.runs}")
    variants = _parse_variants(args.variants)
    from backend.optim.problem import SIGMA_REL_DEFAULT

    sigma_rel = SIGMA_REL_DEFAULT if args.sigma_rel is None else args.sigma_rel
    if not (np.isfinite(sigma_rel) and sigma_rel > 0):
        raise UsageError(f"--sigma-rel {args.sigma_rel}: must be a positive number")
    from backend.common.atomic import make_folder

    if args.hessian_dir is not None:  # first: a --json or --plot path it takes is then refused as a folder
        try:
            make_folder(args.hessian_dir)
        except OSError as e:
            raise UsageError(f"cannot create --hessian-dir {args.hessian_dir}: {e.strerror or e}") from None
    _check_writable_file(args.json, "--json")
    plot_path = args.plot if args.plot is not None else args.json.with_suffix(".png")
    _check_plot_format(plot_path)
    if plot_path.absolute() == args.json.absolute():
        raise UsageError(f"--plot {plot_path}: the same file as --json")
    _check_writable_file(plot_path, "--plot")

    if args.hessian_dir is not None:
        world = sequences.make_world(args.sequence, seed=args.seed)
        data = montecarlo.make_problem_data(world, np.random.default_rng([args.seed, 0]))
        for v in variants:
            structure = hessian_structure(build_problem(data, v))
            path = args.hessian_dir / f"hessian_{args.sequence}_{v}.png"
            try:
                structure.write_png(path)
            except OSError as e:
                raise UsageError(f"--hessian-dir {args.hessian_dir}: cannot write {path.name}: {e.strerror or e}") from None
            print(f"wrote {path} ({structure.items} items, {structure.params} params, {structure.nnz} nonzeros)")

    from tqdm import tqdm

    with tqdm(total=args.runs, desc=f"sim {args.sequence}", unit="run", file=sys.stderr, disable=None) as bar:
        summary, results = montecarlo.run_study(args.sequence, runs=args.runs, seed=args.seed, variants=variants, method=args.solver, sigma_rel=sigma_rel, on_run=lambda _r: bar.update(1))

    payload = {
        "sequence": args.sequence,
        "runs": args.runs,
        "seed": args.seed,
        "solver": {
            "method": {"gn": "gauss-newton", "lm": "levenberg-marquardt"}[args.solver],
            "max_iterations": montecarlo.MAX_ITERATIONS,
            "linear_solver": "schur complement + envelope or dense cholesky",
            "gauge": "prior on pose 0 and on the distance from pose 0 to the farthest pose (7 freedoms)",
            "sigma_rel": sigma_rel,
        },
        "machine": {"python": platform.python_version(), "processor": platform.machine(), "cpus": _cpu_count()},
        "variants": {name: s.to_json() for name, s in summary.items()},
    }
    from backend.common.atomic import atomic_path

    option, path, plot_written = "--json", args.json, False
    try:  # each file complete or absent; the plot is moved into place just before the JSON
        with atomic_path(args.json) as json_tmp:
            json_tmp.write_text(json.dumps(payload, indent=2) + "\n")
            option, path = "--plot", plot_path
            with atomic_path(plot_path) as plot_tmp:
                write_plot(plot_tmp, args.sequence, args.runs, results, variants)
            option, path, plot_written = "--json", args.json, True
    except OSError as e:
        written = f"only {plot_path} was written" if plot_written else "neither file was written"
        raise UsageError(f"cannot write {option} {path}: {e.strerror or e}; {written}") from None
    print(format_table(args.sequence, args.runs, summary))
    print(f"wrote {args.json} and {plot_path}", file=sys.stderr)
    return 0


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
