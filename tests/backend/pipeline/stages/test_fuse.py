"""Landmark fusion at a stereo keyframe (`backend.pipeline.stages.fuse`): a map point seen
again where a free stereo keypoint agrees with it in position, depth and descriptor is
re-observed; one that disagrees in any of them, or whose keypoint is taken, is not."""

from __future__ import annotations

import numpy as np

from backend.frontend.points import StereoPoints
from backend.geometry import so3
from backend.geometry.camera import PinholeCamera
from backend.pipeline.stages.fuse import FuseSettings, fuse_points

CAMERA = PinholeCamera(fx=450.0, fy=450.0, cx=376.0, cy=240.0, width=752, height=480, baseline=0.11)
R_WORLD_CAMERA = so3.exp(np.array([0.02, -0.1, 0.03]))
T_WORLD_CAMERA = np.array([0.3, -0.2, 1.0])


def _stereo(p_cam: np.ndarray, descriptors: np.ndarray, *, octave: np.ndarray | None = None) -> StereoPoints:
    """The keyframe's stereo keypoints where the camera-frame points `p_cam` project."""
    uv = CAMERA.project(p_cam)
    u_right = uv[:, 0] - CAMERA.fx * CAMERA.baseline / p_cam[:, 2]
    return StereoPoints(uv_left=uv, descriptors=descriptors, octave=np.zeros(len(uv), np.int64) if octave is None else octave, u_right=u_right, p_cam=p_cam)


def _world(p_cam: np.ndarray) -> np.ndarray:
    return p_cam @ R_WORLD_CAMERA.T + T_WORLD_CAMERA


def _scene(n: int = 40, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """`n` camera-frame points 1-6 m ahead spread over the image (at least 30 px apart) and
    random ORB descriptors."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.linspace(60, 690, 8), np.linspace(60, 420, 5)), axis=-1).reshape(-1, 2)[:n]
    z = rng.uniform(1.0, 6.0, len(grid))
    p_cam = np.stack([(grid[:, 0] - CAMERA.cx) * z / CAMERA.fx, (grid[:, 1] - CAMERA.cy) * z / CAMERA.fy, z], axis=1)
    return p_cam, rng.integers(0, 256, (len(grid), 32), dtype=np.uint8)


def _flip_bits(descriptors: np.ndarray, bits: int) -> np.ndarray:
    out = descriptors.copy()
    bytes_, rest = divmod(bits, 8)
    out[:, :bytes_] ^= 0xFF
    out[:, bytes_] ^= np.uint8((1 << rest) - 1)
    return out


def test_a_point_seen_again_fuses_with_its_keypoint() -> None:
    p_cam, desc = _scene()
    stereo = _stereo(p_cam + 0.002, desc)  # the keyframe sees each point 2 mm off: within a pixel
    fused = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_cam), _flip_bits(desc, 20), stereo, np.ones(len(p_cam), bool))
    np.testing.assert_array_equal(fused, np.arange(len(p_cam)))


def test_a_point_not_fused_where_depth_position_descriptor_or_keypoint_disagree() -> None:
    p_cam, desc = _scene()
    n = len(p_cam)
    stereo = _stereo(p_cam, desc)
    free = np.ones(n, bool)
    free[0] = False  # claimed by a tracked point
    p_map = p_cam.copy()
    p_map[1] *= 2.0  # the same ray, twice as deep: the right image's column disagrees
    p_map[2, :2] += 6.0 / CAMERA.fx * p_map[2, 2]  # 6 px off in the image: outside the radius
    p_map[3] = -p_map[3]  # behind the camera
    d_map = desc.copy()
    d_map[4] = _flip_bits(desc[4:5], 51)[0]  # 51 bits off: above ORB-SLAM's TH_LOW
    fused = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_map), d_map, stereo, free)
    assert list(fused[:5]) == [-1] * 5
    np.testing.assert_array_equal(fused[5:], np.arange(5, n))


def test_the_error_bound_widens_with_the_keypoints_octave() -> None:
    p_cam, desc = _scene()
    p_map = p_cam.copy()
    p_map[:, 0] += 2.5 / CAMERA.fx * p_map[:, 2]  # 2.5 px off in both images: beyond χ² 7.815 at 1 px, within at 1.2² px
    fine = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_map), desc, _stereo(p_cam, desc), np.ones(len(p_cam), bool))
    coarse = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_map), desc, _stereo(p_cam, desc, octave=np.full(len(p_cam), 2)), np.ones(len(p_cam), bool))
    assert np.all(fine == -1)
    np.testing.assert_array_equal(coarse, np.arange(len(p_cam)))


def test_two_points_at_one_keypoint_fuse_the_closer_descriptor_only() -> None:
    p_cam, desc = _scene(n=1)
    stereo = _stereo(p_cam, desc)
    p_map = np.concatenate([p_cam, p_cam + 0.001])
    d_map = np.concatenate([_flip_bits(desc, 30), _flip_bits(desc, 10)])
    fused = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_map), d_map, stereo, np.ones(1, bool))
    assert list(fused) == [-1, 0]


def test_nothing_to_fuse_gives_no_match() -> None:
    p_cam, desc = _scene()
    stereo = _stereo(p_cam, desc)
    assert list(fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, np.zeros((0, 3)), np.zeros((0, 32), np.uint8), stereo, np.ones(len(p_cam), bool))) == []
    none_free = fuse_points(CAMERA, R_WORLD_CAMERA, T_WORLD_CAMERA, _world(p_cam), desc, stereo, np.zeros(len(p_cam), bool))
    assert np.all(none_free == -1)
    assert FuseSettings().max_hamming == 50  # ORB-SLAM's TH_LOW
