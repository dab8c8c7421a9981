"""The Export buttons: the shown snapshot's map and poses, downloaded by the clicking tab."""

from __future__ import annotations

from collections.abc import Callable

import viser

from backend.export.output_frame import OutputFrame
from backend.export.ply import snapshot_ply_bytes
from backend.pipeline.recording import RecordingWriter
from backend.pipeline.snapshot import FrameTrajectory, Snapshot, Trajectory
from viewer import panels


def export(
    client: viser.ClientHandle | None,
    what: str,
    snapshot: Snapshot | None,
    *,
    frame_trajectory: Callable[[], FrameTrajectory] | None,
    is_newest: bool,
    frame: OutputFrame,
) -> None:
    """Send `what` of `snapshot` to `client`: "map" (one PLY), "files" (a zip of the map
    files 3D tools read), "keyframes" (TUM) or "trajectory" (every tracked frame, TUM;
    the keyframes where the engine tracks no frames or the shown keyframe is not the
    newest, with a note saying so). The TUM files are poses of `frame` (as `coplanar run`
    writes them by default: the frame of the dataset's ground truth), which their header says."""
    if client is None:
        return
    if snapshot is None:
        client.add_notification("Nothing to export", "No keyframe is shown yet: press Step first.", auto_close_seconds=5.0, color="yellow")
        return
    stem = f"coplanar_kf{snapshot.keyframe:05d}_{snapshot.variant}"
    if what == "map":
        client.send_file_download(f"coplanar_map_kf{snapshot.keyframe:05d}_{snapshot.variant}.ply", snapshot_ply_bytes(snapshot), save_immediately=True)
    elif what == "files":
        from backend.common.optional import MissingLibraryError
        from backend.export.map_files import map_files_zip

        try:
            data = map_files_zip(snapshot)
        except MissingLibraryError as e:
            client.add_notification("Export needs open3d", str(e), auto_close_seconds=10.0, color="red")
            return
        client.send_file_download(f"coplanar_map_kf{snapshot.keyframe:05d}_{snapshot.variant}.zip", data, save_immediately=True)
    elif what == "keyframes":
        client.send_file_download(f"{stem}_keyframes.txt", _tum(frame, snapshot.estimate), save_immediately=True)
    elif frame_trajectory is None or not is_newest:
        # Per-frame poses exist for the engine's current state only (the newest keyframe).
        client.send_file_download(f"{stem}_keyframes.txt", _tum(frame, snapshot.estimate), save_immediately=True)
        client.add_notification(
            "Keyframe poses exported", "Every-frame poses exist only for the newest keyframe and engines that track frames; the keyframe poses were written.", auto_close_seconds=6.0
        )
    else:
        client.send_file_download(f"{stem}_trajectory.txt", _tum(frame, frame_trajectory().estimate), save_immediately=True)


def send_recording(client: viser.ClientHandle | None, recorder: RecordingWriter | None) -> None:
    """Send the recording so far to `client` (`coplanar serve --replay FILE` opens it), or
    say why there is none."""
    if client is None:
        return
    if recorder is None or not recorder.keyframes:
        client.add_notification("Nothing recorded", "Tick Record (in the Record folder), then Step or Play; the recording starts with the keyframes kept.", auto_close_seconds=6.0, color="yellow")
        return
    name = "".join(c if c.isalnum() or c in "-_" else "_" for c in recorder.source.split(" ")[0])[:40] or "run"
    client.send_file_download(f"coplanar_{name}_{recorder.keyframes}kf.recording.zip", recorder.to_bytes(), save_immediately=True)


def _tum(frame: OutputFrame, estimate: Trajectory) -> bytes:
    """`estimate` (`T_world_rect0`) as TUM text of poses of `frame`, its header saying so."""
    return panels.tum_bytes(frame.poses(estimate), comment=f"coplanar serve export: {frame.note}")
