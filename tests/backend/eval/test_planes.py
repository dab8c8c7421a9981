"""Matching estimated planes to ground-truth planes."""

from __future__ import annotations

import numpy as np

from backend.eval.planes import recovered_planes


def test_recovered_planes_by_normal_and_offset() -> None:
    n_true = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    d_true = np.array([0.0, -4.0, 2.0])
    tilt = np.radians(5.0)
    n_est = np.array([[0.0, np.sin(tilt), np.cos(tilt)], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    d_est = np.array([0.05, 4.02, 2.5])  # the wall x = 4 with the flipped normal; y = -2 off by 0.5 m
    np.testing.assert_array_equal(recovered_planes(n_est, d_est, n_true, d_true), [True, True, False])
    np.testing.assert_array_equal(recovered_planes(n_est, d_est, n_true, d_true, max_angle_deg=3.0), [False, True, False])
    assert not recovered_planes(np.zeros((0, 3)), np.zeros(0), n_true, d_true).any()


def test_recovered_planes_by_patch_does_not_depend_on_the_origin() -> None:
    """A floor seen in a strip 2.2 m from the origin, tilted 2.6° about the strip: 10 cm
    off at the origin, 2 cm over the strip it was mapped from. Moved 2 cm further up it is
    still recovered by its patch; a patch that reaches 15 cm above the floor is not."""
    n_true, d_true = np.array([[0.0, 0.0, 1.0]]), np.array([0.0])
    tilt = np.radians(2.6)
    n_est = np.array([[0.0, -np.sin(tilt), np.cos(tilt)]])
    y0 = -2.2
    d_est = np.array([np.sin(tilt) * y0])  # the plane passes through z = 0 at y = y0
    assert abs(d_est[0]) > 0.099
    strip = np.array([[x, y, 0.0] for x in (-2.0, 1.5) for y in (y0 - 0.35, y0 + 0.35)])
    strip[:, 2] = -(n_est[0, :2] @ strip[:, :2].T + d_est[0]) / n_est[0, 2]  # on the estimated plane
    assert recovered_planes(n_est, d_est - 0.02, n_true, d_true, max_offset_m=0.05, hulls_est_world=[strip + [0, 0, 0.02]]).all()
    assert not recovered_planes(n_est, d_est, n_true, d_true, max_offset_m=0.05).any()
    high = strip.copy()
    high[0, 2] = 0.15
    assert not recovered_planes(n_est, d_est, n_true, d_true, hulls_est_world=[high]).any()
    assert recovered_planes(n_est, d_est, n_true, d_true, hulls_est_world=[np.zeros((0, 3))], max_offset_m=0.2).all()


def test_plane_recovery_counts_the_true_planes_seen_and_those_mapped() -> None:
    """A plane seen in a keyframe and mapped is recovered; a seen plane the map misses is
    missed; a plane under 5 % of every keyframe's image is not counted; frames that are not
    keyframes are not looked at."""
    import dataclasses

    from backend.eval.planes import plane_recovery
    from backend.pipeline.snapshot import PlaneLandmark

    @dataclasses.dataclass
    class Camera:
        width: int = 10
        height: int = 10

    ids = np.full((4, 10, 10), -1, np.int16)
    ids[0, :5] = 1  # the floor z = 0: half of frame 0
    ids[0, 5:, :2] = 2  # the wall x = 2: 20 % of frame 0
    ids[0, 9, 9] = 3  # a plane on 1 % of frame 0 only
    ids[2, :] = 4  # a plane filling frame 2, which is not a keyframe

    class Rendered:
        timestamps_ns = np.array([0, 50, 100, 150], np.int64)
        plane_table = {1: np.array([0, 0, 1, 0.0]), 2: np.array([1, 0, 0, -2.0]), 3: np.array([0, 1, 0, -5.0]), 4: np.array([0, 1, 0, -9.0])}
        camera = Camera()

        def left_plane_ids(self, index: int) -> np.ndarray:
            return ids[index]

    def landmark(n: list[float], d: float, hull: np.ndarray) -> PlaneLandmark:
        return PlaneLandmark(id=0, n=np.array(n, float), d=d, hull_world=hull, n_points=10, n_lines=0, last_consensus=1.0, last_candidates=1)

    floor = landmark([0, 0, -1], 0.03, np.array([[0, 0, -0.03], [1, 0, -0.03], [0, 1, -0.03]]))  # flipped normal, 3 cm low
    far_wall = landmark([1, 0, 0], -2.5, np.array([[2.5, 0, 0], [2.5, 1, 0], [2.5, 0, 1]]))  # 50 cm from the wall
    result = plane_recovery(Rendered(), np.array([0, 150]), [floor, far_wall])
    assert result == {"seen": 2, "recovered": 1, "recovered_by_origin_offset": 1, "recovered_ids": [1], "missed_ids": [2]}
    assert plane_recovery(Rendered(), np.array([0, 150]), [])["recovered"] == 0


def test_left_plane_ids_are_the_left_views() -> None:
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=0.5, seed=3))
    for i in (0, len(seq) - 1):
        np.testing.assert_array_equal(seq.left_plane_ids(i), seq.views(i)[0].plane_id)
