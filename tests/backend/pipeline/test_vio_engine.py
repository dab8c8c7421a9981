"""Parts of the VIO engine's start that can be checked without running it."""

from __future__ import annotations

import numpy as np

from backend.data.synthetic import CAMERA
from backend.geometry import so3
from backend.pipeline.stages.two_view import rotation_free_parallax_px


def _views(R_10: np.ndarray, t_10: np.ndarray, depth: tuple[float, float], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of 200 points in front of camera 0 at the given depth range, seen from
    camera 0 and from camera 1 (`X_1 = R_10 X_0 + t_10`), the ones in both images."""
    uv = np.column_stack([rng.uniform(0, CAMERA.width, 200), rng.uniform(0, CAMERA.height, 200)])
    X0 = CAMERA.normalize(uv) * rng.uniform(*depth, 200)[:, None]
    X1 = X0 @ R_10.T + t_10
    uv1 = CAMERA.project(X1)
    keep = (X1[:, 2] > 0) & CAMERA.in_image(uv1)
    return uv[keep], uv1[keep]


def test_a_turn_has_no_rotation_free_parallax_and_a_step_with_depth_has() -> None:
    """A 20° turn moves the pixels by a hundred and more, all of it explained by a rotation;
    a 10 cm sideways step with points between 1 and 4 m leaves parallax; the same step
    in front of a wall at one depth is mostly a rotation in disguise (little left)."""
    rng = np.random.default_rng(0)
    turn = so3.exp(np.radians([3.0, 20.0, 2.0]))
    uv0, uv1 = _views(turn, np.zeros(3), (1.0, 4.0), rng)
    assert np.median(np.linalg.norm(uv1 - uv0, axis=1)) > 100
    assert rotation_free_parallax_px(CAMERA, uv0, uv1) < 0.1
    step = np.array([-0.10, 0.0, 0.0])
    uv0, uv1 = _views(so3.exp(np.radians([0.0, 5.0, 0.0])), step, (1.0, 4.0), rng)
    assert rotation_free_parallax_px(CAMERA, uv0, uv1) > 5.0
    uv0, uv1 = _views(np.eye(3), step, (3.0, 3.05), rng)
    moved = np.median(np.linalg.norm(uv1 - uv0, axis=1))  # about 15 px
    assert rotation_free_parallax_px(CAMERA, uv0, uv1) < 0.2 * moved
    assert rotation_free_parallax_px(CAMERA, uv0[:2], uv1[:2]) == 0.0
