"""`coplanar run`: the engine headless, writing the trajectory, metrics and map (DESIGN §7).

Outputs in `--out DIR`:

- `trajectory.txt`: TUM (`t x y z qx qy qz qw`, seconds), one line per tracked frame (the
  stereo engine's per-frame trajectory: each frame's pose relative to its reference keyframe
  composed with that keyframe's final estimate; lost frames are left out). The poses are of
  the frame the dataset's own ground truth gives poses of (`--trajectory-frame truth`, the
  default: EuRoC's and rendered scenes' IMU body, `T_world_body = T_world_rect0 ·
  T_body_rect0⁻¹`; KITTI's left camera), or of the rectified left camera as the engine
  estimates them (`--trajectory-frame camera`); the header comment and `metrics.json`
  (`trajectory_frame`, `trajectory_frame_note`, `T_frame_rect0`) say which
  (`backend.export.output_frame`). The Monte-Carlo worlds have keyframes only: there it is
  the keyframes, of the simulated camera (`metrics.json` says so: `trajectory_poses`,
  `frames == keyframes`).
- `keyframes.txt`: the same for the keyframes only.
- `groundtruth.txt`: the ground truth of the evaluated frames (those of trajectory.txt with
  ground truth), TUM, in the same frame, the same timestamps: `evo_ape tum
  DIR/groundtruth.txt DIR/trajectory.txt -a` reproduces `ate_rmse_cm` (`-as`:
  `ate_sim3_rmse_cm`), and `evo_rpe tum DIR/groundtruth.txt DIR/trajectory.txt --delta 1
  --delta_unit m` reproduces `rpe_cm_per_m`. Where the dataset's ground truth is a file of
  timed samples (EuRoC's `state_groundtruth_estimate0/data.csv`), a frame's ground truth is
  the sample nearest in time (within 10 ms), as evo pairs them: with the default frame,
  `evo_ape euroc DATASET/mav0/state_groundtruth_estimate0/data.csv DIR/trajectory.txt -a`
  reproduces `ate_rmse_cm` too.
- `metrics.json` (see :func:`backend.eval.run_metrics.trajectory_metrics` for the trajectory
  figures, all computed on the written poses), the combined
  `map.ply`, and the map as the usual 3D tools read it (`backend.export.map_files`):
  `points.ply` (point cloud), `lines.ply` (line set), `planes.ply` (triangle mesh with
  `plane_id`), `cameras.ply` (keyframe frustums).

The files are written into a hidden staging folder inside `--out` and moved into place only
when all are written (`backend.common.atomic`): a full disk, an error or Ctrl-C / SIGTERM
during the run leaves `--out` as it was (an earlier run's files there stay whole), and the
command says so.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import sys
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from backend.data.source import StereoSource
    from backend.export.output_frame import OutputFrame, TrajectoryFrame
    from backend.pipeline.snapshot import Trajectory

DEFAULT_DURATION_S = 30.0
# Stages the stereo engine reports as means per frame within a step (the rest: per keyframe).


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import path
    from app.sources import add_source_arguments
    from backend.export.output_frame import TrajectoryFrame
    from backend.optim.variant import VARIANT_NAMES

    p = sub.add_parser(
        "run", help="run the engine headless; write trajectory.txt (every tracked frame), keyframes.txt, groundtruth.txt, metrics.json, map.ply and points.ply, lines.ply, planes.ply, cameras.ply"
    )
    add_source_arguments(p, duration_default=DEFAULT_DURATION_S)
    p.add_argument("--variant", required=True, choices=VARIANT_NAMES, help="parametrization")
    p.add_argument("--out", required=True, type=path, help="output folder (created if missing)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="stereo inputs: stop after the first N frames (default all)")
    p.add_argument(
        "--trajectory-frame",
        choices=[str(f) for f in TrajectoryFrame],
        default=str(TrajectoryFrame.TRUTH),
        help="what the written trajectories are poses of: truth (default): the frame of the dataset's own ground truth (EuRoC, rendered scenes: the IMU body), "
        "so evo against the dataset's ground-truth file reproduces metrics.json; camera: the rectified left camera, as the engine estimates it",
    )
    p.add_argument("--keyframes", type=int, default=None, metavar="N", help="stop after N keyframes (default: mc-a / mc-b one pass of the trajectory, stereo inputs all)")
    p.add_argument(
        "--dense",
        action="store_true",
        help="image inputs: fuse the keyframes' depth (rendered, or stereo matching) into a TSDF at the estimated poses after the run; "
        "write mesh.ply and, on rendered scenes, the mesh's distance to the true planes in metrics.json",
    )
    p.set_defaults(run=run, history=1)


def _prepare_out(out: pathlib.Path) -> None:
    from app.errors import UsageError
    from backend.common.atomic import make_folder

    try:
        if out.exists() and not out.is_dir():
            raise UsageError(f"--out {out}: exists and is not a folder")
        make_folder(out)
        probe = out / ".coplanar-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise UsageError(f"--out {out}: cannot write there: {e.strerror or e}") from None


def _json_safe(value):
    """`value` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_staged(out: pathlib.Path, write) -> None:
    """`write(folder)` into a staging folder inside `out`, moved into `out` when it returns;
    a failed write (a full disk) is one line naming the file, and nothing is moved."""
    from app.errors import UsageError
    from backend.common.atomic import staged_folder

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


class Evaluated(NamedTuple):
    """Poses as written (`poses`, of the output frame), the ground truth each is evaluated
    against (`truth`, the same instants, NaN rows: none), their accuracy (the metrics.json
    figures) and the evaluated ground truth (`groundtruth`: groundtruth.txt)."""

    poses: Trajectory
    truth: Trajectory
    accuracy: dict[str, Any]
    groundtruth: Trajectory


def evaluate(frame: OutputFrame, source: StereoSource | None, estimate: Trajectory, truth: Trajectory) -> Evaluated:
    """`estimate` (`T_world_rect0`) as poses of `frame` and their accuracy against the ground
    truth in that frame (`truth`: the source's own, `T_world_rect0`, NaN rows: none; where
    `source` holds timed samples, the sample nearest each pose: backend.export.output_frame)."""
    from backend.eval.run_metrics import trajectory_metrics
    from backend.export.output_frame import ground_truth_in
    from backend.pipeline.snapshot import Trajectory

    poses = frame.poses(estimate)
    in_frame = ground_truth_in(frame, source, truth)
    accuracy, evaluated = trajectory_metrics(poses, in_frame)
    return Evaluated(poses, in_frame, accuracy, Trajectory.of(*evaluated))


def _frame_metrics(frame: OutputFrame) -> dict[str, Any]:
    """What metrics.json says of the written poses' frame."""
    return {"trajectory_frame": frame.name, "trajectory_frame_note": frame.note, "T_frame_rect0": frame.T_frame_rect0.tolist()}


def _write_outputs(out: pathlib.Path, snapshot, metrics: dict, *, frame: OutputFrame, frames: Trajectory, keyframes: Trajectory, groundtruth: Trajectory) -> None:
    """trajectory.txt (`frames`: every tracked frame), keyframes.txt, groundtruth.txt (all
    three poses of `frame`, which their header says), metrics.json, the combined map.ply and
    the typed points.ply, lines.ply, planes.ply and cameras.ply (backend.export.map_files)."""
    from backend.common.optional import MissingLibraryError
    from backend.export.map_files import write_map_files
    from backend.export.ply import write_ply
    from backend.export.tum import write_tum

    write_tum(out / "trajectory.txt", frames, comment=f"coplanar run, every tracked frame: {frame.note}")
    write_tum(out / "keyframes.txt", keyframes, comment=f"coplanar run, keyframes: {frame.note}")
    write_tum(out / "groundtruth.txt", groundtruth, comment=f"coplanar run, ground truth of the evaluated frames: {frame.note}")
    (out / "metrics.json").write_text(json.dumps(_json_safe(metrics), indent=2, allow_nan=False) + "\n")
    try:
        write_map_files(snapshot, out)
    except MissingLibraryError as e:  # the run's results stay: the combined map without open3d
        write_ply(out / "map.ply", snapshot)
        print(f"warning: {e}; wrote map.ply only", file=sys.stderr)


def _no_ground_truth(estimate: Trajectory) -> Trajectory:
    import numpy as np

    from backend.pipeline.snapshot import Trajectory

    n = len(estimate)
    return Trajectory.of(np.asarray(estimate.timestamp_ns), np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan))


def _frame_choice(args: argparse.Namespace) -> TrajectoryFrame:
    """`--trajectory-frame` (the default where a caller's namespace has none)."""
    from backend.export.output_frame import TrajectoryFrame

    return TrajectoryFrame(getattr(args, "trajectory_frame", TrajectoryFrame.TRUTH))


def _cm(value: float) -> str:
    return f"{value:.2f} cm" if math.isfinite(value) else "n/a (no ground truth)"


def run(args: argparse.Namespace) -> int:
    from app.sources import build_engine
    from backend.pipeline.sim_engine import SimEngine

    if getattr(args, "dense", False):
        from backend.common.optional import require_open3d

        require_open3d()  # before the run: a missing library is one line, not a lost run

    from backend.common.atomic import InterruptedAfterCommit

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


def _run_simulation(args: argparse.Namespace, engine) -> int:
    import numpy as np
    from tqdm import tqdm

    from app.errors import UsageError
    from backend.eval import sequences
    from backend.export.output_frame import output_frame

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
    frame = output_frame(None, choice=_frame_choice(args))
    written = evaluate(frame, None, snapshot.estimate, gt)
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "trajectory_poses": "keyframes (a Monte-Carlo world has no frames between keyframes)",
        **_frame_metrics(frame),
        "frames": n,
        "frames_tracked": len(snapshot.estimate),
        "keyframes": n,
        **written.accuracy,
        "keyframe_ate_rmse_cm": written.accuracy["ate_rmse_cm"],
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
    _write_staged(args.out, lambda folder: _write_outputs(folder, snapshot, metrics, frame=frame, frames=written.poses, keyframes=written.poses, groundtruth=written.groundtruth))
    print(
        f"{n} keyframes, {args.variant}: ATE {_cm(metrics['ate_rmse_cm'])} (SE3-aligned), RMSE {_cm(metrics['rmse_cm'])}, "
        f"{len(snapshot.planes)} planes; {mean['total']:.1f} ms per keyframe; "
        f"wrote {args.out}/trajectory.txt (keyframes), keyframes.txt, groundtruth.txt, metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply"
    )
    return 0


def dense_mesh(source, snapshot, path: pathlib.Path) -> dict:
    """`--dense`: every keyframe's depth fused at its final estimated pose into a TSDF
    (backend.eval.dense), the mesh written to `path`; its size, the fusion time per keyframe
    and, on rendered scenes, the distance of its vertices to the true planes (cm)."""
    import numpy as np

    from backend.data.source import RenderedTruth
    from backend.eval.dense import distance_to_planes, fuse_keyframes, keyframe_frames, map_bounds

    frames = keyframe_frames(source, snapshot.estimate.timestamp_ns)
    t = np.asarray(snapshot.estimate.t_world_camera)
    fusion = fuse_keyframes(source, frames, np.asarray(snapshot.estimate.R_world_camera), t, map_bounds(snapshot.points.p_world, t))
    mesh = fusion.mesh()
    o3d = fusion._o3d
    from backend.common.atomic import atomic_path
    from backend.common.native_output import native_stderr_silenced

    with atomic_path(path) as tmp, native_stderr_silenced():
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise OSError(f"{path}: open3d could not write the mesh (disk full?)")
    out: dict[str, object] = {
        "keyframes_fused": fusion.keyframes,
        "fusion_ms_per_keyframe": fusion.time_ms / max(fusion.keyframes, 1),
        "voxel_m": fusion.voxel_m,
        "vertices": len(mesh.vertices),
        "triangles": len(mesh.triangles),
        "distance_to_true_planes_cm": None,
    }
    if isinstance(source, RenderedTruth) and len(mesh.vertices):
        d = 100.0 * distance_to_planes(np.asarray(mesh.vertices), source.plane_table)
        out["distance_to_true_planes_cm"] = {"median": float(np.median(d)), "p90": float(np.percentile(d, 90)), "within_2cm": float(np.mean(d < 2.0))}
    return out


def _run_stereo(args: argparse.Namespace, engine) -> int:
    from tqdm import tqdm

    from app.errors import UsageError
    from backend.eval.run_metrics import stereo_timing, vio_metrics
    from backend.export.output_frame import output_frame
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
    source = engine.data_source
    frame = output_frame(source, choice=_frame_choice(args))
    frames = engine.frame_trajectory()
    written = evaluate(frame, source, frames.estimate, frames.ground_truth)
    keyframe_truth = snapshot.ground_truth if snapshot.ground_truth is not None else _no_ground_truth(snapshot.estimate)
    keyframes = evaluate(frame, source, snapshot.estimate, keyframe_truth)
    metrics = {
        "source": engine.source,
        "variant": args.variant,
        "trajectory_poses": "tracked frames",
        **_frame_metrics(frame),
        "frames": engine.frames,
        "frames_tracked": len(frames),
        "keyframes": len(snapshot.estimate),
        **written.accuracy,
        "keyframe_ate_rmse_cm": keyframes.accuracy["ate_rmse_cm"],
        "keyframe_rmse_cm": keyframes.accuracy["rmse_cm"],
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
        metrics["vio"] = vio_metrics(snapshot, dataclasses.replace(frames, estimate=written.poses, ground_truth=written.truth))

    def write(folder: pathlib.Path) -> None:
        if getattr(args, "dense", False):
            metrics["dense"] = dense_mesh(source, snapshot, folder / "mesh.ply")
        _write_outputs(folder, snapshot, metrics, frame=frame, frames=written.poses, keyframes=keyframes.poses, groundtruth=written.groundtruth)

    _write_staged(args.out, write)
    per_frame = metrics["timing_ms"]["total_per_frame"]
    print(
        f"{engine.frames} frames, {metrics['keyframes']} keyframes, {args.variant}: ATE {_cm(metrics['ate_rmse_cm'])} (SE3-aligned, "
        f"{metrics['frames_evaluated']} frames), RMSE {_cm(metrics['rmse_cm'])}, {len(snapshot.planes)} planes, {lost} lost frames, "
        f"{reinitializations} re-initializations; {per_frame:.1f} ms per frame; "
        f"wrote {args.out}/trajectory.txt, keyframes.txt, groundtruth.txt (poses of {frame.name}), metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply"
    )
    return 0
