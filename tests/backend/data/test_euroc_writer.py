"""The EuRoC writer and the reader round trip: what `coplanar render` writes reads back
with the same calibration, frames, IMU samples and ground truth."""

from __future__ import annotations

import pathlib

import numpy as np
from PIL import Image

from backend.data.euroc import EurocDataset
from backend.data.euroc_writer import EurocWriter, GroundTruthRows
from backend.data.motion import ImuNoise, imu_samples, random_trajectory
from backend.geometry.camera import PinholeCamera

CAMERA = PinholeCamera(fx=458.0, fy=458.0, cx=30.5, cy=25.0, width=64, height=48, baseline=0.11)
# Camera z along body x, camera x along body -y, camera y along body -z; 5 cm forward.
T_BODY_CAM0 = np.array([[0.0, 0.0, 1.0, 0.05], [-1.0, 0.0, 0.0, 0.055], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def _write(root: pathlib.Path, n_frames: int = 6) -> tuple[np.ndarray, object, object]:
    trajectory = random_trajectory(np.random.default_rng(1))
    stamps = np.arange(n_frames, dtype=np.int64) * 50_000_000
    imu = imu_samples(trajectory, start_ns=0, end_ns=int(stamps[-1]))
    writer = EurocWriter(root, camera=CAMERA, T_body_cam0=T_BODY_CAM0, imu_noise=ImuNoise(), camera_rate_hz=20.0, imu_rate_hz=200.0)
    rng = np.random.default_rng(0)
    for t in stamps:
        left = rng.integers(0, 255, (48, 64), dtype=np.uint8)
        depth = np.full((48, 64), 2.5)
        depth[0, 0] = np.inf
        plane = np.full((48, 64), 3, dtype=np.int16)
        plane[:, :10] = -1
        writer.add_frame(int(t), images=(left, 255 - left), depths=(depth, depth), planes=(plane, plane))
    writer.write_imu(imu.timestamp_ns, imu.gyro, imu.accel)
    gt_t = imu.timestamp_ns
    tt = gt_t * 1e-9
    writer.write_ground_truth(GroundTruthRows(gt_t, trajectory.position(tt), trajectory.rotation(tt), trajectory.velocity(tt), np.zeros((len(tt), 3)), np.zeros((len(tt), 3))))
    writer.write_planes(np.array([[1.0, 0.0, 0.0]] * 4), np.array([-3.0, 1.0, 2.0, 0.5]))
    writer.close()
    return stamps, trajectory, imu


def test_round_trip(tmp_path: pathlib.Path) -> None:
    stamps, trajectory, imu = _write(tmp_path / "seq")
    ds = EurocDataset(tmp_path / "seq")
    np.testing.assert_array_equal(ds.timestamps_ns, stamps)
    cam = ds.camera
    assert (cam.width, cam.height) == (64, 48)
    assert abs(cam.baseline - 0.11) < 1e-9
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [458.0, 458.0, 30.5, 25.0], atol=1e-6)  # square pixels, centred: rectification is the identity
    np.testing.assert_allclose(ds.rectification.T_cam0_rect0, np.eye(4), atol=1e-9)  # already rectified
    # IMU: every sample back, and those between two frames.
    assert len(ds.imu) == len(imu)
    np.testing.assert_allclose(ds.imu.gyro, imu.gyro, atol=1e-9)
    assert len(ds.imu_between(int(stamps[1]), int(stamps[2]))) == 10
    # Ground truth of the cameras at frame times.
    tt = stamps * 1e-9
    T_world_body = np.tile(np.eye(4), (len(tt), 1, 1))
    T_world_body[:, :3, :3] = trajectory.rotation(tt)
    T_world_body[:, :3, 3] = trajectory.position(tt)
    np.testing.assert_allclose(ds.T_world_rect0[:-1], (T_world_body @ T_BODY_CAM0)[:-1], atol=1e-9)
    # Images are stored losslessly.
    left, right = ds.raw_pair(2)
    assert left.dtype == np.uint8 and left.shape == (48, 64)
    np.testing.assert_array_equal(right, 255 - left)


def test_extras_depth_and_planes(tmp_path: pathlib.Path) -> None:
    stamps, _, _ = _write(tmp_path / "seq", n_frames=2)
    mav0 = tmp_path / "seq" / "mav0"
    for i in (0, 1):
        depth = np.asarray(Image.open(mav0 / f"depth{i}" / "data" / f"{stamps[0]}.png"))
        assert depth.dtype == np.uint16 and depth[1, 1] == 2500 and depth[0, 0] == 0
        plane = np.asarray(Image.open(mav0 / f"planes{i}" / "data" / f"{stamps[0]}.png")).astype(int) - 1
        assert plane[0, 0] == -1 and plane[0, 20] == 3
    table = np.loadtxt(mav0 / "planes.csv", delimiter=",")
    assert table.shape == (4, 5)
    np.testing.assert_allclose(table[:, 4], [-3.0, 1.0, 2.0, 0.5])


def test_written_folder_without_imu0_reads_for_stereo(tmp_path: pathlib.Path) -> None:
    """DESIGN §8: a stereo folder without imu0 is valid; IMU data is asked for only by VIO."""
    import shutil

    import pytest

    from backend.data.errors import DatasetError

    stamps, _, _ = _write(tmp_path / "seq")
    with_imu = EurocDataset(tmp_path / "seq")
    shutil.rmtree(tmp_path / "seq" / "mav0" / "imu0")
    ds = EurocDataset(tmp_path / "seq")
    assert ds.has_imu is False and with_imu.has_imu is True
    assert len(ds) == len(with_imu) == len(stamps)
    np.testing.assert_array_equal(ds.timestamps_ns, stamps)
    for i in (0, len(ds) - 1):
        for a, b in zip(ds.raw_pair(i), with_imu.raw_pair(i)):
            np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(ds.T_world_rect0, with_imu.T_world_rect0)
    with pytest.raises(DatasetError) as caught:
        ds.imu_between(int(stamps[1]), int(stamps[2]))
    message = str(caught.value)
    assert message == f"{tmp_path / 'seq' / 'mav0' / 'imu0'}: missing folder: IMU data is needed for VIO (stereo runs without it)"
