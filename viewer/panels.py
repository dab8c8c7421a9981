"""The debugger's text panels (markdown): the report of a snapshot, the variants computed at
one keyframe side by side, the A/B run's differences; and the TUM text of an export."""

from __future__ import annotations

import io
import math
from collections.abc import Mapping

import numpy as np

from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot, Trajectory
from viewer import images

#: Stage names of `OptimizationReport.timing_ms` as the report's timing table shows them.
STAGE_LABELS = {
    "load": "reading images",
    "load_wait": "waiting for images",
    "point_dm": "point D&M",
    "tracking": "tracking",
    "line_dm": "line D&M",
    "mapping": "mapping",
    "plane_seg": "plane segmentation",
    "plane_fit": "plane fitting",
    "setup": "problem set-up",
    "linearize": "linearize",
    "solve": "solve",
    "update": "update",
    "optimization": "optimization",
    "culling": "culling",
    "image": "keyframe image",
    "total": "total",
    "total_per_frame": "total per frame",
}


def _num(value: float, digits: int = 2) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def timing_table(timing_ms: dict[str, float]) -> str:
    """The stage times as a two-column table (ms), in the pipeline's order."""
    rows = "\n".join(f"| {STAGE_LABELS.get(k, k)} | {v:.1f} |" for k, v in timing_ms.items())
    return f"| stage | ms |\n|---|---|\n{rows}"


def report_markdown(s: Snapshot) -> str:
    """Everything about one snapshot: solve, trajectory error, map, detection, timing."""
    r = s.report
    det = s.detection
    rows = "\n".join(
        f"| {q} | {c} | {i} ({100.0 * i / max(c, 1):.0f}%) | {'accepted → plane ' + str(p) if a else 'rejected'} |"
        for q, c, i, a, p in zip(det.instance, det.candidates, det.inliers, det.accepted, det.plane)
    )
    detection = f"| instance | candidates | consensus | result |\n|---|---|---|---|\n{rows}" if rows else "no candidate set reached the size threshold"
    notes = f"**{s.message}**\n\n" if s.message else ""
    if s.tracking is not None and s.image is None:  # otherwise shown beside the image
        notes += images.tracking_markdown(s.tracking) + "\n\n"
    dropped = f"; {images.plural(r.dropped_landmarks, 'landmark')} left out of a step" if r.dropped_landmarks else ""
    return (
        f"**keyframe {s.keyframe}** · {r.variant} · window {r.window} + {r.fixed_poses} fixed\n\n"
        f"{notes}"
        f"{images.plural(r.iterations, 'iteration')} ({r.termination or ('converged' if r.converged else 'not converged')}{dropped}) · "
        f"cost {r.initial_cost:.4g} → {r.final_cost:.4g}\n\n"
        f"**trajectory error**: RMSE {s.metrics.rmse_cm:.2f} cm · ATE (SE3) {s.metrics.ate_cm:.2f} cm\n\n"
        f"**map**: {images.plural(len(s.points), 'point')} · {images.plural(len(s.lines), 'line')} · {images.plural(len(s.planes), 'plane')}\n\n"
        f"{imu_markdown(s)}"
        f"**co-planar detection** (θ_cp = 80 %)\n\n{detection}\n\n"
        f"**time**\n\n{timing_table(r.timing_ms)}"
    )


def imu_markdown(s: Snapshot) -> str:
    """VIO's inertial state at the snapshot's keyframe (empty for the other engines): the
    initialization's status and figures, velocity, biases and gravity, with the truth where
    the input has it."""
    imu = s.imu
    if imu is None:
        return ""
    v = imu.velocity_world[-1]
    b = imu.bias[-1]

    def vec(x: np.ndarray, digits: int = 3) -> str:
        return "(" + ", ".join(_num(float(c), digits) for c in x) + ")"

    rows = [
        f"| velocity (m/s, world) | {vec(v)} | {vec(imu.velocity_true[-1]) if imu.velocity_true is not None else '–'} |",
        f"| accelerometer bias (m/s²) | {vec(b[:3], 4)} | {vec(imu.bias_true[-1][:3], 4) if imu.bias_true is not None else '–'} |",
        f"| gyroscope bias (rad/s) | {vec(b[3:], 5)} | {vec(imu.bias_true[-1][3:], 5) if imu.bias_true is not None else '–'} |",
        f"| gravity (m/s², world) | {vec(imu.gravity_world, 2)} | (0, 0, -9.81) |",
    ]
    init = ""
    rep = imu.report
    if imu.initialized:
        figures = [f"scale {_num(rep.get('scale', float('nan')), 3)}"]
        truth_figures = (
            ("gravity_error_deg", "gravity error", "°"),
            ("scale_error_pct", "alignment's scale error", " %"),
            ("joint_scale_error_pct", "after the joint solve", " %"),
            ("bias_gyro_error_pct", "gyro bias error", " %"),
        )
        for key, label, unit in truth_figures:
            if key in rep:
                figures.append(f"{label} {_num(rep[key], 2)}{unit}")
        for r in rep.get("refinements", []):
            after = f", {_num(r['scale_error_pct'], 2)} % against the truth" if "scale_error_pct" in r else ""
            figures.append(f"refined at keyframe {r['keyframe']} ({_num(r['after_start_s'], 1)} s after) ×{_num(r['scale'], 3)}{after}")
        if rejections := rep.get("refinement_rejections"):
            figures.append(f"{rejections} refinement alignment(s) rejected, the last: {rep.get('refinement_last_rejection', '')}")
        init = f"initialized at keyframe {imu.init_keyframe}: " + ", ".join(figures) + " (against the truth where known)\n\n"
    return f"**IMU** ({'initialized' if imu.initialized else 'not initialized'}): {imu.status}\n\n{init}| | estimate | truth |\n|---|---|---|\n" + "\n".join(rows) + "\n\n"


#: A scale known to worse than this (1σ, relative) is flagged: twice it exceeds the 10 % a
#: user would notice in the map's size. The engine's start accepts up to 30 % and refines it
#: later (backend/pipeline/vio_settings.py); this is the debugger's warning, not a tuned figure.
UNCERTAIN_SCALE = 0.05
#: Accelerometer excitation (VINS-Mono's std of Δv/Δt) below which the start says so.
LOW_EXCITATION_MPS2 = 0.25


def vio_start_note(s: Snapshot) -> str:
    """One line on VIO's start for the status line (empty for the other engines): while
    waiting, what it waits for; once initialized, how well the scale is known (σ from the
    alignment) and, when it is uncertain, why (little acceleration or rotation at the start)
    and what helps; the truth's scale error where the input has it."""
    imu = s.imu
    if imu is None:
        return ""
    if not imu.initialized:
        return f"VIO not initialized yet: {imu.status}"
    rep = imu.report
    quality = rep.get("quality") or {}
    sigma = float(quality.get("scale_rel_std", float("nan")))
    excitation = float(quality.get("accel_excitation_mps2", float("nan")))
    rotation = float(quality.get("rotation_span_deg", float("nan")))
    span = float(rep.get("span_s", float("nan")))
    head = f"initialized at keyframe {imu.init_keyframe} ({_num(span, 1)} s of motion), the alignment's scale known to ±{_num(100 * sigma, 0)} % (1σ)"
    truth = rep.get("joint_scale_error_pct", rep.get("scale_error_pct"))
    against = f"; after the joint solve {_num(float(truth), 1)} % against the truth" if truth is not None and math.isfinite(float(truth)) else ""
    if refinements := rep.get("refinements"):
        last = refinements[-1]
        sigma = float(last["scale_rel_std"])
        error = last.get("scale_error_pct")
        against = f", {_num(float(error), 1)} % against the truth" if error is not None and math.isfinite(float(error)) else ""
        head = (
            f"initialized at keyframe {imu.init_keyframe} ({_num(span, 1)} s of motion); its scale refined at keyframe {last['keyframe']} "
            f"({_num(float(last['after_start_s']), 1)} s after the start) ×{_num(float(last['scale']), 3)}, known to ±{_num(100 * sigma, 0)} % (1σ)"
        )
        if not (math.isfinite(sigma) and sigma > UNCERTAIN_SCALE):
            return f"VIO {head}{against}"
        return f"**uncertain VIO scale**: {head}{against}. More motion (faster, or turning while moving) determines it better."
    if not (math.isfinite(sigma) and sigma > UNCERTAIN_SCALE):
        return f"VIO {head}{against}"
    why = []
    if math.isfinite(excitation) and excitation < LOW_EXCITATION_MPS2:
        why.append(f"little acceleration ({_num(excitation, 2)} m/s²)")
    if math.isfinite(rotation) and rotation < 15.0:
        why.append(f"little rotation ({_num(rotation, 0)}°)")
    because = f", because the start had {' and '.join(why)}" if why else ": the start's motion barely constrains it"
    return (
        f"**uncertain VIO start**: {head}{because}{against}. The window's joint solve refines the scale from there, and the alignment again with more motion "
        "(15 s after the start); an error left shows in the "
        "map's size and the trajectory. A start with more motion (faster, or turning while moving: `--speed 2` on rendered scenes) gives a better one; Reset to start again."
    )


def variants_markdown(variants: Mapping[Variant, Snapshot], *, shown: Snapshot, newest_keyframe: int) -> str:
    """The variants computed at one keyframe (the stepped one first; every other one
    re-optimized the same window from the state that step left), side by side; at an older
    keyframe than the newest, where no more can be added, it says so."""
    if not variants:
        return "no keyframe yet"
    first = next(iter(variants))
    rows = []
    for name, s in variants.items():
        r = s.report
        mark = " ◀ shown" if s is shown else ""
        how = "step" if name == first else "re-optimized"
        rows.append(
            f"| **{name}**{mark} | {how} | {r.items} / {r.params} | {r.initial_cost:.4g} → {r.final_cost:.4g} | {r.iterations} "
            f"| {r.timing_ms.get('optimization', float('nan')):.0f} | {_num(s.metrics.rmse_cm)} | {_num(s.metrics.ate_cm)} |"
        )
    if shown.keyframe == newest_keyframe:
        how_to_add = "choose another in *Variant* to add it; every re-optimization starts from the state the step left"
    else:
        how_to_add = f"kept from when it was the newest; variants can be added at the newest keyframe ({newest_keyframe}) only, where the engine's state is"
    return (
        f"**keyframe {shown.keyframe}**: the variants computed here ({how_to_add})\n\n"
        "| variant | from | items / params | cost | iter. | opt. ms | RMSE cm | ATE cm |\n|---|---|---|---|---|---|---|---|\n" + "\n".join(rows)
    )


def ab_markdown(a: Snapshot, b: Snapshot | None) -> str:
    """The A/B run at keyframe `a.keyframe`: both runs' figures and B − A."""
    if b is None:
        return f"**A/B run**: B has no snapshot at keyframe {a.keyframe} (it started later, or was re-optimized only): step to see both."

    def row(label: str, va: float, vb: float, digits: int = 2) -> str:
        diff = vb - va if math.isfinite(va) and math.isfinite(vb) else float("nan")
        return f"| {label} | {_num(va, digits)} | {_num(vb, digits)} | {_num(diff, digits)} |"

    ra, rb = a.report, b.report
    ta, tb = a.estimate.timestamp_ns[-1], b.estimate.timestamp_ns[-1]
    same = "same frame" if ta == tb else f"different frames: A at {ta * 1e-9:.3f} s, B at {tb * 1e-9:.3f} s"
    gap = float(np.linalg.norm(a.estimate.t_world_camera[-1] - b.estimate.t_world_camera[-1])) * 100.0
    return f"**A/B run** at keyframe {a.keyframe} ({same}); newest cameras {gap:.2f} cm apart\n\n| | A: {ra.variant} | B: {rb.variant} | B − A |\n|---|---|---|---|\n" + "\n".join(
        [
            row("RMSE (cm)", a.metrics.rmse_cm, b.metrics.rmse_cm),
            row("ATE (cm)", a.metrics.ate_cm, b.metrics.ate_cm),
            row("cost after", ra.final_cost, rb.final_cost, 1),
            row("iterations", ra.iterations, rb.iterations, 0),
            row("optimization (ms)", ra.timing_ms.get("optimization", float("nan")), rb.timing_ms.get("optimization", float("nan")), 1),
            row("params", ra.params, rb.params, 0),
            row("points", len(a.points), len(b.points), 0),
            row("planes", len(a.planes), len(b.planes), 0),
        ]
    )


def tum_bytes(trajectory: Trajectory, *, comment: str = "") -> bytes:
    """`trajectory` as TUM text (`t x y z qx qy qz qw`, seconds, metres), `comment` in its
    `#` header."""
    from backend.export.tum import write_tum

    buffer = io.StringIO()
    write_tum(buffer, trajectory, comment=comment)
    return buffer.getvalue().encode()
