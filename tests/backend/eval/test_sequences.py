"""The Monte-Carlo worlds of DESIGN §4: sequence a (four walls) and b (one wall)."""

from __future__ import annotations

import numpy as np
import pytest

from backend.eval import sequences


@pytest.fixture(scope="module")
def world_a() -> sequences.World:
    return sequences.make_world("a", seed=0)


@pytest.fixture(scope="module")
def world_b() -> sequences.World:
    return sequences.make_world("b", seed=0)


def _assert_rotations(R: np.ndarray) -> None:
    np.testing.assert_allclose(np.swapaxes(R, 1, 2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def _on_planes(world: sequences.World) -> None:
    n, d = world.plane_n, world.plane_d
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    res_p = np.sum(n[world.point_plane] * world.points, axis=1) + d[world.point_plane]
    assert np.max(np.abs(res_p)) < 1e-12
    for k in range(2):
        e = world.segments[:, k]
        res_l = np.sum(n[world.segment_plane] * e, axis=1) + d[world.segment_plane]
        assert np.max(np.abs(res_l)) < 1e-12


def _check_segments(world: sequences.World, per_wall: int) -> None:
    s = world.segments
    length = np.linalg.norm(s[:, 1] - s[:, 0], axis=1)
    assert np.all((length >= 0.5) & (length <= 2.0))
    vertical = np.abs(s[:, 1, 2] - s[:, 0, 2]) / length  # |cos| of the angle to world z
    for q in range(len(world.plane_n)):
        sel = world.segment_plane == q
        assert sel.sum() == per_wall
        near_vertical = vertical[sel] > np.cos(np.deg2rad(10.0)) - 1e-12
        near_horizontal = vertical[sel] < np.sin(np.deg2rad(10.0)) + 1e-12
        assert near_vertical.sum() == per_wall // 2
        assert near_horizontal.sum() == per_wall - per_wall // 2


def test_sequence_a_counts(world_a: sequences.World) -> None:
    assert world_a.name == "a"
    assert world_a.R_world_camera.shape == (150, 3, 3)
    assert world_a.t_world_camera.shape == (150, 3)
    assert world_a.points.shape == (200, 3)
    assert world_a.segments.shape == (100, 2, 3)
    assert len(world_a.plane_n) == 4 and len(world_a.plane_d) == 4
    np.testing.assert_array_equal(np.bincount(world_a.point_plane), [50] * 4)
    np.testing.assert_array_equal(np.bincount(world_a.segment_plane), [25] * 4)
    cam = world_a.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (752, 480, 460.0, 460.0, 376.0, 240.0)


def test_sequence_a_walls_are_x_and_y_plus_minus_4(world_a: sequences.World) -> None:
    walls = {(tuple(np.round(n, 12)), float(d)) for n, d in zip(world_a.plane_n, world_a.plane_d)}
    # n·X + d = 0 with |d| = 4 and an axis-aligned normal: x = ±4 and y = ±4.
    xs = sorted(-d * n[0] for n, d in walls if abs(n[0]) == 1)
    ys = sorted(-d * n[1] for n, d in walls if abs(n[1]) == 1)
    assert xs == [-4.0, 4.0] and ys == [-4.0, 4.0]


def test_sequence_a_points_on_their_walls_within_extent(world_a: sequences.World) -> None:
    _on_planes(world_a)
    p = world_a.points
    n = world_a.plane_n[world_a.point_plane]
    horizontal = np.where(np.abs(n[:, 0]) == 1, p[:, 1], p[:, 0])  # along the wall
    assert np.all(np.abs(horizontal) <= 3.0)
    assert np.all(np.abs(p[:, 2]) <= 1.5)
    # Every wall gets points spread over its extent (not all in one spot).
    for q in range(4):
        sel = world_a.point_plane == q
        assert np.ptp(horizontal[sel]) > 3.0 and np.ptp(p[sel, 2]) > 1.5


def test_sequence_a_segments(world_a: sequences.World) -> None:
    _check_segments(world_a, 25)


@pytest.mark.parametrize("n", [0, 1, 7, 37, 75, 149])
def test_sequence_a_poses_follow_the_design_formula(world_a: sequences.World, n: int) -> None:
    theta = 2 * np.pi * n / 150
    np.testing.assert_allclose(world_a.t_world_camera[n], [1.5 * np.cos(theta), 1.5 * np.sin(theta), 0.3 * np.sin(10 * theta)], atol=1e-12)
    R = world_a.R_world_camera[n]
    _assert_rotations(R[None])
    # Optical axis horizontal, radially outward; image y = world -z (down).
    np.testing.assert_allclose(R[:, 2], [np.cos(theta), np.sin(theta), 0.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 1], [0.0, 0.0, -1.0], atol=1e-12)


def test_sequence_a_all_poses(world_a: sequences.World) -> None:
    _assert_rotations(world_a.R_world_camera)
    t = world_a.t_world_camera
    np.testing.assert_allclose(np.hypot(t[:, 0], t[:, 1]), 1.5, atol=1e-12)
    forward = world_a.R_world_camera[:, :, 2]
    np.testing.assert_allclose(forward[:, 2], 0.0, atol=1e-12)
    radial = t[:, :2] / np.linalg.norm(t[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(forward[:, :2], radial, atol=1e-12)


def test_sequence_b_counts_and_wall(world_b: sequences.World) -> None:
    assert world_b.name == "b"
    assert world_b.R_world_camera.shape == (50, 3, 3)
    assert world_b.t_world_camera.shape == (50, 3)
    assert world_b.points.shape == (50, 3)
    assert world_b.segments.shape == (20, 2, 3)
    np.testing.assert_allclose(world_b.plane_n, [[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(world_b.plane_d, [-4.0])
    _on_planes(world_b)
    np.testing.assert_allclose(world_b.points[:, 0], 4.0)
    np.testing.assert_allclose(world_b.segments[..., 0], 4.0)


def test_sequence_b_points_and_segment_centres_within_extent(world_b: sequences.World) -> None:
    p = world_b.points
    assert np.all(np.abs(p[:, 1]) <= 2.0) and np.all(np.abs(p[:, 2]) <= 1.5)
    assert np.ptp(p[:, 1]) > 2.0 and np.ptp(p[:, 2]) > 1.5
    c = world_b.segments.mean(axis=1)
    assert np.all(np.abs(c[:, 1]) <= 2.0) and np.all(np.abs(c[:, 2]) <= 1.5)


def test_sequence_b_segment_endpoints_within_extent(world_b: sequences.World) -> None:
    e = world_b.segments
    assert np.all(np.abs(e[..., 1]) <= 2.0) and np.all(np.abs(e[..., 2]) <= 1.5)


def test_sequence_b_segments(world_b: sequences.World) -> None:
    _check_segments(world_b, 20)


@pytest.mark.parametrize("n", [0, 5, 12, 24, 37, 49])
def test_sequence_b_poses_follow_the_design_formula(world_b: sequences.World, n: int) -> None:
    np.testing.assert_allclose(world_b.t_world_camera[n], [0.0, -1.0 + 2.0 * n / 49.0, 0.3 * np.sin(4 * np.pi * n / 49)], atol=1e-12)
    R = world_b.R_world_camera[n]
    _assert_rotations(R[None])
    yaw = np.deg2rad(10.0) * np.sin(2 * np.pi * n / 49)
    # Looking along +x, turned by the yaw about world z; image y = world -z.
    np.testing.assert_allclose(R[:, 2], [np.cos(yaw), np.sin(yaw), 0.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 1], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(R[:, 0], np.cross(R[:, 1], R[:, 2]), atol=1e-12)


def test_sequence_b_yaw_range(world_b: sequences.World) -> None:
    f = world_b.R_world_camera[:, :, 2]
    yaw = np.rad2deg(np.arctan2(f[:, 1], f[:, 0]))
    assert abs(yaw.max() - 10.0) < 0.1 and abs(yaw.min() + 10.0) < 0.1
    assert yaw[0] == pytest.approx(0.0, abs=1e-12) and yaw[-1] == pytest.approx(0.0, abs=1e-10)


def test_sequence_b_wall_is_seen(world_b: sequences.World) -> None:
    _, ok = sequences.visible(world_b, world_b.points)
    assert ok.shape == (50, 50)
    assert np.all(ok.sum(axis=0) >= 2)  # every point is observed at least twice
    assert np.all(ok.sum(axis=1) >= 10)  # every camera sees a good part of the wall


def test_unknown_sequence_raises() -> None:
    with pytest.raises(ValueError, match="c"):
        sequences.make_world("c")
    with pytest.raises(ValueError):
        sequences.make_world("")


@pytest.mark.parametrize("name", ["a", "b"])
def test_world_is_deterministic_per_seed_and_differs_between_seeds(name: str) -> None:
    w0 = sequences.make_world(name, seed=3)
    w1 = sequences.make_world(name, seed=3)
    w2 = sequences.make_world(name, seed=4)
    np.testing.assert_array_equal(w0.points, w1.points)
    np.testing.assert_array_equal(w0.segments, w1.segments)
    assert not np.allclose(w0.points, w2.points)
    assert not np.allclose(w0.segments, w2.segments)
    # The poses are not random.
    np.testing.assert_array_equal(w0.t_world_camera, w2.t_world_camera)
    np.testing.assert_array_equal(w0.R_world_camera, w2.R_world_camera)


def test_visible_rejects_points_behind_the_camera(world_b: sequences.World) -> None:
    R0, t0 = world_b.R_world_camera[0], world_b.t_world_camera[0]
    ahead = t0 + 3.0 * R0[:, 2]
    behind = t0 - 3.0 * R0[:, 2]  # projects exactly onto the principal point
    behind_offset = t0 - 3.0 * R0[:, 2] + 0.5 * R0[:, 0]
    too_close = t0 + 0.05 * R0[:, 2]
    outside = t0 + 1.0 * R0[:, 2] + 5.0 * R0[:, 0]
    uv, ok = sequences.visible(world_b, np.stack([ahead, behind, behind_offset, too_close, outside]))
    assert uv.shape == (50, 5, 2)
    np.testing.assert_allclose(uv[0, 0], [376.0, 240.0], atol=1e-9)
    assert world_b.camera.in_image(uv[0, 1])  # in the image rectangle, yet behind
    np.testing.assert_array_equal(ok[0], [True, False, False, False, False])


def test_visible_matches_manual_projection(world_a: sequences.World) -> None:
    uv, ok = sequences.visible(world_a, world_a.points)
    n, p = 17, 33
    X_c = world_a.R_world_camera[n].T @ (world_a.points[p] - world_a.t_world_camera[n])
    np.testing.assert_allclose(uv[n, p], world_a.camera.project(X_c), atol=1e-9)
    # Sequence a: a camera looking outward never sees the wall behind it.
    cam_dir = world_a.R_world_camera[:, :, 2]
    wall_n = world_a.plane_n[world_a.point_plane]
    facing_away = cam_dir @ wall_n.T < -0.9  # camera looks at the opposite wall
    assert not np.any(ok & facing_away)
    assert np.all(ok.sum(axis=1) >= 10)
