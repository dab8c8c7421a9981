"""Render one stereo frame of every built-in scene and save left image | depth | plane mask
as docs/scenes/<scene>.png (the gallery of docs/usage.md): the frame 4 s (`street`: 1 s, on
its first straight; `exposure`: 12 s, at a gain of 0.55) into the scene's sequence of seed 0, as `coplanar run --scene NAME` sees
it (the scene's rig, motion and exposure).

    .venv/bin/python scripts/scene_gallery.py [--scenes street,shake]
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np
from PIL import Image

from backend.data.scenes import SCENE_NAMES, builtin_scene
from backend.data.synthetic import SequenceSettings, SyntheticSequence

OUT = pathlib.Path(__file__).resolve().parents[1] / "docs" / "scenes"
TIME_S = 4.0
TIME_S_OF = {"street": 1.0, "exposure": 12.0}  # before its first turn; at a gain of 0.55


def _depth_image(depth: np.ndarray, *, far_m: float) -> np.ndarray:
    """Near bright, far dark (0.3 m to `far_m`, log scale); nothing hit is black."""
    finite = np.isfinite(depth)
    x = np.zeros(depth.shape)
    x[finite] = 1.0 - np.clip(np.log(depth[finite] / 0.3) / np.log(far_m / 0.3), 0.0, 1.0)
    return np.stack([(255 * x).astype(np.uint8)] * 3, axis=-1)


def _plane_image(plane: np.ndarray) -> np.ndarray:
    """A distinct colour per plane id, black for none."""
    rng = np.random.default_rng(5)
    palette = rng.integers(60, 256, (int(plane.max()) + 2, 3)).astype(np.uint8)
    palette[0] = 0
    return palette[plane.astype(int) + 1]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default=",".join(SCENE_NAMES), help=f"comma-separated built-in scenes (default: all: {', '.join(SCENE_NAMES)})")
    args = parser.parse_args(argv)
    names = [n for n in args.scenes.split(",") if n]
    unknown = [n for n in names if n not in SCENE_NAMES]
    if unknown:
        parser.error(f"--scenes: unknown {', '.join(unknown)} (built-in: {', '.join(SCENE_NAMES)})")
    OUT.mkdir(parents=True, exist_ok=True)
    for name in names:
        scene = builtin_scene(name)
        seq = SyntheticSequence(scene, settings=SequenceSettings(duration_s=TIME_S_OF.get(name, TIME_S)), cache_frames=1)
        view = seq.views(len(seq) - 1)[0]
        far_m = 80.0 if scene.motion.road is not None else 8.0  # a street's depths reach further than a room's
        left = np.stack([view.image] * 3, axis=-1)
        row = np.concatenate([left, _depth_image(view.depth, far_m=far_m), _plane_image(view.plane_id)], axis=1)
        Image.fromarray(row).save(OUT / f"{name}.png", optimize=True)
        print(OUT / f"{name}.png")


if __name__ == "__main__":
    main()
