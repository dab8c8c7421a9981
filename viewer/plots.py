"""Plots over the kept keyframes (PNG, matplotlib's Agg): trajectory error, optimization
cost (log axis) and iterations, time per stage, what is tracked and mapped, and events on
a strip below (frames lost, map re-initialized, a plane created or removed), with the shown
keyframe marked. Every axis says its unit; the legends sit above their panel, off the data.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

from backend.pipeline.snapshot import Snapshot

if TYPE_CHECKING:  # matplotlib is imported when the first plot is drawn
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Stages drawn in the time panel (keys of `OptimizationReport.timing_ms`) and their labels.
STAGES = (("point_dm", "point D&M"), ("tracking", "tracking"), ("line_dm", "line D&M"), ("plane_seg", "plane seg."), ("plane_fit", "plane fitting"), ("optimization", "optimization"))
WIDTH_PX, HEIGHT_PX, DPI = 560, 900, 100


def _series(snapshots: list[Snapshot]) -> dict[str, np.ndarray]:
    nan = float("nan")

    def col(fn) -> np.ndarray:
        return np.array([fn(s) for s in snapshots], dtype=float)

    out = {
        "keyframe": col(lambda s: s.keyframe),
        "rmse": col(lambda s: s.metrics.rmse_cm),
        "ate": col(lambda s: s.metrics.ate_cm),
        "cost0": col(lambda s: s.report.initial_cost),
        "cost1": col(lambda s: s.report.final_cost),
        "iterations": col(lambda s: s.report.iterations),
        "points": col(lambda s: s.tracking.tracked_points if s.tracking is not None else len(s.points)),
        "lines": col(lambda s: s.tracking.tracked_lines if s.tracking is not None else len(s.lines)),
        "planes": col(lambda s: len(s.planes)),
        "lost": col(lambda s: s.tracking.lost_frames if s.tracking is not None else 0),
        "reinit": col(lambda s: s.tracking.reinitializations if s.tracking is not None else 0),
    }
    for key, _ in STAGES:
        out[key] = col(lambda s, key=key: s.report.timing_ms.get(key, nan))
    return out


#: What a tick on the events strip's "planes" row means (the legend says it too).
PLANE_EVENT_LABELS = ("plane created (new id)", "plane removed or merged")


def plane_events(snapshots: list[Snapshot]) -> tuple[np.ndarray, np.ndarray]:
    """Per snapshot (one per keyframe, in order): whether a plane was created (an id the
    previous snapshot did not have; at keyframe 0, any plane) and whether one was removed
    or merged away (an id the previous snapshot had is gone). Boolean arrays; keyframes where
    RANSAC only accepted candidate sets into existing planes mark nothing."""
    created = np.zeros(len(snapshots), dtype=bool)
    removed = np.zeros(len(snapshots), dtype=bool)
    previous: set[int] | None = None
    for i, s in enumerate(snapshots):
        ids = {plane.id for plane in s.planes}
        if previous is None:
            created[i] = s.keyframe == 0 and bool(ids)  # before it: no map (older keyframes were let go)
        else:
            created[i], removed[i] = bool(ids - previous), bool(previous - ids)
        previous = ids
    return created, removed


def _plain_numbers(ax: Axes) -> None:
    """Tick labels as plain numbers on a linear axis: no '1e7' offset text above it."""
    from matplotlib.ticker import ScalarFormatter

    formatter = ScalarFormatter(useOffset=False)
    formatter.set_scientific(False)
    ax.yaxis.set_major_formatter(formatter)


def _count_axis(ax: Axes) -> None:
    """A linear axis of counts: integer ticks, plain numbers."""
    from matplotlib.ticker import MaxNLocator

    _plain_numbers(ax)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))


def _cost_panel(ax: Axes, x: np.ndarray, d: dict[str, np.ndarray], style: dict) -> Axes:
    """Cost before (dashed, hollow markers, drawn on top) and after (solid) on a log axis
    (unitless, ½ Σ whitened residual²; costs <= 0 are left out), iterations on a twin."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    positive = {key: np.where(d[key] > 0, d[key], np.nan) for key in ("cost0", "cost1")}
    ax.plot(x, positive["cost1"], label="cost after (solid)", zorder=2, **style)
    ax.plot(x, positive["cost0"], label="cost before (dashed)", linestyle="--", marker="o", markersize=3.5, markerfacecolor="none", linewidth=1.0, zorder=3)
    ax.set_yscale("log", nonpositive="mask")
    costs = np.concatenate([positive["cost0"], positive["cost1"]])
    costs = costs[np.isfinite(costs)]
    if costs.size:
        ax.yaxis.set_major_locator(FixedLocator(cost_ticks(float(costs.min()), float(costs.max()))))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: compact_number(value)))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylabel("cost (unitless, log)")
    twin = ax.twinx()
    twin.step(x, d["iterations"], where="mid", color="0.5", linewidth=0.9, label="iterations")
    twin.set_ylabel("iterations (count)", color="0.4")
    _count_axis(twin)
    return twin


def cost_ticks(low: float, high: float, *, most: int = 6) -> list[float]:
    """Tick values for a log cost axis over [low, high] (both > 0, unitless): 1, 2, 5 × 10^k,
    or where that gives more than `most` 1, 3 × 10^k, or powers of ten (every few decades);
    round values evenly spaced inside a range narrower than two such ticks."""
    from matplotlib.ticker import MaxNLocator

    first, last = int(np.floor(np.log10(low))), int(np.ceil(np.log10(high)))
    for mantissas in ((1, 2, 5), (1, 3), (1,)):
        ticks = [m * 10.0**k for k in range(first, last + 1) for m in mantissas if low <= m * 10.0**k <= high]
        if len(ticks) <= most:
            break
    if len(ticks) > most:
        stride = int(np.ceil((last - first + 1) / most))
        ticks = [10.0**k for k in range(first, last + 1, stride) if low <= 10.0**k <= high]
    if len(ticks) < 2:
        ticks = [float(t) for t in MaxNLocator(nbins=4).tick_values(low, high) if low <= t <= high]
    return ticks


def compact_number(value: float) -> str:
    """A tick label without an offset or a multiplier: '300', '4,500', '0.02', '1e7'."""
    if value <= 0 or not np.isfinite(value):
        return ""
    if value >= 1e5:
        mantissa, exponent = f"{value:.1e}".split("e")
        return f"{mantissa.removesuffix('.0')}e{int(exponent)}"
    return f"{value:,.0f}" if value >= 10 else f"{value:.2g}"


def _events_panel(ax: Axes, x: np.ndarray, d: dict[str, np.ndarray], snapshots: list[Snapshot]) -> None:
    """The events strip: frames lost, map re-initialized, planes created or removed."""
    created, removed = plane_events(snapshots)
    rows = (
        (0, d["lost"] > 0, "frames lost", "tab:red", "v"),
        (1, d["reinit"] > 0, "map re-initialized", "black", "x"),
        (2, created, PLANE_EVENT_LABELS[0], "tab:blue", "^"),
        (2, removed, PLANE_EVENT_LABELS[1], "tab:purple", "v"),
    )
    for row, hit, label, color, marker in rows:
        ax.scatter(x[hit], np.full(int(hit.sum()), row), color=color, marker=marker, s=22, label=label)
    ax.set_yticks([0, 1, 2], ["lost", "re-init.", "planes ±"], fontsize=7)
    ax.set_ylim(-0.7, 2.7)
    ax.set_xlabel("keyframe (index)")


def _legend_above(ax: Axes, twin: Axes | None) -> None:
    """The legend of `ax` (and its twin) above the axes, outside the data."""
    handles, labels = ax.get_legend_handles_labels()
    if twin is not None:
        h2, l2 = twin.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    if handles:
        ax.legend(handles, labels, fontsize=6.5, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=min(len(handles), 3), frameon=False, borderaxespad=0.2, handlelength=2.4)


def plots_figure(snapshots: list[Snapshot], *, current: int | None) -> Figure:
    """The plots of `snapshots` (one per keyframe, in order) as a matplotlib figure
    (`WIDTH_PX` wide at `DPI`); `current` is the keyframe marked by a vertical line. Every
    axis says its unit; costs are on a log axis, legends sit above their panel."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    inertial = any(s.imu is not None for s in snapshots)
    height = HEIGHT_PX + (190 if inertial else 0)
    fig = Figure(figsize=(WIDTH_PX / DPI, height / DPI), dpi=DPI, layout=ConstrainedLayoutEngine(h_pad=0.02, hspace=0.0))
    ratios = [3, 3, 3, 3, 3, 1.6] if inertial else [3, 3, 3, 3, 1.6]
    axes = list(fig.subplots(len(ratios), 1, sharex=True, height_ratios=ratios))
    if inertial:  # the IMU panel goes above the events strip
        axes = axes[:4] + [axes[5], axes[4]]
    d = _series(snapshots)
    x = d["keyframe"]
    style = dict(marker=".", markersize=3, linewidth=1.2)
    twins: dict[int, Axes] = {}
    fig.suptitle(f"{snapshots[-1].source}" if snapshots else "", fontsize=9, x=0.02, ha="left")

    ax = axes[0]
    ax.plot(x, d["rmse"], label="RMSE", **style)
    ax.plot(x, d["ate"], label="ATE (SE3)", **style)
    ax.set_ylabel("error (cm)")
    _plain_numbers(ax)

    twins[1] = _cost_panel(axes[1], x, d, style)

    ax = axes[2]
    for key, label in STAGES:
        if np.any(np.nan_to_num(d[key]) > 0):
            ax.plot(x, d[key], label=label, **style)
    ax.set_ylabel("time (ms)")
    _plain_numbers(ax)

    ax = axes[3]
    ax.plot(x, d["points"], label="points tracked", **style)
    ax.plot(x, d["lines"], label="lines tracked", **style)
    ax.set_ylabel("features (count)")
    _count_axis(ax)
    twin = twins[3] = ax.twinx()
    twin.step(x, d["planes"], where="mid", color="tab:purple", linewidth=1.2, label="planes")
    twin.set_ylabel("planes (count)", color="tab:purple")
    _count_axis(twin)

    _events_panel(axes[4], x, d, snapshots)
    if inertial:
        twins[5] = _imu_panel(axes[5], snapshots, style)
    for i, ax in enumerate(axes):
        if current is not None:
            ax.axvline(current, color="tab:red", linewidth=1.0, alpha=0.7)
        ax.grid(True, linewidth=0.3)
        ax.tick_params(labelsize=7)
        ax.yaxis.label.set_fontsize(8)
        _legend_above(ax, twins.get(i))
    for twin in twins.values():
        twin.tick_params(labelsize=7)
        twin.yaxis.label.set_fontsize(8)
    if len(x) == 1:
        axes[0].set_xlim(x[0] - 1, x[0] + 1)
    return fig


def _imu_panel(ax: Axes, snapshots: list[Snapshot], style: dict) -> Axes:
    """Speed (m/s, estimated and true) and |gyro bias| (mrad/s, on a twin) in VIO."""
    with_imu = [(s.keyframe, s.imu) for s in snapshots if s.imu is not None]
    xs = np.array([keyframe for keyframe, _ in with_imu], dtype=float)
    speed = np.array([np.linalg.norm(imu.velocity_world[-1]) if imu.initialized else np.nan for _, imu in with_imu])
    ax.plot(xs, speed, label="speed", **style)
    velocity_true = [imu.velocity_true for _, imu in with_imu if imu.velocity_true is not None]
    if len(velocity_true) == len(with_imu):  # the truth is known at every keyframe
        ax.plot(xs, [np.linalg.norm(v[-1]) for v in velocity_true], label="true speed", linestyle="--", linewidth=1.0)
    ax.set_ylabel("speed (m/s)")
    _plain_numbers(ax)
    twin = ax.twinx()
    bg = np.array([1e3 * np.linalg.norm(imu.bias[-1][3:]) for _, imu in with_imu])
    twin.plot(xs, bg, color="tab:green", linewidth=1.0, label="|gyro bias| (mrad/s)")
    twin.set_ylabel("gyro bias (mrad/s)", color="tab:green")
    _plain_numbers(twin)
    return twin


def plots_png(snapshots: list[Snapshot], *, current: int | None) -> bytes:
    """:func:`plots_figure` as PNG bytes."""
    fig = plots_figure(snapshots, current=current)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def plots_image(snapshots: list[Snapshot], *, current: int | None) -> np.ndarray:
    """:func:`plots_png` decoded to an RGB array (H, W, 3) uint8 for a GUI image."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(plots_png(snapshots, current=current))).convert("RGB"))
