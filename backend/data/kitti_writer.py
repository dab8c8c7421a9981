"""Write a rendered EuRoC folder as a KITTI odometry sequence (`coplanar render --format kitti`):

```
OUT/sequences/00/image_0/NNNNNN.png, image_1/NNNNNN.png   the EuRoC reader's rectified pairs (lossless PNG)
OUT/sequences/00/calib.txt                                P0..P3 of the rectified camera, Tr
OUT/sequences/00/times.txt                                seconds, exact to the nanosecond
OUT/poses/00.txt                                          T_world_rect0 per frame, 3x4 row-major
```

What `backend.data.kitti.KittiSequence` reads back is what `backend.data.euroc.EurocDataset`
gives for the same folder: the same rectified images, camera, timestamps and `T_world_rect0`.
The poses are written in the render's world frame (z up), not re-based so that the first
is the identity as KITTI's own are: an engine starts at the first frame's ground-truth pose,
so only then are its trajectories on the two folders identical (and comparable number for
number). A frame without ground truth (the render's last, past the truth's samples) is a
row of twelve `nan`, which the KITTI reader reads as no ground truth.
"""

from __future__ import annotations

import decimal
import pathlib

import numpy as np
from PIL import Image

from backend.data.euroc import EurocDataset
from backend.geometry.camera import PinholeCamera

SEQUENCE = "00"


def convert(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    """Write the EuRoC folder `euroc_folder` as `out/sequences/00` and `out/poses/00.txt`."""
    source = EurocDataset(euroc_folder)
    sequence = out / "sequences" / SEQUENCE
    write_images(source, sequence)
    (sequence / "calib.txt").write_text(calib_text(source.camera))
    (sequence / "times.txt").write_text(times_text(source.timestamps_ns))
    (out / "poses").mkdir(parents=True, exist_ok=True)
    (out / "poses" / f"{SEQUENCE}.txt").write_text(poses_text(source.T_world_rect0))


def write_images(source: EurocDataset, sequence: pathlib.Path) -> None:
    """Each frame's rectified pair as `image_0/NNNNNN.png`, `image_1/NNNNNN.png` (lossless),
    one pair in memory at a time."""
    folders = (sequence / "image_0", sequence / "image_1")
    for folder in folders:
        folder.mkdir(parents=True, exist_ok=True)
    for i in range(len(source)):
        for folder, image in zip(folders, source.rectified_pair(i)):
            Image.fromarray(image).save(folder / f"{i:06d}.png", compress_level=1)


def _row(values: np.ndarray) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(values).ravel())


def calib_text(camera: PinholeCamera) -> str:
    """calib.txt of the rectified stereo `camera`: P0 its projection, P1 the right camera's
    (`P1[0,3] = -fx * baseline`, from which the reader's `-P1[0,3] / P1[0,0]` gives the
    baseline to the last place, exactly for the render's 0.11 m at 458 px; for about one
    value in nine no float P1[0,3] gives it exactly). The render has no colour cameras:
    P2 = P0 and P3 = P1, so that tools expecting four projections find them. Tr (velodyne
    to cam0) is the identity: there is no velodyne. Numbers in full precision (repr)."""
    P0 = np.array([[camera.fx, 0.0, camera.cx, 0.0], [0.0, camera.fy, camera.cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    P1 = P0.copy()
    P1[0, 3] = -camera.fx * camera.baseline
    Tr = np.eye(4)[:3]
    return "".join(f"{key}: {_row(P)}\n" for key, P in (("P0", P0), ("P1", P1), ("P2", P0), ("P3", P1), ("Tr", Tr)))


def times_text(timestamps_ns: np.ndarray) -> str:
    """times.txt: each timestamp (int64 ns) as exact decimal seconds, one per line."""
    return "".join(f"{decimal.Decimal(int(t)).scaleb(-9):f}\n" for t in timestamps_ns)


def poses_text(T_world_rect0: np.ndarray) -> str:
    """poses/NN.txt: each (4, 4) pose's top 3x4, row-major, in full precision (repr); a NaN
    pose (no ground truth) as twelve `nan`."""
    return "".join(f"{_row(T[:3, :])}\n" for T in T_world_rect0)
