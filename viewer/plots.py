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
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

#: Stages drawn in the time panel (keys of `OptimizationReport.timing_ms`) and their labels.
STAGES = (("point_dm", "point D&M"), ("tracking", "tracking"), ("line_dm", "line D&M"), ("plane_seg", "plane seg."), ("plane_fit", "plane fitting"), ("optimization", "optimization"))
WIDTH_PX, HEIGHT_PX, DPI = 560, 900, 100
CURRENT_GID = "current keyframe"  # the vertical line at the shown keyframe, in every panel


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


#: Labels of the lines and marker sets the figure draws (its legends show them).
COST_AFTER, COST_BEFORE, TRUE_SPEED, GYRO_BIAS = "cost after (solid)", "cost before (dashed)", "true speed", "|gyro bias| (mrad/s)"


def _curves(snapshots: list[Snapshot]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The data of every labelled line and marker set of the figure, by label: x the
    keyframe index, y in its panel's unit (costs <= 0 as NaN, left out of the log axis).
    What :func:`plots_figure` draws and :class:`PlotCanvas` puts into a figure it keeps."""
    d = _series(snapshots)
    x = d["keyframe"]
    out = {"RMSE": (x, d["rmse"]), "ATE (SE3)": (x, d["ate"])}
    out[COST_AFTER] = (x, np.where(d["cost1"] > 0, d["cost1"], np.nan))
    out[COST_BEFORE] = (x, np.where(d["cost0"] > 0, d["cost0"], np.nan))
    out["iterations"] = (x, d["iterations"])
    for key, label in STAGES:
        out[label] = (x, d[key])
    out["points tracked"], out["lines tracked"], out["planes"] = (x, d["points"]), (x, d["lines"]), (x, d["planes"])
    created, removed = plane_events(snapshots)
    for row, hit, label in ((0, d["lost"] > 0, "frames lost"), (1, d["reinit"] > 0, "map re-initialized"), (2, created, PLANE_EVENT_LABELS[0]), (2, removed, PLANE_EVENT_LABELS[1])):
        out[label] = (x[hit], np.full(int(hit.sum()), float(row)))
    with_imu = [(s.keyframe, s.imu) for s in snapshots if s.imu is not None]
    if with_imu:
        xs = np.array([keyframe for keyframe, _ in with_imu], dtype=float)
        out["speed"] = (xs, np.array([np.linalg.norm(imu.velocity_world[-1]) if imu.initialized else np.nan for _, imu in with_imu]))
        velocity_true = [imu.velocity_true for _, imu in with_imu if imu.velocity_true is not None]
        if len(velocity_true) == len(with_imu):  # the truth is known at every keyframe
            out[TRUE_SPEED] = (xs, np.array([np.linalg.norm(v[-1]) for v in velocity_true]))
        out[GYRO_BIAS] = (xs, np.array([1e3 * np.linalg.norm(imu.bias[-1][3:]) for _, imu in with_imu]))
    return out


def _stages_drawn(curves: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[str, ...]:
    """The stages with a time somewhere (the others are not drawn)."""
    return tuple(label for _, label in STAGES if np.any(np.nan_to_num(curves[label][1]) > 0))


def _cost_range(curves: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[float, float] | None:
    costs = np.concatenate([curves[COST_BEFORE][1], curves[COST_AFTER][1]])
    costs = costs[np.isfinite(costs)]
    return (float(costs.min()), float(costs.max())) if costs.size else None


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


def _cost_panel(ax: Axes, curves: dict[str, tuple[np.ndarray, np.ndarray]], style: dict) -> Axes:
    """Cost before (dashed, hollow markers, drawn on top) and after (solid) on a log axis
    (unitless, ½ Σ whitened residual²; costs <= 0 are left out), iterations on a twin."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter

    ax.plot(*curves[COST_AFTER], label=COST_AFTER, zorder=2, **style)
    ax.plot(*curves[COST_BEFORE], label=COST_BEFORE, linestyle="--", marker="o", markersize=3.5, markerfacecolor="none", linewidth=1.0, zorder=3)
    ax.set_yscale("log", nonpositive="mask")
    span = _cost_range(curves)
    if span is not None:
        ax.yaxis.set_major_locator(FixedLocator(cost_ticks(*span)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: compact_number(value)))
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_ylabel("cost (unitless, log)")
    twin = ax.twinx()
    twin.step(*curves["iterations"], where="mid", color="0.5", linewidth=0.9, label="iterations")
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


def _events_panel(ax: Axes, curves: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """The events strip: frames lost, map re-initialized, planes created or removed."""
    rows = (("frames lost", "tab:red", "v"), ("map re-initialized", "black", "x"), (PLANE_EVENT_LABELS[0], "tab:blue", "^"), (PLANE_EVENT_LABELS[1], "tab:purple", "v"))
    for label, color, marker in rows:
        ax.scatter(*curves[label], color=color, marker=marker, s=22, label=label)
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
    return _figure(snapshots, _curves(snapshots), current=current)


def _figure(snapshots: list[Snapshot], curves: dict[str, tuple[np.ndarray, np.ndarray]], *, current: int | None) -> Figure:
    """:func:`plots_figure` with the snapshots' :func:`_curves` already computed."""
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
    x = curves["RMSE"][0]
    style = dict(marker=".", markersize=3, linewidth=1.2)
    twins: dict[int, Axes] = {}
    fig.suptitle(f"{snapshots[-1].source}" if snapshots else "", fontsize=9, x=0.02, ha="left")

    ax = axes[0]
    ax.plot(*curves["RMSE"], label="RMSE", **style)
    ax.plot(*curves["ATE (SE3)"], label="ATE (SE3)", **style)
    ax.set_ylabel("error (cm)")
    _plain_numbers(ax)

    twins[1] = _cost_panel(axes[1], curves, style)

    ax = axes[2]
    for label in _stages_drawn(curves):
        ax.plot(*curves[label], label=label, **style)
    ax.set_ylabel("time (ms)")
    _plain_numbers(ax)

    ax = axes[3]
    ax.plot(*curves["points tracked"], label="points tracked", **style)
    ax.plot(*curves["lines tracked"], label="lines tracked", **style)
    ax.set_ylabel("features (count)")
    _count_axis(ax)
    twin = twins[3] = ax.twinx()
    twin.step(*curves["planes"], where="mid", color="tab:purple", linewidth=1.2, label="planes")
    twin.set_ylabel("planes (count)", color="tab:purple")
    _count_axis(twin)

    _events_panel(axes[4], curves)
    if inertial:
        twins[5] = _imu_panel(axes[5], curves, style)
    for i, ax in enumerate(axes):
        if current is not None:
            ax.axvline(current, color="tab:red", linewidth=1.0, alpha=0.7, gid=CURRENT_GID)
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


def _imu_panel(ax: Axes, curves: dict[str, tuple[np.ndarray, np.ndarray]], style: dict) -> Axes:
    """Speed (m/s, estimated and true) and |gyro bias| (mrad/s, on a twin) in VIO."""
    ax.plot(*curves["speed"], label="speed", **style)
    if TRUE_SPEED in curves:
        ax.plot(*curves[TRUE_SPEED], label=TRUE_SPEED, linestyle="--", linewidth=1.0)
    ax.set_ylabel("speed (m/s)")
    _plain_numbers(ax)
    twin = ax.twinx()
    twin.plot(*curves[GYRO_BIAS], color="tab:green", linewidth=1.0, label=GYRO_BIAS)
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
    """:func:`plots_figure` rendered to an RGB array (H, W, 3) uint8 for a GUI image: the
    pixels of :func:`plots_png`, drawn once straight into Agg's buffer."""
    return PlotCanvas().image(snapshots, current=current)


class PlotCanvas:
    """The plots drawn again and again as the kept keyframes change (the Plots tab): the
    figure is kept and only its data replaced while the panels, the lines drawn and the
    title stay the same, which costs about half of building and laying out a new figure
    (the layout is still computed at every draw); anything else builds a new one. A new
    figure gives the pixels :func:`plots_png` would; a kept one the same up to a pixel of
    the layout's rounding (it starts from the previous positions)."""

    def __init__(self) -> None:
        self._canvas: FigureCanvasAgg | None = None
        self._shape: tuple | None = None
        self.built = 0  # figures built (the rest were reused)

    def image(self, snapshots: list[Snapshot], *, current: int | None) -> np.ndarray:
        """RGB (H, W, 3) uint8 of `snapshots`' plots with `current` marked."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        curves = _curves(snapshots)
        shape = self._shape_of(snapshots, curves, current=current)
        if self._canvas is None or shape != self._shape:
            self._canvas, self._shape = FigureCanvasAgg(_figure(snapshots, curves, current=current)), shape
            self.built += 1
        else:
            _replace_data(self._canvas.figure, curves, current=current)
        self._canvas.draw()
        return np.asarray(self._canvas.buffer_rgba())[..., :3].copy()

    @staticmethod
    def _shape_of(snapshots: list[Snapshot], curves: dict[str, tuple[np.ndarray, np.ndarray]], *, current: int | None) -> tuple:
        """What decides which artists the figure has (a change builds a new one)."""
        return (
            snapshots[-1].source if snapshots else "",
            "speed" in curves,
            TRUE_SPEED in curves,
            _stages_drawn(curves),
            _cost_range(curves) is not None,
            current is None,
            len(curves["RMSE"][0]) == 1,
        )


def _replace_data(fig: Figure, curves: dict[str, tuple[np.ndarray, np.ndarray]], *, current: int | None) -> None:
    """Put `curves` into the lines and marker sets of a figure :func:`plots_figure` drew
    (found by label), move the shown keyframe's line, and let every axis rescale as a new
    figure's would (the events strip keeps its fixed rows)."""
    from matplotlib.ticker import FixedLocator

    for ax in fig.axes:
        for line in ax.get_lines():
            label = str(line.get_label())
            if line.get_gid() == CURRENT_GID and current is not None:
                line.set_xdata(np.array([current, current], dtype=float))
            elif label in curves:
                line.set_data(*curves[label])
        for collection in ax.collections:
            label = str(collection.get_label())
            if label in curves:
                collection.set_offsets(np.column_stack(curves[label]))
        if ax.get_yscale() == "log":
            span = _cost_range(curves)
            if span is not None:
                ax.yaxis.set_major_locator(FixedLocator(cost_ticks(*span)))
        ax.relim()
        ax.autoscale_view()
