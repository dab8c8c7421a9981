"""The dense check: rendered depth fused at the keyframe poses gives walls on the true planes;
poses off by a few centimetres show as surfaces off the planes."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("open3d")

from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence
from backend.eval.dense import distance_to_planes, fuse_keyframes, map_bounds, stereo_depth


@pytest.fixture(scope="module")
def room() -> SyntheticSequence:
    return SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=4.0))


def _median_cm(room: SyntheticSequence, shift_m: float) -> float:
    frames = np.arange(0, 81, 8)
    T = room.T_world_rect0[frames]
    t = T[:, :3, 3].copy()
    t[1::2] += shift_m * np.array([1.0, 0.5, 0.0]) / np.linalg.norm([1.0, 0.5, 0.0])  # every other keyframe displaced
    fusion = fuse_keyframes(room, frames, T[:, :3, :3], t, map_bounds(np.zeros((0, 3)), t, margin_m=4.0))
    mesh = fusion.mesh()
    assert len(mesh.triangles) > 1000 and fusion.keyframes == len(frames)
    return float(np.median(100.0 * distance_to_planes(np.asarray(mesh.vertices), room.plane_table)))


def test_true_poses_put_the_mesh_on_the_true_planes_and_bad_poses_do_not(room: SyntheticSequence) -> None:
    exact = _median_cm(room, 0.0)
    off = _median_cm(room, 0.06)
    assert exact < 0.5
    assert off > 4 * exact and off > 1.0


def test_stereo_depth_of_a_rendered_pair(room: SyntheticSequence) -> None:
    left, right = room.rectified_pair(10)
    depth = stereo_depth(left, right, room.camera)
    truth = room.left_depth(10)
    ok = (depth > 0) & np.isfinite(truth) & (truth < 4.0)
    assert ok.mean() > 0.5
    assert np.median(np.abs(depth[ok] - truth[ok]) / truth[ok]) < 0.03
