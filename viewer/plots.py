"""Plots over the kept keyframes (PNG, matplotlib's Agg): trajectory error, optimization
cost and iterations, time per stage, what is tracked and mapped, and events on a strip
below (frames lost, map re-initialized, planes accepted), with the shown keyframe marked.
"""

from __future__ import annotations

import io

import numpy as np

from backend.pipeline.snapshot import Snapshot

#: Stages drawn in the time panel (keys of `OptimizationReport.timing_ms`) and their labels.
STAGES = (("point_dm", "point D&M"), ("tracking", "tracking"), ("line_dm", "line D&M"), ("plane_seg", "plane seg."), ("plane_fit", "plane fitting"), ("optimization", "optimization"))
WIDTH_PX, HEIGHT_PX, DPI = 560, 760, 100


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
        "accepted": col(lambda s: sum(s.detection.accepted)),
    }
    for key, _ in STAGES:
        out[key] = col(lambda s, key=key: s.report.timing_ms.get(key, nan))
    return out


def plots_png(snapshots: list[Snapshot], *, current: int | None) -> bytes:
    """The plots of `snapshots` (one per keyframe, in order) as PNG bytes; `current` is
    the keyframe marked by a vertical line."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    inertial = any(s.imu is not None for s in snapshots)
    height = HEIGHT_PX + (150 if inertial else 0)
    fig = Figure(figsize=(WIDTH_PX / DPI, height / DPI), dpi=DPI)
    fig.subplots_adjust(left=0.12, right=0.88, top=0.96, bottom=0.06, hspace=0.12)
    ratios = [3, 3, 3, 3, 3, 1.4] if inertial else [3, 3, 3, 3, 1.4]
    axes = list(fig.subplots(len(ratios), 1, sharex=True, height_ratios=ratios))
    if inertial:  # the IMU panel goes above the events strip
        axes = axes[:4] + [axes[5], axes[4]]
    d = _series(snapshots)
    x = d["keyframe"]
    style = dict(marker=".", markersize=3, linewidth=1.2)
    twins = {}

    ax = axes[0]
    ax.plot(x, d["rmse"], label="RMSE", **style)
    ax.plot(x, d["ate"], label="ATE (SE3)", **style)
    ax.set_ylabel("error (cm)")
    ax.set_title(f"{snapshots[-1].source}" if snapshots else "", fontsize=9, loc="left")

    ax = axes[1]
    ax.plot(x, d["cost0"], label="cost before", **style)
    ax.plot(x, d["cost1"], label="cost after", **style)
    if np.all(d["cost1"][np.isfinite(d["cost1"])] > 0) and len(x):
        ax.set_yscale("log")
    ax.set_ylabel("cost")
    twin = twins[1] = ax.twinx()
    twin.step(x, d["iterations"], where="mid", color="0.5", linewidth=0.9, label="iterations")
    twin.set_ylabel("iterations", color="0.4")

    ax = axes[2]
    for key, label in STAGES:
        if np.any(np.nan_to_num(d[key]) > 0):
            ax.plot(x, d[key], label=label, **style)
    ax.set_ylabel("time (ms)")

    ax = axes[3]
    ax.plot(x, d["points"], label="points tracked", **style)
    ax.plot(x, d["lines"], label="lines tracked", **style)
    ax.set_ylabel("features")
    twin = twins[3] = ax.twinx()
    twin.step(x, d["planes"], where="mid", color="tab:purple", linewidth=1.2, label="planes")
    twin.set_ylabel("planes", color="tab:purple")

    ax = axes[4]
    for row, (key, label, color, marker) in enumerate(
        (
            ("lost", "frames lost", "tab:red", "v"),
            ("reinit", "map re-initialized", "black", "x"),
            ("accepted", "plane accepted", "tab:blue", "|"),
        )
    ):
        hit = d[key] > 0
        ax.scatter(x[hit], np.full(int(hit.sum()), row), color=color, marker=marker, s=22, label=label)
    ax.set_yticks([0, 1, 2], ["lost", "re-init.", "plane"], fontsize=7)
    ax.set_ylim(-0.7, 2.7)
    ax.set_xlabel("keyframe")

    for ax in axes:
        if current is not None:
            ax.axvline(current, color="tab:red", linewidth=1.0, alpha=0.7)
        ax.grid(True, linewidth=0.3)
        ax.tick_params(labelsize=7)
        ax.yaxis.label.set_size(8)
    if inertial:
        ax = axes[5]
        with_imu = [(s.keyframe, s.imu) for s in snapshots if s.imu is not None]
        xs = np.array([keyframe for keyframe, _ in with_imu], dtype=float)
        speed = np.array([np.linalg.norm(imu.velocity_world[-1]) if imu.initialized else np.nan for _, imu in with_imu])
        ax.plot(xs, speed, label="speed", **style)
        velocity_true = [imu.velocity_true for _, imu in with_imu if imu.velocity_true is not None]
        if len(velocity_true) == len(with_imu):  # the truth is known at every keyframe
            ax.plot(xs, [np.linalg.norm(v[-1]) for v in velocity_true], label="true speed", linestyle="--", linewidth=1.0)
        ax.set_ylabel("speed (m/s)")
        twin = twins[5] = ax.twinx()
        bg = np.array([1e3 * np.linalg.norm(imu.bias[-1][3:]) for _, imu in with_imu])
        twin.plot(xs, bg, color="tab:green", linewidth=1.0, label="|gyro bias| (mrad/s)")
        twin.set_ylabel("gyro bias (mrad/s)", color="tab:green")
    for i, ax in enumerate(axes[:4] + axes[5:]):
        i = i if i < 4 else 5
        handles, labels = ax.get_legend_handles_labels()
        if i in twins:
            h2, l2 = twins[i].get_legend_handles_labels()
            handles, labels = handles + h2, labels + l2
        if handles:
            ax.legend(handles, labels, fontsize=6.5, loc="upper left", ncols=3, framealpha=0.7)
    if len(x) == 1:
        axes[0].set_xlim(x[0] - 1, x[0] + 1)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def plots_image(snapshots: list[Snapshot], *, current: int | None) -> np.ndarray:
    """:func:`plots_png` decoded to an RGB array (H, W, 3) uint8 for a GUI image."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(plots_png(snapshots, current=current))).convert("RGB"))
