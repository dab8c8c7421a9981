"""The debugger's text panels and the TUM export."""

from __future__ import annotations

import numpy as np

from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import Tracking
from viewer import images, panels


def test_report_times_are_a_table_and_counts_read_as_words() -> None:
    snap = SimEngine(SimSettings(window=4, max_iterations=2)).step()
    text = panels.report_markdown(snap)
    assert "| stage | ms |" in text
    assert all(f"| {panels.STAGE_LABELS.get(k, k)} | {v:.1f} |" in text for k, v in snap.report.timing_ms.items())
    one = Tracking(frames=1, lost_frames=0, reinitializations=1, tracked_points=1, tracked_lines=2)
    line = images.tracking_markdown(one)
    assert "1 frame ·" in line and "1 re-initialization" in line and "1 point ·" in line and "2 lines" in line
    assert "1 frames" not in line


def test_tum_export_round_trips_the_keyframe_poses() -> None:
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    for _ in range(5):
        snap = engine.step()
    rows = np.loadtxt(panels.tum_bytes(snap.estimate).decode().splitlines())
    assert rows.shape == (5, 8)
    np.testing.assert_allclose(rows[:, 1:4], snap.estimate.t_world_camera, atol=1e-8)
    np.testing.assert_allclose(rows[:, 0], snap.estimate.timestamp_ns * 1e-9, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-8)


class _Client:
    """What exports.export sends a tab: the downloads, by name."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}

    def send_file_download(self, name: str, data: bytes, *, save_immediately: bool) -> None:
        self.files[name] = data

    def add_notification(self, *args: object, **kwargs: object) -> None:
        pass


def test_trajectory_downloads_are_poses_of_the_ground_truths_frame() -> None:
    """The debugger's TUM downloads are in the frame `coplanar run` writes by default (the
    dataset's ground-truth frame, here a body 10 cm behind the camera), which their header says."""
    from backend.export.output_frame import TrajectoryFrame, output_frame
    from viewer import exports

    class _Source:
        ground_truth_frame = "body"
        T_truth_rect0 = np.eye(4)

    _Source.T_truth_rect0[:3, 3] = [0.1, 0.0, 0.0]
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    for _ in range(3):
        snap = engine.step()
    client = _Client()
    frame = output_frame(_Source(), choice=TrajectoryFrame.TRUTH)  # type: ignore[arg-type]
    exports.export(client, "keyframes", snap, frame_trajectory=None, is_newest=True, frame=frame)  # type: ignore[arg-type]
    (text,) = (data.decode() for data in client.files.values())
    assert "T_world_body" in text.split("# t x y z")[0]
    rows = np.loadtxt(text.splitlines())
    R, t = np.asarray(snap.estimate.R_world_camera), np.asarray(snap.estimate.t_world_camera)
    np.testing.assert_allclose(rows[:, 1:4], t - R @ np.array([0.1, 0.0, 0.0]), atol=1e-8)  # T_world_rect0 · T_body_rect0⁻¹


def _vio(*, initialized: bool, sigma: float = 0.02, excitation: float = 0.6, rotation: float = 90.0, truth: float | None = None, refinements: list | None = None):
    import dataclasses

    from backend.pipeline.snapshot import ImuState

    report = {"span_s": 4.75, "quality": {"scale_rel_std": sigma, "accel_excitation_mps2": excitation, "rotation_span_deg": rotation}}
    if truth is not None:
        report["joint_scale_error_pct"] = truth
    if refinements is not None:
        report["refinements"] = refinements
    imu = ImuState(
        initialized=initialized,
        status="structure from motion: 6 keyframes over 1.1 s" if not initialized else "initialized",
        init_keyframe=24 if initialized else -1,
        report=report if initialized else {},
        velocity_world=np.zeros((1, 3)),
        bias=np.zeros((1, 6)),
        gravity_world=np.array([0.0, 0.0, -9.81]),
    )
    return dataclasses.replace(SimEngine(SimSettings(window=4, max_iterations=2)).step(), imu=imu)


def test_the_vio_start_says_how_well_its_scale_is_known_and_why_it_is_poor() -> None:
    assert panels.vio_start_note(SimEngine(SimSettings(window=4, max_iterations=2)).step()) == ""
    assert panels.vio_start_note(_vio(initialized=False)) == "VIO not initialized yet: structure from motion: 6 keyframes over 1.1 s"
    good = panels.vio_start_note(_vio(initialized=True, sigma=0.02, truth=-2.2))
    assert good == "VIO initialized at keyframe 24 (4.8 s of motion), the alignment's scale known to ±2 % (1σ); after the joint solve -2.2 % against the truth"
    poor = panels.vio_start_note(_vio(initialized=True, sigma=0.14, excitation=0.12, rotation=8.0))
    assert poor.startswith(
        "**uncertain VIO start**: initialized at keyframe 24 (4.8 s of motion), the alignment's scale known to ±14 % (1σ), "
        "because the start had little acceleration (0.12 m/s²) and little rotation (8°). "
    )
    assert "the start's motion barely constrains it" in panels.vio_start_note(_vio(initialized=True, sigma=0.14))
    assert "`--speed 2`" in poor and "Reset" in poor


def test_the_vio_start_note_and_panel_follow_the_scale_refinement() -> None:
    """After the start's scale is refined the note gives the refinement's keyframe, factor, σ and
    error, and warns only while that σ is large; the IMU panel lists each refinement."""
    refined = {"keyframe": 60, "after_start_s": 15.1, "scale": 0.985, "scale_rel_std": 0.04, "scale_error_pct": -0.5}
    snap = _vio(initialized=True, sigma=0.25, excitation=0.12, rotation=8.0, refinements=[refined])
    assert panels.vio_start_note(snap) == (
        "VIO initialized at keyframe 24 (4.8 s of motion); its scale refined at keyframe 60 (15.1 s after the start) ×0.985, known to ±4 % (1σ), -0.5 % against the truth"
    )
    assert "refined at keyframe 60 (15.1 s after) ×0.985, -0.50 % against the truth" in panels.imu_markdown(snap)
    assert "rejected" not in panels.imu_markdown(snap)
    # Alignments the refinement rejected (tried again `refine_retry_s` later) are counted, with the last reason.
    snap.imu.report.update(refinement_rejections=3, refinement_last_rejection="visual and inertial motion disagree: chi2/dof 5.63 > 1")
    assert "3 refinement alignment(s) rejected, the last: visual and inertial motion disagree: chi2/dof 5.63 > 1" in panels.imu_markdown(snap)
    early = panels.vio_start_note(_vio(initialized=True, sigma=0.25, refinements=[{**refined, "scale_rel_std": 0.09}]))
    assert early.startswith("**uncertain VIO scale**: ") and "±9 %" in early
    assert "(15 s after the start)" in panels.vio_start_note(_vio(initialized=True, sigma=0.25))
