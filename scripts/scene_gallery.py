"""Render one stereo frame of every built-in scene and save left image | depth | plane mask
as docs/scenes/<scene>.png (the gallery of docs/usage.md).

    .venv/bin/python scripts/scene_gallery.py
"""

from __future__ import annotations

import pathlib

import numpy as np
from PIL import Image

from backend.data.motion import random_trajectory
from backend.data.render import render_view
from backend.data.scenes import SCENE_NAMES, builtin_scene
from backend.data.synthetic import CAMERA, T_BODY_CAM0

OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "scenes"


def _depth_image(depth: np.ndarray) -> np.ndarray:
    """Near bright, far dark (0.3–8 m, log scale); nothing hit is black."""
    finite = np.isfinite(depth)
    x = np.zeros(depth.shape)
    x[finite] = 1.0 - np.clip(np.log(depth[finite] / 0.3) / np.log(8.0 / 0.3), 0.0, 1.0)
    return np.stack([(255 * x).astype(np.uint8)] * 3, axis=-1)


def _plane_image(plane: np.ndarray) -> np.ndarray:
    """A distinct colour per plane id, black for none."""
    rng = np.random.default_rng(5)
    palette = rng.integers(60, 256, (int(plane.max()) + 2, 3)).astype(np.uint8)
    palette[0] = 0
    return palette[plane.astype(int) + 1]


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name in SCENE_NAMES:
        scene = builtin_scene(name)
        centre, half = scene.camera_region
        trajectory = random_trajectory(np.random.default_rng([0, 0xDA7A]), centre=np.asarray(centre), half_extent=np.asarray(half), height=0.0)
        t = np.array([4.0])
        R_world_body, p_world_body = trajectory.rotation(t)[0], trajectory.position(t)[0]
        view = render_view(scene, CAMERA, R_world_body @ T_BODY_CAM0[:3, :3], p_world_body + R_world_body @ T_BODY_CAM0[:3, 3])
        left = np.stack([view.image] * 3, axis=-1)
        row = np.concatenate([left, _depth_image(view.depth), _plane_image(view.plane_id)], axis=1)
        Image.fromarray(row).save(OUT / f"{name}.png", optimize=True)
        print(OUT / f"{name}.png")


if __name__ == "__main__":
    main()
