"""A dense check of the map: keyframe depth fused into a TSDF volume (open3d) at the
*estimated* keyframe poses, and the mesh extracted from it. Where the poses are right the
surfaces are thin and flat; drift and bad poses show as doubled or blurred walls at a glance.

Depth per keyframe: the rendered depth of rendered scenes (the ground truth: what is left of
the mesh's error is the poses'), or stereo disparity (OpenCV semi-global matching on the
rectified pair) for EuRoC folders. On rendered scenes the mesh's vertices are measured
against the true planes: the distance of each vertex to the nearest true plane (metres).

It is not on the per-frame path: `run --dense` fuses the keyframes after the run at their
final poses, and the debugger does it in the background for the keyframe shown.
"""

from __future__ import annotations

import dataclasses
import time

import cv2
import numpy as np

from backend.common.optional import require_open3d
from backend.data.source import RenderedTruth
from backend.geometry.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class DenseSettings:
    """TSDF voxel size (m; larger where the region needs more than `max_resolution` voxels
    along its longest side), truncation in voxels, depths beyond `max_depth_m` left out
    (stereo depth grows noisy with distance), and the margin (m) around the region."""

    voxel_m: float = 0.03
    trunc_voxels: float = 3.0
    max_depth_m: float = 4.0
    max_resolution: int = 256
    margin_m: float = 0.5


def keyframe_depth(source, index: int) -> np.ndarray:
    """Depth (H, W) float32 metres along the left camera's z of frame `index` (0: none): the
    renderer's depth where the source has it, else stereo semi-global matching."""
    if isinstance(source, RenderedTruth):
        depth = np.asarray(source.left_depth(index), dtype=np.float32)
        return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
    left, right = source.rectified_pair(index)
    return stereo_depth(left, right, source.camera)


def stereo_depth(left: np.ndarray, right: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """Depth (H, W) float32 metres from a rectified uint8 pair by OpenCV's semi-global block
    matching (0 where no disparity)."""
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=64, blockSize=5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2)  # type: ignore[attr-defined]  # not in OpenCV's stubs
    disparity = sgbm.compute(left, right).astype(np.float32) / 16.0
    with np.errstate(divide="ignore"):
        depth = np.where(disparity > 0.5, camera.fx * camera.baseline / disparity, 0.0)
    return depth.astype(np.float32)


class DenseFusion:
    """A TSDF volume (open3d's uniform volume, no colour) of keyframe depth maps over the
    axis-aligned cube that holds `bounds_world` ((2, 3): lower and upper corner, metres).

    The uniform volume, not open3d's scalable one: with open3d-cpu 0.20.0 on this machine the
    scalable volume and the tensor VoxelBlockGrid extract empty meshes (even for a plane 2 m
    in front of the camera), the uniform one does not. It needs the region up front: the
    map's extent (`map_bounds`)."""

    def __init__(self, camera: PinholeCamera, bounds_world: np.ndarray, *, settings: DenseSettings = DenseSettings()) -> None:
        o3d = require_open3d()
        self._o3d = o3d
        self.settings = settings
        self.camera = camera
        lo, hi = np.asarray(bounds_world, float)
        side = float(np.max(hi - lo))
        self.voxel_m = max(settings.voxel_m, side / settings.max_resolution)
        resolution = max(int(np.ceil(side / self.voxel_m)), 8)
        self.intrinsic = o3d.camera.PinholeCameraIntrinsic(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
        self.volume = o3d.pipelines.integration.UniformTSDFVolume(
            length=resolution * self.voxel_m,
            resolution=resolution,
            sdf_trunc=settings.trunc_voxels * self.voxel_m,
            color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor,
            origin=lo,
        )
        self.keyframes = 0
        self.time_ms = 0.0

    def integrate(self, depth_m: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> None:
        """Fuse one depth map (H, W) metres seen from pose `T_world_camera`."""
        o3d = self._o3d
        t0 = time.perf_counter()
        depth = o3d.geometry.Image(np.ascontiguousarray(depth_m, dtype=np.float32))
        blank = o3d.geometry.Image(np.zeros((depth_m.shape[0], depth_m.shape[1], 3), np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(blank, depth, depth_scale=1.0, depth_trunc=self.settings.max_depth_m, convert_rgb_to_intensity=False)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_world_camera, t_world_camera
        self.volume.integrate(rgbd, self.intrinsic, np.linalg.inv(T))  # open3d takes world -> camera
        self.keyframes += 1
        self.time_ms += 1e3 * (time.perf_counter() - t0)

    def mesh(self):
        """The extracted triangle mesh (open3d, world frame, metres) with vertex normals."""
        mesh = self.volume.extract_triangle_mesh()
        mesh.compute_vertex_normals()
        return mesh


def map_bounds(p_world: np.ndarray, camera_centres_world: np.ndarray, *, margin_m: float = DenseSettings.margin_m) -> np.ndarray:
    """The region to fuse (2, 3): the map points between their 1st and 99th percentiles per
    axis (stray far points left out) and the camera centres, grown by `margin_m`."""
    pts = np.asarray(p_world, float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    cams = np.asarray(camera_centres_world, float).reshape(-1, 3)
    parts = [cams]
    if len(pts) >= 10:
        parts.append(np.percentile(pts, [1, 99], axis=0))
    everything = np.concatenate(parts)
    return np.stack([everything.min(axis=0) - margin_m, everything.max(axis=0) + margin_m])


def fuse_keyframes(
    source, frames: np.ndarray, R_world_camera: np.ndarray, t_world_camera: np.ndarray, bounds_world: np.ndarray, *, settings: DenseSettings = DenseSettings(), depth_cache: dict | None = None
) -> DenseFusion:
    """Fuse the keyframes at source frames `frames` (K,) at the poses (K, 3, 3), (K, 3) over
    `bounds_world` (2, 3) (:func:`map_bounds`)."""
    fusion = DenseFusion(source.camera, bounds_world, settings=settings)
    for i, R, t in zip(np.asarray(frames, int), R_world_camera, t_world_camera):
        if depth_cache is not None and int(i) in depth_cache:
            depth = depth_cache[int(i)]
        else:
            depth = keyframe_depth(source, int(i))
            if depth_cache is not None:
                depth_cache[int(i)] = depth
        fusion.integrate(depth, R, t)
    return fusion


def distance_to_planes(vertices_world: np.ndarray, planes: dict[int, np.ndarray]) -> np.ndarray:
    """Distance (V,) in metres of each vertex to the nearest of the true planes
    (`planes`: id -> (n_x, n_y, n_z, d), `n·X + d = 0`)."""
    if len(planes) == 0:
        return np.full(len(vertices_world), np.inf)
    table = np.array(list(planes.values()), dtype=float).reshape(-1, 4)
    return np.min(np.abs(np.asarray(vertices_world, float) @ table[:, :3].T + table[:, 3]), axis=1)


def keyframe_frames(source, timestamps_ns: np.ndarray) -> np.ndarray:
    """The source frame index of each keyframe timestamp."""
    stamps = np.asarray(source.timestamps_ns, dtype=np.int64)
    return np.searchsorted(stamps, np.asarray(timestamps_ns, dtype=np.int64))
