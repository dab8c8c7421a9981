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

The run itself is `backend.headless.run.run_headless`, which `coplanar sweep` calls too. The
files are written into a hidden staging folder inside `--out` and moved into place only
when all are written (`backend.common.atomic`): a full disk, an error or Ctrl-C / SIGTERM
during the run leaves `--out` as it was (an earlier run's files there stay whole), and the
command says so.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

DEFAULT_DURATION_S = 30.0


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
    p.add_argument("--keyframes", type=int, default=None, metavar="N", help="stop after N keyframes (default: mc-a / mc-b one pass of the trajectory, stereo inputs all)")
    p.add_argument(
        "--dense",
        action="store_true",
        help="image inputs: fuse the keyframes' depth (rendered, or stereo matching) into a TSDF at the estimated poses after the run; "
        "write mesh.ply and, on rendered scenes, the mesh's distance to the true planes in metrics.json",
    )
    p.add_argument(
        "--trajectory-frame",
        choices=[str(f) for f in TrajectoryFrame],
        default=str(TrajectoryFrame.TRUTH),
        help="what the written trajectories are poses of: truth (default): the frame of the dataset's own ground truth (EuRoC, rendered scenes: the IMU body), "
        "so evo against the dataset's ground-truth file reproduces metrics.json; camera: the rectified left camera, as the engine estimates it",
    )
    p.add_argument(
        "--record",
        default=None,
        metavar="FILE",
        type=path,
        help="also write the run's snapshots (each keyframe's map, image, Hessian and plane-mode comparison) to FILE, "
        "which `coplanar serve --replay FILE` opens without the engine or the dataset; the engine then runs every stage, as the debugger's does",
    )
    p.set_defaults(run=run, history=1)


def run(args: argparse.Namespace) -> int:
    """Check the options, run the engine (backend.headless.run_headless) and print its
    summary line; expected failures are UsageError (one line, exit code 2)."""
    from app.errors import UsageError
    from app.sources import engine_config, segmenter_error
    from backend.common.atomic import InterruptedAfterCommit
    from backend.export.output_frame import TrajectoryFrame
    from backend.frontend.segmenters import SegmenterError
    from backend.headless.run import OutputError, RecordPathError, RunError, run_headless

    if getattr(args, "dense", False):
        from backend.common.optional import require_open3d

        require_open3d()  # before the run: a missing library is one line, not a lost run

    record = getattr(args, "record", None)
    config = engine_config(args, headless=record is None)  # a recording's snapshots carry the image and the Hessian
    if args.keyframes is not None and args.keyframes < 1:
        raise UsageError(f"--keyframes {args.keyframes}: must be at least 1")
    out: pathlib.Path = args.out
    try:
        created = not out.exists()
    except OSError:  # a name the file system refuses: the run says so
        created = False
    try:
        frame = TrajectoryFrame(getattr(args, "trajectory_frame", TrajectoryFrame.TRUTH))
        result = run_headless(config, out, keyframes=args.keyframes, dense=getattr(args, "dense", False), trajectory_frame=frame, record=record)
    except SegmenterError as e:
        raise segmenter_error(e, config) from None
    except RecordPathError as e:
        raise UsageError(f"--record {e}") from None
    except OutputError as e:
        raise UsageError(f"--out {e}") from None
    except RunError as e:
        raise UsageError(str(e)) from None
    except InterruptedAfterCommit:
        raise
    except KeyboardInterrupt:
        earlier = out.is_dir() and any(not p.name.startswith(".") for p in out.iterdir())
        raise KeyboardInterrupt(f"nothing written to {out}" + ("; the files already there are as they were" if earlier else "")) from None
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed run leaves no empty folder it made (its parents stay)
    for warning in result.metrics.get("warnings") or ():
        print(f"warning: {warning}", file=sys.stderr)
    print(result.summary)
    return 0
