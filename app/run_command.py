"""`coplanar run`: the engine headless, writing the trajectory, metrics and map (DESIGN §7).

Outputs in `--out DIR`:

- `trajectory.txt`: TUM (`t x y z qx qy qz qw`, seconds, `T_world_camera` of the rectified
  left camera), one line per tracked frame (the stereo engine's per-frame trajectory: each
  frame's pose relative to its reference keyframe composed with that keyframe's final
  estimate; lost frames are left out). The Monte-Carlo worlds have keyframes only: there it
  is the keyframes (`metrics.json` says so: `trajectory_poses`, `frames == keyframes`).
- `keyframes.txt`: the same for the keyframes only.
- `groundtruth.txt`: the ground truth of the evaluated frames (those of trajectory.txt with
  ground truth), TUM, the same timestamps: `evo_ape tum DIR/groundtruth.txt
  DIR/trajectory.txt -a` reproduces `ate_rmse_cm` (`-as`: `ate_sim3_rmse_cm`), and
  `evo_rpe tum DIR/groundtruth.txt DIR/trajectory.txt --delta 1 --delta_unit m`
  reproduces `rpe_cm_per_m`.
- `metrics.json` (see :func:`trajectory_metrics` for the trajectory figures), the combined
  `map.ply`, and the map as the usual 3D tools read it (`backend.export.map_files`):
  `points.ply` (point cloud), `lines.ply` (line set), `planes.ply` (triangle mesh with
  `plane_id`), `cameras.ply` (keyframe frustums).

The files are written into a hidden staging folder inside `--out` and moved into place only
when all are written (`backend.export.atomic`): a full disk, an error or Ctrl-C / SIGTERM
during the run leaves `--out` as it was (an earlier run's files there stay whole), and the
command says so.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

DEFAULT_DURATION_S = 30.0
# Stages the stereo engine reports as means per frame within a step (the rest: per keyframe).
PER_FRAME_STAGES = ("point_dm", "tracking", "load")


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import path
    from app.sources import add_source_arguments
    from backend.optim.problem import VARIANTS

    p = sub.add_parser("run", help="run the engine headless; write trajectory.txt (every tracked frame), keyframes.txt, groundtruth.txt, metrics.json, map.ply "
                                       "and points.ply, lines.ply, planes.ply, cameras.ply")
    add_source_arguments(p, duration_default=DEFAULT_DURATION_S)
    p.add_argument("--variant", required=True, choices=VARIANTS, help="parametrization")
    p.add_argument("--out", required=True, type=path, help="output folder (created if missing)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stereo inputs: stop after the first N frames (default all)")
    p.add_argument("--keyframes", type=int, default=None, metavar="N",
                   help="stop after N keyframes (default: mc-a / mc-b one pass of the trajectory, stereo inputs all)")
    p.add_argument("--dense", action="store_true",
                   help="image inputs: fuse the keyframes' depth (rendered, or stereo matching) into a TSDF at the estimated poses after the run; "
                        "write mesh.ply and, on rendered scenes, the mesh's distance to the true planes in metrics.json")
    p.set_defaults(run=run, history=1)


def _prepare_out(out: pathlib.Path) -> None:
    from app.cli import UsageError
    from backend.export.atomic import make_folder

    try:
        if out.exists() and not out.is_dir():
            raise UsageError(f"--out {out}: exists and is not a folder")
        make_folder(out)
        probe = out / ".coplanar-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise UsageError(f"--out {out}: cannot write there: {e.strerror or e}") from None


def _json_safe(value):  # noqa: ANN001, ANN202
    """`value` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


RPE_DELTA_M = 1.0  # path length per relative-pose-error pair, metres


def trajectory_metrics(estimate, ground_truth) -> tuple[dict, object]:  # noqa: ANN001
    """Accuracy of the poses `estimate` (a Trajectory) against `ground_truth` (a Trajectory
    of the same instants, NaN rows: none); also the evaluated ground truth (a Trajectory).

    Evaluated: the poses with ground truth (`frames_evaluated`). Positions are taken as
    written to the TUM file (9 decimals), so evo on the files gives the same figures:

    - `ate_rmse_cm`: absolute trajectory error, RMSE of the position errors after the
      least-squares rigid alignment of the estimate to the ground truth (Umeyama, SE(3));
      `evo_ape tum groundtruth.txt trajectory.txt -a`. Null below 2 evaluated poses.
    - `ate_sim3_rmse_cm`: the same after a similarity alignment (Sim(3), `-as`); null below 3.
    - `rmse_cm`: RMSE of the position errors without alignment (the engine starts at the
      ground-truth pose where there is one).
    - `rpe_cm_per_m`: relative pose error, RMSE over consecutive pose pairs about
      `rpe_delta_m` = 1 m of travelled path apart (path measured on the estimate) of the
      translation of `(Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`, in cm, i.e. cm per metre travelled;
      `evo_rpe tum groundtruth.txt trajectory.txt --delta 1 --delta_unit m`. Null when the
      path is shorter than 1 m (`rpe_pairs` 0).
    """
    import numpy as np

    from backend.eval.trajectory import ate_rmse, relative_pose_error, translational_rmse
    from backend.pipeline.snapshot import Trajectory

    valid = np.isfinite(ground_truth.t_world_camera).all(axis=1) if len(ground_truth) else np.zeros(0, bool)
    if len(ground_truth) != len(estimate):
        valid = np.zeros(len(estimate), bool)
    stamp = np.asarray(estimate.timestamp_ns)[valid]
    p_est = np.round(np.asarray(estimate.t_world_camera)[valid], 9)
    p_gt = np.round(np.asarray(ground_truth.t_world_camera)[valid], 9)
    R_est = np.asarray(estimate.R_world_camera)[valid]
    R_gt = np.asarray(ground_truth.R_world_camera)[valid]
    n = int(valid.sum())
    nan = float("nan")
    rpe = relative_pose_error(R_est, p_est, R_gt, p_gt, delta_m=RPE_DELTA_M) if n else None
    metrics = {
        "frames_evaluated": n,
        "ate_rmse_cm": 100.0 * ate_rmse(p_est, p_gt, align="se3") if n >= 2 else nan,
        "ate_sim3_rmse_cm": 100.0 * ate_rmse(p_est, p_gt, align="sim3") if n >= 3 else nan,
        "rmse_cm": 100.0 * translational_rmse(p_est, p_gt) if n else nan,
        "rpe_cm_per_m": rpe.rmse_cm_per_m if rpe is not None else nan,
        "rpe_delta_m": RPE_DELTA_M,
        "rpe_pairs": rpe.pairs if rpe is not None else 0,
    }
    return metrics, Trajectory.of(stamp, R_gt, p_gt)


def _write_staged(out: pathlib.Path, write) -> None:  # noqa: ANN001
    """`write(folder)` into a staging folder inside `out`, moved into `out` when it returns;
    a failed write (a full disk) is one line naming the file, and nothing is moved."""
    from app.cli import UsageError
    from backend.export.atomic import staged_folder

    stage = None
    try:
        with staged_folder(out) as stage:
            write(stage)
    except OSError as e:
        if e.filename:
            detail = f"{pathlib.Path(e.filename).name}: {e.strerror or e}"
        elif e.strerror:
            detail = f"the outputs: {e.strerror}"
        else:
            detail = str(e).replace(f"{stage}/", "") if stage is not None else str(e)
        raise UsageError(f"--out {out}: cannot write {detail}; nothing was written there") from None


def _write_outputs(out: pathlib.Path, snapshot, metrics: dict, *, frames, groundtruth) -> None:  # noqa: ANN001
    """trajectory.txt (`frames`: every tracked frame), keyframes.txt, groundtruth.txt,
    metrics.json, the combined map.ply and the typed points.ply, lines.ply, planes.ply and
    cameras.ply (backend.export.map_files)."""
    from backend.export.map_files import MissingLibraryError, write_map_files
    from backend.export.ply import write_ply
    from backend.export.tum import write_tum

    write_tum(out / "trajectory.txt", frames)
    write_tum(out / "keyframes.txt", snapshot.estimate)
    write_tum(out / "groundtruth.txt", groundtruth)
    (out / "metrics.json").write_text(json.dumps(_json_safe(metrics), indent=2, allow_nan=False) + "\n")
    try:
        write_map_files(snapshot, out)
    except MissingLibraryError as e:  # the run's results stay: the combined map without open3d
        write_ply(out / "map.ply", snapshot)
        print(f"warning: {e}; wrote map.ply only", file=sys.stderr)


def _no_ground_truth(estimate):  # noqa: ANN001, ANN202
    import numpy as np

    from backend.pipeline.snapshot import Trajectory

    n = len(estimate)
    return Trajectory.of(np.asarray(estimate.timestamp_ns), np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan))


def _cm(value: float) -> str:
    return f"{value:.2f} cm" if math.isfinite(value) else "n/a (no ground truth)"


def run(args: argparse.Namespace) -> int:
    from app.sources import build_engine
    from backend.pipeline.sim_engine import SimEngine

    if getattr(args, "dense", False):
        from backend.export.map_files import require_open3d

        require_open3d()  # before the run: a missing library is one line, not a lost run

    from backend.export.atomic import InterruptedAfterCommit

    engine = build_engine(args, headless=True)
    try:
        created = not args.out.exists()
    except OSError:  # a name the file system refuses: _prepare_out says so
        created = False
    try:
        if isinstance(engine, SimEngine):
            return _run_simulation(args, engine)
        return _run_stereo(args, engine)
    except InterruptedAfterCommit:
        raise
    except KeyboardInterrupt:
        earlier = args.out.is_dir() and any(not p.name.startswith(".") for p in args.out.iterdir())
        raise KeyboardInterrupt(f"nothing written to {args.out}" + ("; the files already there are as they were" if earlier else "")) from None
    finally:
        if created and args.out.is_dir() and not any(args.out.iterdir()):
            args.out.rmdir()  # a failed run leaves no empty folder it made (its parents stay)


def _run_simulation(args: argparse.Namespace, engine) -> int:  # noqa: ANN001
    import numpy as np
    from tqdm import tqdm

    from app.cli import UsageError
    from backend.eval import sequences

    n = args.keyframes if args.keyframes is not None else len(sequences.make_world(engine.settings.sequence, seed=args.seed).t_world_camera)
    if n < 1:
        raise UsageError(f"--keyframes {n}: must be at least 1")
    _prepare_out(args.out)
    timings: dict[str, list[float]] = {}
    snapshot = None
    with tqdm(total=n, desc=f"run {engine.source}", unit="kf", file=sys.stderr, disable=None) as bar:
        for _ in range(n):
            snapshot = engine.step()
            for stage, ms in snapshot.report.timing_ms.items():
                timings.setdefault(stage, []).append(ms)
            bar.update(1)
    assert snapshot is not None
    mean = {k: float(np.mean(v)) for k, v in timings.items()}
    # No images, no frames between keyframes: the trajectory is the keyframes'.
    gt = snapshot.ground_truth if snapshot.ground_truth is not None else _no_ground_truth(snapshot.estimate)
    accuracy, evaluated = trajectory_metrics(snapshot.estimate, gt)
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "trajectory_poses": "keyframes (a Monte-Carlo world has no frames between keyframes)",
        "frames": n,
        "frames_tracked": len(snapshot.estimate),
        "keyframes": n,
        **accuracy,
        "keyframe_ate_rmse_cm": snapshot.metrics.ate_cm,
        "planes": len(snapshot.planes),
        "points": len(snapshot.points),
        "lines": len(snapshot.lines),
        # DESIGN §7's stages; the simulation has no images, so no feature detection and
        # matching or segmentation: those are null. Means over keyframes, milliseconds.
        "timing_ms": {
            "point_dm": None,
            "line_dm": None,
            "plane_seg": None,
            "plane_fit": mean["detection"],
            "optimization": mean["optimization"],
            "total_per_frame": mean["total"],
            "all_stages": mean,
        },
    }
    _write_staged(args.out, lambda folder: _write_outputs(folder, snapshot, metrics, frames=snapshot.estimate, groundtruth=evaluated))
    print(f"{n} keyframes, {args.variant}: ATE {_cm(metrics['ate_rmse_cm'])} (SE3-aligned), RMSE {_cm(metrics['rmse_cm'])}, "
          f"{len(snapshot.planes)} planes; {mean['total']:.1f} ms per keyframe; "
          f"wrote {args.out}/trajectory.txt (keyframes), keyframes.txt, groundtruth.txt, metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply")
    return 0


def stereo_timing(steps: list[tuple[int, dict[str, float]]]) -> dict:
    """DESIGN §7's timing means from the steps' `(frames, timing_ms)`, milliseconds.

    The stereo engine reports `point_dm`, `tracking` and `load` as means per frame within a
    step: they are averaged per frame (each step weighted by its frames). `total` is the
    step's wall time without loading images: `total_per_frame` is Σ total / Σ frames. Every
    other stage runs once per keyframe and is averaged over the keyframes where it ran (a
    stage that did not run reports 0: the first keyframe's optimization, line D&M of P
    variants, segmentation of -wo variants); None where it never ran."""
    frames = sum(f for f, _ in steps)
    stages: list[str] = []
    for _, timing in steps:
        stages += [k for k in timing if k not in stages]
    mean: dict[str, float | None] = {}
    for stage in stages:
        if stage == "total_per_frame":
            continue
        if stage in PER_FRAME_STAGES:
            mean[stage] = sum(f * t.get(stage, 0.0) for f, t in steps) / frames if frames else None
        else:
            ran = [t[stage] for _, t in steps if t.get(stage, 0.0) != 0.0]
            mean[stage] = sum(ran) / len(ran) if ran else None
    mean["total_per_frame"] = sum(t.get("total", 0.0) for _, t in steps) / frames if frames else None
    timing = {k: mean.get(k) for k in ("point_dm", "tracking", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame")}
    timing["all_stages"] = mean
    return timing


def dense_mesh(source, snapshot, path: pathlib.Path) -> dict:  # noqa: ANN001
    """`--dense`: every keyframe's depth fused at its final estimated pose into a TSDF
    (backend.eval.dense), the mesh written to `path`; its size, the fusion time per keyframe
    and, on rendered scenes, the distance of its vertices to the true planes (cm)."""
    import numpy as np

    from backend.eval.dense import distance_to_planes, fuse_keyframes, keyframe_frames, map_bounds

    frames = keyframe_frames(source, snapshot.estimate.timestamp_ns)
    t = np.asarray(snapshot.estimate.t_world_camera)
    fusion = fuse_keyframes(source, frames, np.asarray(snapshot.estimate.R_world_camera), t, map_bounds(snapshot.points.p_world, t))
    mesh = fusion.mesh()
    o3d = fusion._o3d
    from backend.export.atomic import atomic_path
    from backend.native_output import native_stderr_silenced

    with atomic_path(path) as tmp, native_stderr_silenced():
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise OSError(f"{path}: open3d could not write the mesh (disk full?)")
    out = {
        "keyframes_fused": fusion.keyframes, "fusion_ms_per_keyframe": fusion.time_ms / max(fusion.keyframes, 1),
        "voxel_m": fusion.voxel_m, "vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
        "distance_to_true_planes_cm": None,
    }
    table = getattr(source, "plane_table", None)
    if table is not None and len(mesh.vertices):
        d = 100.0 * distance_to_planes(np.asarray(mesh.vertices), table)
        out["distance_to_true_planes_cm"] = {"median": float(np.median(d)), "p90": float(np.percentile(d, 90)), "within_2cm": float(np.mean(d < 2.0))}
    return out


def vio_metrics(snapshot, frames) -> dict:  # noqa: ANN001
    """The VIO part of metrics.json: the first initialization (keyframe, time, what the
    alignment estimated and, on rendered scenes, its errors; the latest one's too, after a
    loss VIO starts again; the gravity direction and gyroscope bias errors after the
    refinement by the windows with IMU factors), the last keyframe's velocity and biases,
    and the scale error of the whole trajectory (the Sim(3) alignment's scale minus one, in
    percent, over the tracked frames with ground truth after the initialization)."""
    import numpy as np

    from backend.eval.trajectory import ate_rmse, umeyama_alignment

    imu = snapshot.imu
    first = imu.first_init_keyframe

    def time_s(k: int) -> float | None:
        return float((snapshot.estimate.timestamp_ns[k] - snapshot.estimate.timestamp_ns[0]) * 1e-9) if k >= 0 else None

    out = {
        "initialized": imu.initialized, "status": imu.status,
        "init_keyframe": first, "init_time_s": time_s(first), "alignment": imu.first_report,
        "last_init_keyframe": imu.init_keyframe, "last_init_time_s": time_s(imu.init_keyframe), "last_alignment": imu.report,
        "velocity_world": imu.velocity_world[-1].tolist(), "bias_accel": imu.bias[-1][:3].tolist(), "bias_gyro": imu.bias[-1][3:].tolist(),
        "scale_error_pct": None,
    }
    if first >= 0 and snapshot.ground_truth is not None:
        # Gravity after the refinement: the angle between the world's vertical seen from the
        # estimated and from the true keyframe orientation (roll and pitch error), at the
        # initialization keyframe as the windows with IMU factors left it, and over all
        # keyframes since.
        z = np.array([0.0, 0.0, 1.0])
        R_est = np.asarray(snapshot.estimate.R_world_camera)[first:]
        R_gt = np.asarray(snapshot.ground_truth.R_world_camera)[first:]
        ok = np.all(np.isfinite(R_gt.reshape(len(R_gt), -1)), axis=1)
        a, b = R_est[ok].transpose(0, 2, 1) @ z, R_gt[ok].transpose(0, 2, 1) @ z
        tilt = np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))
        if len(tilt):
            out["gravity_error_refined_deg"] = float(tilt[0])
            out["tilt_error_median_deg"] = float(np.median(tilt))
    if first >= 0 and imu.bias_true is not None:
        # The gyroscope bias after the refinement likewise: the initialization keyframe's, as
        # the windows with IMU factors left it, and the median over the keyframes since.
        b_est, b_true = np.asarray(imu.bias)[first:, 3:], np.asarray(imu.bias_true)[first:, 3:]
        pct = 100.0 * np.linalg.norm(b_est - b_true, axis=1) / np.maximum(np.linalg.norm(b_true, axis=1), 1e-12)
        out["bias_gyro_error_refined_pct"] = float(pct[0])
        out["bias_gyro_error_median_pct"] = float(np.median(pct))
    if first >= 0:
        t0 = snapshot.estimate.timestamp_ns[first]
        p_est, p_gt = np.asarray(frames.estimate.t_world_camera), np.asarray(frames.ground_truth.t_world_camera)
        sel = (np.asarray(frames.estimate.timestamp_ns) >= t0) & np.all(np.isfinite(p_gt), axis=1)
        if sel.sum() >= 3:
            _, _, scale = umeyama_alignment(p_est[sel], p_gt[sel], with_scale=True)
            out["scale_error_pct"] = float(100.0 * (scale - 1.0))
            # The frames before the first initialization have no metric scale (a failed start
            # keeps its arbitrary unit): VIO's accuracy is that of the frames from it on.
            out["frames_after_init"] = int(sel.sum())
            out["ate_after_init_cm"] = float(100.0 * ate_rmse(p_est[sel], p_gt[sel], align="se3"))
            out["ate_sim3_after_init_cm"] = float(100.0 * ate_rmse(p_est[sel], p_gt[sel], align="sim3"))
    return out


def _run_stereo(args: argparse.Namespace, engine) -> int:  # noqa: ANN001
    from tqdm import tqdm

    from app.cli import UsageError
    from backend.pipeline.engine import EndOfSequence

    if args.keyframes is not None and args.keyframes < 1:
        raise UsageError(f"--keyframes {args.keyframes}: must be at least 1")
    _prepare_out(args.out)
    total_frames = len(engine.data_source)
    steps: list[tuple[int, dict[str, float]]] = []
    messages: list[str] = []
    lost = reinitializations = 0
    reasons: dict[str, int] = {}
    snapshot = None
    bar = tqdm(total=total_frames, desc=f"run {args.variant}", unit="frame", file=sys.stderr, disable=None, dynamic_ncols=True)
    engine.on_frame = lambda _index: bar.update(1)
    try:
        while args.keyframes is None or len(steps) < args.keyframes:
            try:
                snapshot = engine.step()
            except EndOfSequence:
                break
            tracking = snapshot.tracking
            steps.append((tracking.frames, dict(snapshot.report.timing_ms)))
            lost += tracking.lost_frames
            reinitializations += tracking.reinitializations
            reasons[tracking.keyframe_reason] = reasons.get(tracking.keyframe_reason, 0) + 1
            if snapshot.message:
                messages.append(f"keyframe {snapshot.keyframe}: {snapshot.message}")
                bar.write(f"keyframe {snapshot.keyframe}: {snapshot.message}", file=sys.stderr)
    except BaseException:
        bar.leave = False  # an error line (or the interruption) follows: no half-drawn bar above it
        raise
    finally:
        bar.close()
        engine.on_frame = None
    if snapshot is None:
        raise UsageError(f"{engine.source}: no keyframe in {engine.frames} frames")
    frames = engine.frame_trajectory()
    accuracy, evaluated = trajectory_metrics(frames.estimate, frames.ground_truth)
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "trajectory_poses": "tracked frames",
        "frames": engine.frames,
        "frames_tracked": len(frames),
        "keyframes": len(snapshot.estimate),
        **accuracy,
        "keyframe_ate_rmse_cm": snapshot.metrics.ate_cm,
        "keyframe_rmse_cm": snapshot.metrics.rmse_cm,
        "planes": len(snapshot.planes),
        "points": len(snapshot.points),
        "lines": len(snapshot.lines),
        "lost_frames": lost,
        "reinitializations": reinitializations,
        "keyframe_reasons": reasons,
        "timing_ms": stereo_timing(steps),
        "messages": messages,
    }
    if snapshot.imu is not None:
        metrics["mode"] = "vio"
        metrics["vio"] = vio_metrics(snapshot, frames)

    def write(folder: pathlib.Path) -> None:
        if getattr(args, "dense", False):
            metrics["dense"] = dense_mesh(engine.data_source, snapshot, folder / "mesh.ply")
        _write_outputs(folder, snapshot, metrics, frames=frames.estimate, groundtruth=evaluated)

    _write_staged(args.out, write)
    per_frame = metrics["timing_ms"]["total_per_frame"]
    print(f"{engine.frames} frames, {metrics['keyframes']} keyframes, {args.variant}: ATE {_cm(metrics['ate_rmse_cm'])} (SE3-aligned, "
          f"{metrics['frames_evaluated']} frames), RMSE {_cm(metrics['rmse_cm'])}, {len(snapshot.planes)} planes, {lost} lost frames, "
          f"{reinitializations} re-initializations; {per_frame:.1f} ms per frame; "
          f"wrote {args.out}/trajectory.txt, keyframes.txt, groundtruth.txt, metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply")
    return 0
