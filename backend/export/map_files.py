"""The map as separate files that the usual 3D tools read as what they are (open3d,
CloudCompare, MeshLab), beside the combined `map.ply` (:mod:`backend.export.ply`):

- `points.ply`: the map points as a point cloud, coloured by plane, with a per-point
  `plane_id` (-1: none); written by open3d (tensor point cloud, custom attribute);
- `lines.ply`: the line segments as a line set (two vertices and one edge each), coloured
  by plane; written by open3d;
- `planes.ply`: the plane patches as a triangle mesh (each convex hull fanned into
  triangles), one colour per plane, with a per-face `plane_id`; written with plyfile,
  because open3d's PLY writer drops custom face properties (open3d reads the file as a mesh);
- `cameras.ply`: the keyframe cameras as a line set of frustums (centre and the four image
  corners at `FRUSTUM_DEPTH_M`), estimated poses; written by open3d.

World frame, metres, z up. open3d is imported only here (and by the dense check): a missing
system library (Debian's `libusb-1.0-0`) is a one-line :class:`MissingLibraryError`.
"""

from __future__ import annotations

import io
import pathlib
import tempfile
import zipfile

import numpy as np
from plyfile import PlyData, PlyElement

from backend.common.atomic import atomic_path, write_bytes_atomic
from backend.common.native_output import native_stderr_silenced
from backend.common.optional import require_open3d
from backend.common.palette import plane_color
from backend.export.ply import snapshot_ply_bytes
from backend.pipeline.snapshot import Snapshot

FRUSTUM_DEPTH_M = 0.15
MAP_FILES = ("map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")


def point_cloud(snapshot: Snapshot):
    """The map points: an open3d tensor point cloud with colours and `plane_id`."""
    o3d = require_open3d()
    pts = snapshot.points
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.array(pts.p_world, dtype=np.float32).reshape(-1, 3)))
    cloud.point.colors = o3d.core.Tensor(plane_color(pts.plane).reshape(-1, 3).astype(np.uint8))
    cloud.point["plane_id"] = o3d.core.Tensor(np.array(pts.plane, dtype=np.int32).reshape(-1, 1))
    return cloud


def line_set(snapshot: Snapshot):
    """The line segments: an open3d line set, two vertices per segment, coloured by plane."""
    o3d = require_open3d()
    seg = np.array(snapshot.lines.segment_world, dtype=float).reshape(-1, 2, 3)  # a writable copy (snapshots are read-only)
    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(seg.reshape(-1, 3)), o3d.utility.Vector2iVector(np.arange(2 * len(seg)).reshape(-1, 2)))
    ls.colors = o3d.utility.Vector3dVector(plane_color(snapshot.lines.plane).reshape(-1, 3) / 255.0)
    return ls


def camera_frustums(snapshot: Snapshot):
    """The keyframe cameras (estimate): an open3d line set, 5 vertices and 8 edges each."""
    o3d = require_open3d()
    cam = snapshot.camera
    corners_px = np.array([[0.0, 0.0], [cam.width - 1.0, 0.0], [cam.width - 1.0, cam.height - 1.0], [0.0, cam.height - 1.0]])
    corners = cam.normalize(corners_px) * FRUSTUM_DEPTH_M  # camera frame, (4, 3)
    local = np.concatenate([np.zeros((1, 3)), corners])  # centre first
    R = np.asarray(snapshot.estimate.R_world_camera)
    t = np.asarray(snapshot.estimate.t_world_camera)
    vertices = (np.einsum("nij,kj->nki", R, local) + t[:, None, :]).reshape(-1, 3)
    edges = np.array([[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4], [4, 1]])
    lines = (edges[None] + 5 * np.arange(len(R))[:, None, None]).reshape(-1, 2)
    ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector2iVector(lines))
    ls.colors = o3d.utility.Vector3dVector(np.tile([[0.1, 0.1, 0.1]], (len(lines), 1)))
    return ls


def planes_ply_bytes(snapshot: Snapshot) -> bytes:
    """The plane patches as a binary PLY triangle mesh: vertices with the plane's colour,
    faces (a fan over each convex hull) with `plane_id`."""
    hulls = [(p.id, np.asarray(p.hull_world, float)) for p in snapshot.planes if len(p.hull_world) >= 3]
    xyz = np.concatenate([h for _, h in hulls]).reshape(-1, 3) if hulls else np.zeros((0, 3))
    rgb = np.concatenate([np.repeat(plane_color(q)[None], len(h), axis=0) for q, h in hulls]).reshape(-1, 3) if hulls else np.zeros((0, 3), np.uint8)
    tri, ids = [], []
    offset = 0
    for q, h in hulls:
        k = np.arange(1, len(h) - 1)
        tri.append(offset + np.stack([np.zeros_like(k), k, k + 1], axis=1))
        ids.append(np.full(len(k), q))
        offset += len(h)
    faces = np.concatenate(tri) if tri else np.zeros((0, 3), np.int64)
    vertex = np.empty(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    vertex["red"], vertex["green"], vertex["blue"] = rgb.T
    face = np.empty(len(faces), dtype=[("vertex_indices", "O"), ("plane_id", "i4")])
    for i, f in enumerate(faces):
        face["vertex_indices"][i] = f.astype(np.int32)
    face["plane_id"] = np.concatenate(ids) if ids else np.zeros(0, np.int32)
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face", val_types={"vertex_indices": "i4"}, len_types={"vertex_indices": "u1"})]
    buffer = io.BytesIO()
    PlyData(elements, text=False, byte_order="<", comments=["coplanar plane patches: world frame, metres, z up"]).write(buffer)
    return buffer.getvalue()


def write_map_files(snapshot: Snapshot, directory: pathlib.Path | str) -> list[pathlib.Path]:
    """Write the combined map and the four typed files (:data:`MAP_FILES`) into `directory`
    (each complete or not at all); returns their paths."""
    o3d = require_open3d()
    out = pathlib.Path(directory)
    paths = [out / name for name in MAP_FILES]
    write_bytes_atomic(paths[0], snapshot_ply_bytes(snapshot))
    if len(snapshot.points) == 0:  # open3d refuses to write empty geometry: the same elements, no rows
        write_bytes_atomic(paths[1], _empty_ply(("vertex", [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("plane_id", "i4")])))
    else:
        with atomic_path(paths[1]) as tmp, native_stderr_silenced():
            if not o3d.t.io.write_point_cloud(str(tmp), point_cloud(snapshot)):
                raise OSError(f"{paths[1]}: open3d could not write the point cloud (disk full?)")
    for path, count, geometry in ((paths[2], len(snapshot.lines), line_set), (paths[4], len(snapshot.estimate), camera_frustums)):
        if count == 0:
            write_bytes_atomic(path, _empty_ply(("vertex", [("x", "f8"), ("y", "f8"), ("z", "f8")]), ("edge", [("vertex1", "i4"), ("vertex2", "i4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])))
        else:
            with atomic_path(path) as tmp, native_stderr_silenced():
                if not o3d.io.write_line_set(str(tmp), geometry(snapshot)):
                    raise OSError(f"{path}: open3d could not write the line set (disk full?)")
    write_bytes_atomic(paths[3], planes_ply_bytes(snapshot))
    return paths


def _empty_ply(*elements: tuple[str, list[tuple[str, str]]]) -> bytes:
    """A binary PLY with the given elements and no rows (what open3d writes, when empty)."""
    buffer = io.BytesIO()
    PlyData([PlyElement.describe(np.empty(0, dtype=fields), name) for name, fields in elements], text=False, byte_order="<").write(buffer)
    return buffer.getvalue()


def map_files_zip(snapshot: Snapshot) -> bytes:
    """The files of :func:`write_map_files` as one zip archive (the debugger's download)."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_map_files(snapshot, tmp)
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
            for path in paths:
                archive.write(path, arcname=path.name)
    return buffer.getvalue()
