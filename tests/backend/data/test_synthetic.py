"""A rendered sequence read back through the EuRoC reader: ground truth, depth and plane
masks agree with each other, the IMU file reproduces the motion, and seeds reproduce it."""

from __future__ import annotations

import pathlib

import gtsam
import numpy as np
import pytest
from PIL import Image

from backend.data.euroc import EurocDataset
from backend.data.motion import ImuNoise
from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, render_sequence

QUIET = ImuNoise(0.0, 0.0, 0.0, 0.0)
NO_BIAS = dict(imu_bias_gyro=(0.0, 0.0, 0.0), imu_bias_accel=(0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    out = tmp_path_factory.mktemp("room") / "seq"
    assert render_sequence(builtin_scene("room"), out, settings=SequenceSettings(duration_s=1.0, imu_noise=QUIET, **NO_BIAS)) == 21
    return out


def test_reads_back(room: pathlib.Path) -> None:
    ds = EurocDataset(room)
    assert len(ds) == 21 and len(ds.imu) == 200
    assert abs(ds.camera.baseline - 0.11) < 1e-9 and (ds.camera.width, ds.camera.height) == (752, 480)
    assert np.all(ds.ground_truth_valid[:-1])
    left, right = ds.rectified_pair(10)
    assert left.shape == (480, 752) and left.std() > 20 and not np.array_equal(left, right)


def test_depth_and_plane_masks_agree_with_the_ground_truth(room: pathlib.Path) -> None:
    """Back-projecting a pixel of plane q by its depth with the true camera pose lands on
    plane q of the table (millimetre depth quantization)."""
    ds = EurocDataset(room)
    table = np.loadtxt(room / "mav0" / "planes.csv", delimiter=",")
    k = 7
    name = f"{ds.timestamps_ns[k]}.png"
    depth = np.asarray(Image.open(room / "mav0" / "depth0" / "data" / name)).astype(float) / 1000.0
    plane = np.asarray(Image.open(room / "mav0" / "planes0" / "data" / name)).astype(int) - 1
    v, u = np.nonzero((plane >= 0) & (depth > 0))
    assert len(u) > 10_000
    pick = np.random.default_rng(0).choice(len(u), 500, replace=False)
    u, v = u[pick], v[pick]
    cam = ds.camera
    p_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones(len(u))], axis=1) * depth[v, u][:, None]
    T = ds.T_world_rect0[k]
    p_world = p_cam @ T[:3, :3].T + T[:3, 3]
    n, d = table[plane[v, u], 1:4], table[plane[v, u], 4]
    assert np.max(np.abs(np.sum(n * p_world, axis=1) + d)) < 0.01
    assert len(np.unique(plane[plane >= 0])) >= 2


def test_written_imu_reproduces_the_ground_truth(room: pathlib.Path) -> None:
    ds = EurocDataset(room)
    gt = ds.ground_truth
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setAccelerometerCovariance(1e-6 * np.eye(3))
    params.setGyroscopeCovariance(1e-6 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))
    pim = gtsam.PreintegratedImuMeasurementsManifold(params, gtsam.imuBias.ConstantBias())
    end_frame = 19  # the last frame lies past the last IMU sample's ground truth
    imu = ds.imu_between(int(ds.timestamps_ns[0]) - 1, int(ds.timestamps_ns[end_frame]) - 1)
    for a, w in zip(imu.accel, imu.gyro):
        pim.integrateMeasurement(a, w, 0.005)
    T0 = ds.T_world_body[0]
    v0 = gt.v_world[0]
    end = pim.predict(gtsam.NavState(gtsam.Rot3(T0[:3, :3]), T0[:3, 3], v0), gtsam.imuBias.ConstantBias())
    T1 = ds.T_world_body[end_frame]
    assert len(imu) == 190
    assert np.linalg.norm(end.position() - T1[:3, 3]) < 1e-4


def test_same_seed_same_sequence(tmp_path: pathlib.Path, room: pathlib.Path) -> None:
    out = tmp_path / "again"
    render_sequence(builtin_scene("room"), out, settings=SequenceSettings(duration_s=0.1, imu_noise=QUIET, **NO_BIAS))
    for k in (0, 2):
        name = sorted((out / "mav0" / "cam0" / "data").iterdir())[k].name
        assert (out / "mav0" / "cam0" / "data" / name).read_bytes() == (room / "mav0" / "cam0" / "data" / name).read_bytes()
    other = tmp_path / "other"
    render_sequence(builtin_scene("room"), other, settings=SequenceSettings(duration_s=0.1, seed=1, imu_noise=QUIET, **NO_BIAS))
    name = sorted((out / "mav0" / "cam0" / "data").iterdir())[2].name
    assert (other / "mav0" / "cam0" / "data" / name).read_bytes() != (out / "mav0" / "cam0" / "data" / name).read_bytes()


def test_on_demand_sequence_matches_the_written_folder(room: pathlib.Path) -> None:
    """The on-demand source (what serve and run use without --dataset) gives what the
    reader reads from the rendered folder, frame for frame, in any order."""
    from backend.data.synthetic import SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=1.0, imu_noise=QUIET, **NO_BIAS), cache_frames=1)
    ds = EurocDataset(room)
    np.testing.assert_array_equal(seq.timestamps_ns, ds.timestamps_ns)
    np.testing.assert_allclose(seq.T_world_rect0[:-1], ds.T_world_rect0[:-1], atol=1e-9)
    np.testing.assert_allclose(seq.imu.accel, ds.imu.accel, atol=1e-9)
    sub = seq.imu_between(int(seq.timestamps_ns[3]), int(seq.timestamps_ns[4]))
    assert len(sub) == 10 and sub.timestamp_ns[0] > seq.timestamps_ns[3]
    for k in (12, 3, 12):  # out of order, past the one-frame cache
        left, right = seq.rectified_pair(k)
        file_left, file_right = ds.rectified_pair(k)
        np.testing.assert_array_equal(left, file_left)
        np.testing.assert_array_equal(right, file_right)
    with pytest.raises(IndexError):
        seq.views(len(seq))


def test_the_frame_cache_keeps_what_the_pipeline_reads_again() -> None:
    """Images and the left plane ids come from the cache as rendered (the oracle segmenter
    asks for a keyframe's plane ids after reading it), frames past the cache render the
    same again, and a cached frame holds no depths (1.4 MB instead of 5 MB at 752×480)."""
    from backend.data.synthetic import SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=1.0), cache_frames=2)
    for k in (5, 6, 7, 5):  # 5 is evicted by 7, then rendered again
        left_view, right_view = seq.views(k)
        left, right = seq.rectified_pair(k)
        np.testing.assert_array_equal(left, left_view.image)
        np.testing.assert_array_equal(right, right_view.image)
        np.testing.assert_array_equal(seq.left_plane_ids(k), left_view.plane_id)
    np.testing.assert_array_equal(seq.left_plane_ids(12), seq.views(12)[0].plane_id)  # not cached: rendered
    cached = list(seq._cache.values())
    assert len(cached) == 2
    assert all(sum(a.nbytes for a in frame if a is not None) <= 1.5 * 2**20 for frame in cached)


def test_plane_ids_are_kept_only_once_asked_for() -> None:
    """A run without the oracle segmenter never asks for plane ids, and its cached frames
    hold the two images only (0.7 MB at 752×480); once asked, frames read from then on keep
    them, and every answer is the rendered view's."""
    from backend.data.synthetic import SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=1.0), cache_frames=4)
    for k in (1, 2):
        seq.rectified_pair(k)
    assert all(frame.left_plane_id is None for frame in seq._cache.values())
    assert sum(a.nbytes for a in seq._cache[1] if a is not None) <= 0.75 * 2**20
    np.testing.assert_array_equal(seq.left_plane_ids(2), seq.views(2)[0].plane_id)  # cached without them: rendered
    seq.rectified_pair(3)
    assert seq._cache[3].left_plane_id is not None
    np.testing.assert_array_equal(seq.left_plane_ids(3), seq.views(3)[0].plane_id)


def test_the_imu_is_simulated_when_first_read_and_the_same_whenever_read() -> None:
    """A stereo run never reads the IMU, so it is not simulated until read; read after
    frames, from two threads at once, or first, it is the same noisy samples and biases
    (the noise comes from the random state the trajectory left, not from when it is read)."""
    import threading

    from backend.data.synthetic import SyntheticSequence

    settings = SequenceSettings(duration_s=2.0, seed=3)
    first = SyntheticSequence(builtin_scene("room"), settings=settings)
    expected = (first.imu.gyro.copy(), first.imu.accel.copy(), first.bias_gyro.copy(), first.imu_true.accel.copy())

    later = SyntheticSequence(builtin_scene("room"), settings=settings)
    later.rectified_pair(4)
    assert later._imu_sim is None  # frames read, IMU not simulated
    read: list[object] = []
    threads = [threading.Thread(target=lambda: read.append(later.imu)) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert read[0] is read[1]  # simulated once
    for got, want in zip((later.imu.gyro, later.imu.accel, later.bias_gyro, later.imu_true.accel), expected, strict=True):
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=2.0, seed=4)).imu.gyro, expected[0])


def test_speed_moves_along_the_same_path_faster() -> None:
    """`speed` F: the pose at time t is the speed-1 pose at time F·t (same path, F times faster),
    and the rate of the cameras (hence the motion between frames) follows."""
    from backend.data.synthetic import SyntheticSequence

    scene = builtin_scene("room")
    slow = SyntheticSequence(scene, settings=SequenceSettings(duration_s=4.0))
    fast = SyntheticSequence(scene, settings=SequenceSettings(duration_s=2.0, speed=2.0))
    t = np.linspace(0.0, 2.0, 9)
    np.testing.assert_allclose(fast.trajectory.position(t), slow.trajectory.position(2.0 * t), atol=1e-12)
    np.testing.assert_allclose(fast.trajectory.rotation(t), slow.trajectory.rotation(2.0 * t), atol=1e-12)
    path = lambda s: np.linalg.norm(np.diff(s.trajectory.position(s.timestamps_ns * 1e-9), axis=0), axis=1).sum()  # noqa: E731
    assert len(fast.timestamps_ns) == 41 and len(slow.timestamps_ns) == 81
    assert path(fast) == pytest.approx(path(slow), rel=1e-3)  # the same path in half the frames
    with pytest.raises(ValueError):
        SequenceSettings(speed=0.0)
