"""Poses: gtsam conversion and the decoupled retraction."""

from __future__ import annotations

import numpy as np

from backend.geometry import so3
from backend.geometry.se3 import Poses, from_gtsam, to_gtsam


def test_gtsam_round_trip_keeps_camera_to_world_poses() -> None:
    rng = np.random.default_rng(4)
    poses = Poses(so3.exp(rng.standard_normal((4, 3))), rng.standard_normal((4, 3)))
    back = from_gtsam(to_gtsam(poses))
    np.testing.assert_allclose(back.R_world_camera, poses.R_world_camera, atol=1e-12)
    np.testing.assert_allclose(back.t_world_camera, poses.t_world_camera, atol=1e-12)
    # gtsam maps camera points to the world the same way: X_w = R X_c + t.
    p_c = np.array([0.3, -0.2, 2.0])
    np.testing.assert_allclose(to_gtsam(poses)[0].transformFrom(p_c), poses.R_world_camera[0] @ p_c + poses.t_world_camera[0], atol=1e-12)


def test_retract_rotates_on_the_right_and_translates_in_the_world() -> None:
    poses = Poses(so3.exp(np.array([[0.1, 0.2, 0.3]])), np.array([[1.0, 2.0, 3.0]]))
    delta = np.array([[0.01, -0.02, 0.03, 0.5, 0.0, -0.5]])
    moved = poses.retract(delta)
    np.testing.assert_allclose(moved.R_world_camera[0], poses.R_world_camera[0] @ so3.exp(delta[0, :3]), atol=1e-15)
    np.testing.assert_allclose(moved.t_world_camera[0], [1.5, 2.0, 2.5])
