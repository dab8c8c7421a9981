"""The `street` scene: a KITTI-like camera at 10 Hz on a car that stays on its road at
8–15 m/s and turns; its truth (plane table, depth) is exact and its texture lies mostly
5–80 m away, as real streets'."""

from __future__ import annotations

import numpy as np
import pytest

from backend.data.scenes import Scene, builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence


@pytest.fixture(scope="module")
def street() -> Scene:
    return builtin_scene("street")


@pytest.fixture(scope="module")
def sequence(street: Scene) -> SyntheticSequence:
    return SyntheticSequence(street, settings=SequenceSettings(duration_s=20.0))


def test_kitti_like_camera_at_10_hz(sequence: SyntheticSequence) -> None:
    cam = sequence.camera
    assert (cam.width, cam.height) == (1241, 376)
    assert cam.fx == cam.fy == pytest.approx(718, abs=1) and cam.cx == pytest.approx(607, abs=1) and cam.cy == pytest.approx(185, abs=1)
    assert cam.baseline == pytest.approx(0.54)
    assert np.all(np.diff(sequence.timestamps_ns) == 100_000_000) and len(sequence) == 201
    assert np.all(np.diff(sequence.imu.timestamp_ns) == 5_000_000)
    # the left camera 1.65 m above the road, looking along the driving direction
    T = sequence.T_world_rect0
    np.testing.assert_allclose(T[:, 2, 3], 1.65, atol=0.03)
    v = sequence.trajectory.velocity(sequence.timestamps_ns * 1e-9)
    forward = np.einsum("ni,ni->n", T[:, :3, 2], v / np.linalg.norm(v, axis=1, keepdims=True))
    assert forward.min() > 0.99


def _on(rect, xy: np.ndarray) -> np.ndarray:
    """Whether world points xy (N, 2) on the ground lie on the horizontal rectangle."""
    d = np.column_stack([xy, np.zeros(len(xy))]) - rect.p0
    a, b = d @ rect.u, d @ rect.v
    return (a >= 0) & (a <= rect.size[0]) & (b >= 0) & (b <= rect.size[1])


def _distance_to_segment(xy: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    d = q - p
    s = np.clip(((xy - p) @ d) / max(d @ d, 1e-12), 0.0, 1.0)
    return np.linalg.norm(xy - (p + s[:, None] * d), axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_car_stays_on_the_road_at_8_to_15_m_per_s_and_turns(street: Scene, seed: int) -> None:
    seq = SyntheticSequence(street, settings=SequenceSettings(duration_s=80.0, seed=seed))  # more than a lap
    t = np.arange(0.0, 80.0, 0.1)
    p = seq.trajectory.position(t)
    speed = np.linalg.norm(seq.trajectory.velocity(t), axis=1)
    assert 8.0 <= speed.min() and speed.max() <= 15.0 and speed.max() - speed.min() > 3.0
    # on the street's asphalt (plane 0, the road strips and the junction squares) ...
    road = [r for r in street.rectangles if r.plane_id == 0 and r.texture.kind in ("road", "asphalt")]
    assert np.all(np.any([_on(r, p[:, :2]) for r in road], axis=0))
    # ... clear of every wall, car and tree trunk
    for rect in street.rectangles:
        if abs(rect.normal[2]) < 0.5:  # vertical: its footprint is a segment
            c = rect.corners
            foot = c[np.argsort(c[:, 2])[:2], :2]
            clearance = 1.0 if rect.corners[:, 2].max() < 2.0 else 5.0  # parked cars, buildings
            assert _distance_to_segment(p[:, :2], foot[0], foot[1]).min() > clearance
    for cyl in street.cylinders:
        assert np.linalg.norm(p[:, :2] - cyl.centre_xy, axis=1).min() > 3.0
    # it turns within the first 20 s, and keeps turning left round the block
    yaw = np.unwrap(np.arctan2(seq.T_world_body[:, 1, 0], seq.T_world_body[:, 0, 0]))
    assert yaw[200] - yaw[0] > np.radians(80) and yaw[-1] - yaw[0] > np.radians(270)


def test_truth_planes_and_depth_agree(sequence: SyntheticSequence) -> None:
    """Back-projecting each pixel by its depth lands on the plane the mask names, from the
    plane table; depth is exact and most texture lies 5–80 m away."""
    cam = sequence.camera
    in_range = []
    for k in (0, 45, 90, 150, 200):
        left, right = sequence.views(k)
        assert left.image.std() > 30 and not np.array_equal(left.image, right.image)
        finite = np.isfinite(left.depth)
        in_range.append(np.mean((left.depth >= 5.0) & (left.depth <= 80.0)) / np.mean(finite))
        assert finite.mean() > 0.7  # the sky is the rest
        v, u = np.nonzero(left.plane_id >= 0)
        pick = np.random.default_rng(k).choice(len(u), 2000, replace=False)
        u, v = u[pick], v[pick]
        z = left.depth[v, u].astype(float)
        p_camera = np.column_stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z])
        T = sequence.T_world_rect0[k]
        p_world = p_camera @ T[:3, :3].T + T[:3, 3]
        planes = np.array([sequence.plane_table[int(i)] for i in left.plane_id[v, u]])
        assert np.max(np.abs(np.sum(planes[:, :3] * p_world, axis=1) + planes[:, 3]) / z) < 1e-4
        assert len(np.unique(left.plane_id[left.plane_id >= 0])) >= 5  # the road and several walls
    assert min(in_range) > 0.7 and np.mean(in_range) > 0.85, in_range
