"""A sweep's plots from its results rows (matplotlib, Agg; each PNG complete or not at all):

- `ate_by_variant.png`: the ATE after SE(3) alignment (cm) of every finished run, per variant
  (a box over the runs, each run a dot coloured by its sequence);
- `time_by_stage.png`: the DESIGN §7 stage times per variant (ms; the mean over the finished
  runs: point D&M and tracking per frame, the others per keyframe where they ran, total per
  frame).
"""

from __future__ import annotations

import pathlib
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from backend.optim.variant import VARIANTS
from backend.sweep.results import OK, STAGES

Row = Mapping[str, Any]
ATE_PLOT = "ate_by_variant.png"
TIME_PLOT = "time_by_stage.png"


def write_plots(out: pathlib.Path, rows: Sequence[Row]) -> list[pathlib.Path]:
    """Both plots in `out`; their paths."""
    return [_ate_by_variant(out / ATE_PLOT, rows), _time_by_stage(out / TIME_PLOT, rows)]


def _variants(rows: Sequence[Row]) -> list[str]:
    present = {r["variant"] for r in rows}
    return [str(v) for v in VARIANTS if v in present]


def _ate_by_variant(path: pathlib.Path, rows: Sequence[Row]) -> pathlib.Path:
    import numpy as np

    variants = _variants(rows)
    done = [r for r in rows if r["status"] == OK and r["ate_rmse_cm"] is not None]
    sequences = list(dict.fromkeys(r["sequence"] for r in done))
    figure, axes = _figure(width=max(4.0, 1.1 * len(variants) + 2.0))
    values = [[float(r["ate_rmse_cm"]) for r in done if r["variant"] == v] for v in variants]
    if any(values):
        axes.boxplot([v or [np.nan] for v in values], tick_labels=variants, showfliers=False)
    colours = _colours(len(sequences))
    for k, sequence in enumerate(sequences):
        for i, v in enumerate(variants):
            ys = [float(r["ate_rmse_cm"]) for r in done if r["variant"] == v and r["sequence"] == sequence]
            xs = i + 1 + (k - (len(sequences) - 1) / 2) * 0.08 + np.zeros(len(ys))
            axes.scatter(xs, ys, s=14, color=colours[k], label=sequence if i == 0 else None, zorder=3)
    axes.set_xticks(range(1, len(variants) + 1), variants)
    axes.set_ylabel("ATE after SE(3) alignment (cm)")
    axes.set_title(f"ATE per variant ({len(done)} finished runs)")
    if sequences:
        axes.legend(fontsize=7, loc="best")
    return _save(figure, path)


def _time_by_stage(path: pathlib.Path, rows: Sequence[Row]) -> pathlib.Path:
    import numpy as np

    variants = _variants(rows)
    done = [r for r in rows if r["status"] == OK]
    figure, axes = _figure(width=max(5.0, 1.4 * len(variants) + 2.0))
    width = 0.8 / len(STAGES)
    colours = _colours(len(STAGES))
    for k, stage in enumerate(STAGES):
        means = []
        for v in variants:
            times = [float(r[f"time_{stage}_ms"]) for r in done if r["variant"] == v and r[f"time_{stage}_ms"] is not None]
            means.append(statistics.fmean(times) if times else 0.0)
        axes.bar(np.arange(len(variants)) + (k - (len(STAGES) - 1) / 2) * width, means, width, color=colours[k], label=stage.replace("_", " "))
    axes.set_xticks(range(len(variants)), variants)
    axes.set_ylabel("time (ms; per frame: point dm, tracking, total; per keyframe: the rest)")
    axes.set_title(f"Time per stage (mean over {len(done)} finished runs)")
    axes.legend(fontsize=7, ncols=2, loc="upper left")
    return _save(figure, path)


def _figure(*, width: float) -> tuple[Any, Any]:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width, 4.0), layout="constrained")
    return figure, figure.add_subplot()


def _colours(n: int) -> list[Any]:
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def _save(figure: Any, path: pathlib.Path) -> pathlib.Path:
    """`figure` as a PNG at `path` (Agg canvas, written under a temporary name)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from backend.common.atomic import atomic_path

    FigureCanvasAgg(figure)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, dpi=110)
    return path
