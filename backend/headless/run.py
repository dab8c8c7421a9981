"""One headless run: the engine an :class:`EngineConfig` describes, stepped to the end of its
input (or a number of keyframes), its figures computed and its outputs written to one folder,
complete or not at all. `coplanar run` and every run of `coplanar sweep` call
:func:`run_headless`; neither builds an engine or writes a run's files any other way.

Outputs in the folder (DESIGN §7; `app/run_command.py` describes each file):
`trajectory.txt`, `keyframes.txt`, `groundtruth.txt` (TUM, seconds; poses of the frame the
dataset's own ground truth is of by default, or of the rectified left camera:
`backend.export.output_frame`, named in each file's header and in metrics.json), `metrics.json`, `map.ply`, `points.ply`, `lines.ply`, `planes.ply`,
`cameras.ply`, and `mesh.ply` with `dense`. They are written into a hidden staging folder
inside it and moved into place when all are written (`backend.common.atomic`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

from backend.export.output_frame import TrajectoryFrame

if TYPE_CHECKING:
    from backend.data.source import StereoSource
    from backend.export.output_frame import OutputFrame
    from backend.pipeline.factory import EngineConfig
    from backend.pipeline.sim_engine import SimEngine
    from backend.pipeline.snapshot import Snapshot, Trajectory

PLANE_RECOVERY_NOTE = (
    "rendered scenes: the true planes covering at least 5 % of some keyframe's left image (seen), and those a map plane "
    "matches within 10 degrees with its patch within 10 cm of the true plane (recovered)"
)
RUN_FILES = ("trajectory.txt", "keyframes.txt", "groundtruth.txt", "metrics.json", "map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")


class RunError(Exception):
    """A run that ended without results (no keyframe in its input): one line."""


class RecordPathError(RunError):
    """`record` names a file that cannot be written; the message starts with its path."""


class OutputError(RunError):
    """The output folder cannot be made or written; the message starts with its path and
    nothing was written there."""


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What a finished run wrote and said: `metrics` as written to metrics.json (JSON values:
    None where a figure is not finite), `summary` the one line `coplanar run` prints, and
    `wall_s` the seconds from building the engine to the last file written."""

    metrics: dict[str, Any]
    summary: str
    wall_s: float


def run_headless(
    config: EngineConfig,
    out: pathlib.Path,
    *,
    keyframes: int | None = None,
    dense: bool = False,
    trajectory_frame: TrajectoryFrame = TrajectoryFrame.TRUTH,
    progress: bool = True,
    record: pathlib.Path | None = None,
) -> RunResult:
    """Run `config`'s engine (built by `make_engine`) to the end of its input, or to
    `keyframes` keyframes (the Monte-Carlo worlds: one pass of their trajectory by default),
    and write its outputs to `out` (made if missing). `dense`: image inputs also fuse the
    keyframes' depth into `mesh.ply` (needs open3d). `trajectory_frame`: what the written
    trajectories are poses of (the dataset's ground truth's frame, or the camera). `progress`: a tqdm bar on stderr (drawn on
    a terminal only) and the engine's messages written under it. `record`: also write every
    snapshot, with the window's plane-mode comparison, to this recording file
    (backend.pipeline.recording; the engine should be interactive, so that snapshots carry
    the keyframe image and the Hessian), with the outputs: both or neither.

    Raises what `make_engine` raises for a bad input (DatasetError, ValueError, SegmenterError),
    DatasetError for a frame found bad during the run, :class:`RunError` when the input gives
    no keyframe and :class:`OutputError` when `out` cannot be written; `out` then holds what
    it held before. Ctrl-C (KeyboardInterrupt) likewise leaves `out` as it was."""
    from backend.pipeline.factory import make_engine
    from backend.pipeline.sim_engine import SimEngine

    if keyframes is not None and keyframes < 1:
        raise ValueError(f"keyframes {keyframes}: must be at least 1")
    start = time.perf_counter()
    if record is not None:
        check_record_path(record)
    _load_export_libraries()
    engine = make_engine(config)
    recorder = _Recorder(engine, record) if record is not None else None
    if isinstance(engine, SimEngine):
        metrics, summary, write = _simulate(engine, config, out, keyframes=keyframes, choice=trajectory_frame, progress=progress, recorder=recorder)
    else:
        metrics, summary, write = _track(engine, config, out, keyframes=keyframes, dense=dense, choice=trajectory_frame, progress=progress, recorder=recorder)
    if recorder is not None:
        write = recorder.then_write(write)
        summary += f"; recorded {recorder.writer.keyframes} keyframes to {record}"
    _write_staged(out, write)
    return RunResult(metrics=json_safe(metrics), summary=summary, wall_s=time.perf_counter() - start)


_Writer = Callable[[pathlib.Path], None]


def _load_export_libraries() -> None:
    """Import what the export needs (open3d) before the run, not during its export, with an
    interruption held until the import has finished (backend.common.optional): a Ctrl-C
    there read as a missing library, and the run wrote map.ply only and exited 0. Where
    open3d is missing the export says so and writes map.ply (`_write_outputs`)."""
    from backend.common.optional import MissingLibraryError, require_open3d

    try:
        require_open3d()
    except MissingLibraryError:
        pass


def check_record_path(path: pathlib.Path) -> None:
    """RecordPathError unless a recording can be written at `path` (its folder exists and is
    writable; not a folder itself)."""
    import os

    folder = path.parent if str(path.parent) else pathlib.Path(".")
    if path.is_dir():
        raise RecordPathError(f"{path}: is a folder (a recording is one file)")
    if not folder.is_dir():
        raise RecordPathError(f"{path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise RecordPathError(f"{path}: cannot write in {folder}")


class _Recorder:
    """A run's recording: each snapshot with its window's plane-mode comparison, written to
    `path` just before the outputs are moved into place."""

    def __init__(self, engine: Any, path: pathlib.Path) -> None:
        from backend.pipeline.recording import RecordingWriter

        self.engine = engine
        self.path = path
        self.writer = RecordingWriter(source=engine.source)

    def add(self, snapshot: Snapshot) -> None:
        self.writer.add(snapshot)
        self.writer.add_comparison(snapshot.keyframe, dict(self.engine.compare_hessians(snapshot.variant.family())))

    def then_write(self, write: _Writer) -> _Writer:
        def both(folder: pathlib.Path) -> None:
            write(folder)
            self.writer.write(self.path)

        return both


def prepare_out(out: pathlib.Path) -> None:
    """Make `out` (and its parents) and check that files can be written there; OutputError
    otherwise."""
    from backend.common.atomic import make_folder

    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: exists and is not a folder")
        make_folder(out)
        probe = out / ".coplanar-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise OutputError(f"{out}: cannot write there: {e.strerror or e}") from None


def json_safe(value: Any) -> Any:
    """`value` with every non-finite float replaced by None (JSON has no NaN) and tuples as
    lists, as json.loads would give it back."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_staged(out: pathlib.Path, write: _Writer) -> None:
    """`write(folder)` into a staging folder inside `out`, moved into `out` when it returns;
    a failed write (a full disk) is one line naming the file (OutputError), and nothing is
    moved."""
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
        raise OutputError(f"{out}: cannot write {detail}; nothing was written there") from None


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


def _write_outputs(out: pathlib.Path, snapshot: Snapshot, metrics: dict[str, Any], *, frame: OutputFrame, frames: Trajectory, keyframes: Trajectory, groundtruth: Trajectory) -> None:
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
    (out / "metrics.json").write_text(json.dumps(json_safe(metrics), indent=2, allow_nan=False) + "\n")
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


def _cm(value: float | None, *, why: str = "no ground truth") -> str:
    return f"{value:.2f} cm" if value is not None and math.isfinite(value) else f"n/a ({why})"


def _scale_warnings(written: Evaluated, *, stereo: bool) -> list[str]:
    """A warning when the ground truth is not in metres (backend/data/plausibility.py)."""
    from backend.data.plausibility import ground_truth_scale_warning

    found = ground_truth_scale_warning(written.poses.t_world_camera, written.truth.t_world_camera, stereo=stereo)
    return [found] if found else []


def _no_error_because(source: Any, evaluated: int) -> str:
    """Why a run has no trajectory error: the input has no ground truth, it covers none of
    the frames, or too few of them were tracked."""
    import numpy as np

    valid = np.asarray(getattr(source, "ground_truth_valid", np.zeros(0, bool)))
    samples = getattr(source, "ground_truth_samples", None)
    has_file = samples is not None and samples()[0].shape[0] > 0
    if valid.any():
        return f"{evaluated} tracked frames with ground truth, fewer than 3"
    return "the ground truth covers none of the frames: see the warning" if has_file else "no ground truth"


def _simulate(
    engine: SimEngine, config: EngineConfig, out: pathlib.Path, *, keyframes: int | None, choice: TrajectoryFrame, progress: bool, recorder: _Recorder | None
) -> tuple[dict[str, Any], str, _Writer]:
    """A Monte-Carlo world's run: `keyframes` steps (default one pass of its trajectory)."""
    import numpy as np
    from tqdm import tqdm

    from backend.eval import sequences
    from backend.export.output_frame import output_frame

    n = keyframes if keyframes is not None else len(sequences.make_world(engine.settings.sequence, seed=config.seed).t_world_camera)
    prepare_out(out)
    timings: dict[str, list[float]] = {}
    snapshot = None
    with tqdm(total=n, desc=f"run {engine.source}", unit="kf", file=sys.stderr, disable=None if progress else True) as bar:
        for _ in range(n):
            snapshot = engine.step()
            for stage, ms in snapshot.report.timing_ms.items():
                timings.setdefault(stage, []).append(ms)
            if recorder is not None:
                recorder.add(snapshot)
            bar.update(1)
    assert snapshot is not None
    mean = {k: float(np.mean(v)) for k, v in timings.items()}
    # No images, no frames between keyframes: the trajectory is the keyframes'.
    gt = snapshot.ground_truth if snapshot.ground_truth is not None else _no_ground_truth(snapshot.estimate)
    frame = output_frame(None, choice=choice)
    written = evaluate(frame, None, snapshot.estimate, gt)
    variant = str(config.variant)
    metrics = {
        "source": engine.source,
        "variant": variant,
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
        "warnings": [],
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
    summary = (
        f"{n} keyframes, {variant}: ATE {_cm(metrics['ate_rmse_cm'])} (SE3-aligned), RMSE {_cm(metrics['rmse_cm'])}, "
        f"{len(snapshot.planes)} planes; {mean['total']:.1f} ms per keyframe; "
        f"wrote {out}/trajectory.txt (keyframes), keyframes.txt, groundtruth.txt, metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply"
    )
    final = snapshot
    return metrics, summary, lambda folder: _write_outputs(folder, final, metrics, frame=frame, frames=written.poses, keyframes=written.poses, groundtruth=written.groundtruth)


def _excitation_onset(source: Any) -> float | None:
    """Seconds from the input's first frame to its excitation onset
    (`backend.eval.excitation`), from its ground truth at the frames (None: none)."""
    import numpy as np

    from backend.eval.excitation import excitation_onset_s

    valid = np.asarray(source.ground_truth_valid, bool)
    if not valid.any():
        return None
    p_world = np.where(valid[:, None], np.asarray(source.T_world_rect0)[:, :3, 3], np.nan)
    return excitation_onset_s(np.asarray(source.timestamps_ns), p_world)


def _track(
    engine: Any, config: EngineConfig, out: pathlib.Path, *, keyframes: int | None, dense: bool, choice: TrajectoryFrame, progress: bool, recorder: _Recorder | None
) -> tuple[dict[str, Any], str, _Writer]:
    """An image input's run (stereo or VIO): every frame up to `keyframes` keyframes."""
    from tqdm import tqdm

    from backend.eval.planes import RenderedPlanes, plane_recovery
    from backend.eval.run_metrics import stereo_timing, vio_metrics
    from backend.export.output_frame import output_frame
    from backend.pipeline.engine import EndOfSequence

    prepare_out(out)
    variant = str(config.variant)
    total_frames = len(engine.data_source)
    steps: list[tuple[int, dict[str, float]]] = []
    messages: list[str] = []
    lost = reinitializations = 0
    reasons: dict[str, int] = {}
    snapshot = None
    bar = tqdm(total=total_frames, desc=f"run {variant}", unit="frame", file=sys.stderr, disable=None if progress else True, dynamic_ncols=True)
    engine.on_frame = lambda _index: bar.update(1)
    try:
        while keyframes is None or len(steps) < keyframes:
            try:
                snapshot = engine.step()
            except EndOfSequence:
                break
            tracking = snapshot.tracking
            steps.append((tracking.frames, dict(snapshot.report.timing_ms)))
            if recorder is not None:
                recorder.add(snapshot)
            lost += tracking.lost_frames
            reinitializations += tracking.reinitializations
            reasons[tracking.keyframe_reason] = reasons.get(tracking.keyframe_reason, 0) + 1
            if snapshot.message:
                messages.append(f"keyframe {snapshot.keyframe}: {snapshot.message}")
                if progress:
                    bar.write(f"keyframe {snapshot.keyframe}: {snapshot.message}", file=sys.stderr)
    except BaseException:
        bar.leave = False  # an error line (or the interruption) follows: no half-drawn bar above it
        raise
    finally:
        bar.close()
        engine.on_frame = None
    if snapshot is None:
        raise RunError(f"{engine.source}: no keyframe in {engine.frames} frames")
    frames = engine.frame_trajectory()
    source = engine.data_source
    frame = output_frame(source, choice=choice)
    written = evaluate(frame, source, frames.estimate, frames.ground_truth)
    keyframe_truth = snapshot.ground_truth if snapshot.ground_truth is not None else _no_ground_truth(snapshot.estimate)
    kf = evaluate(frame, source, snapshot.estimate, keyframe_truth)
    metrics: dict[str, Any] = {
        "source": engine.source,
        "variant": variant,
        "trajectory_poses": "tracked frames",
        **_frame_metrics(frame),
        "frames": engine.frames,
        "frames_tracked": len(frames),
        "keyframes": len(snapshot.estimate),
        **written.accuracy,
        "keyframe_ate_rmse_cm": kf.accuracy["ate_rmse_cm"],
        "keyframe_rmse_cm": kf.accuracy["rmse_cm"],
        "planes": len(snapshot.planes),
        "points": len(snapshot.points),
        "lines": len(snapshot.lines),
        "lost_frames": lost,
        "reinitializations": reinitializations,
        "keyframe_reasons": reasons,
        "timing_ms": stereo_timing(steps),
        "messages": messages,
        "warnings": list(getattr(source, "warnings", ())) + _scale_warnings(written, stereo=snapshot.imu is None),
    }
    if isinstance(source, RenderedPlanes):
        metrics["plane_recovery"] = {"note": PLANE_RECOVERY_NOTE, **plane_recovery(source, snapshot.estimate.timestamp_ns, snapshot.planes)}
    if snapshot.imu is not None:
        metrics["mode"] = "vio"
        metrics["vio"] = vio_metrics(snapshot, dataclasses.replace(frames, estimate=written.poses, ground_truth=written.truth), excitation_onset_s=_excitation_onset(source))
    final = snapshot

    def write(folder: pathlib.Path) -> None:
        if dense:
            metrics["dense"] = dense_mesh(source, final, folder / "mesh.ply")
        _write_outputs(folder, final, metrics, frame=frame, frames=written.poses, keyframes=kf.poses, groundtruth=written.groundtruth)

    per_frame = metrics["timing_ms"]["total_per_frame"]
    why = _no_error_because(source, int(metrics["frames_evaluated"] or 0))
    summary = (
        f"{engine.frames} frames, {metrics['keyframes']} keyframes, {variant}: ATE {_cm(metrics['ate_rmse_cm'], why=why)} (SE3-aligned, "
        f"{metrics['frames_evaluated']} frames), RMSE {_cm(metrics['rmse_cm'], why=why)}, {len(snapshot.planes)} planes, {lost} lost frames, "
        f"{reinitializations} re-initializations; {per_frame:.1f} ms per frame; "
        f"wrote {out}/trajectory.txt, keyframes.txt, groundtruth.txt (poses of {frame.name}), metrics.json, map.ply, points.ply, lines.ply, planes.ply, cameras.ply"
    )
    return metrics, summary, write


def dense_mesh(source: Any, snapshot: Snapshot, path: pathlib.Path) -> dict[str, Any]:
    """`dense`: every keyframe's depth fused at its final estimated pose into a TSDF
    (backend.eval.dense), the mesh written to `path`; its size, the fusion time per keyframe
    (ms) and, on rendered scenes, the distance of its vertices to the true planes (cm)."""
    import numpy as np

    from backend.common.atomic import atomic_path
    from backend.common.native_output import native_stderr_silenced
    from backend.data.source import RenderedTruth
    from backend.eval.dense import distance_to_planes, fuse_keyframes, keyframe_frames, map_bounds

    frames = keyframe_frames(source, snapshot.estimate.timestamp_ns)
    t = np.asarray(snapshot.estimate.t_world_camera)
    fusion = fuse_keyframes(source, frames, np.asarray(snapshot.estimate.R_world_camera), t, map_bounds(snapshot.points.p_world, t))
    mesh = fusion.mesh()
    o3d = fusion._o3d
    with atomic_path(path) as tmp, native_stderr_silenced():
        if not o3d.io.write_triangle_mesh(str(tmp), mesh):
            raise OSError(f"{path}: open3d could not write the mesh (disk full?)")
    out: dict[str, Any] = {
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
