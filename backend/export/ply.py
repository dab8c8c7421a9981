"""The map of a snapshot as one binary PLY: vertices with colours (points, then segment
endpoints, then plane hull corners), `edge` elements for the line segments and `face`
elements (convex polygons) for the plane patches. World frame, metres.

Written with plyfile, which writes arbitrary elements: open3d's writers put point clouds,
line sets and meshes in separate files and cannot mix edges and faces in one.
"""

from __future__ import annotations

import io
import pathlib

import numpy as np
from plyfile import PlyData, PlyElement

from backend.common.palette import plane_color
from backend.pipeline.snapshot import Snapshot


def snapshot_ply_bytes(snapshot: Snapshot) -> bytes:
    """The snapshot's map as binary little-endian PLY bytes."""
    pts = snapshot.points
    segs = snapshot.lines.segment_world.reshape(-1, 3)
    hulls = [p.hull_world for p in snapshot.planes if len(p.hull_world) >= 3]
    hull_planes = [p.id for p in snapshot.planes if len(p.hull_world) >= 3]
    xyz = np.concatenate([pts.p_world, segs, *hulls]).reshape(-1, 3)
    rgb = np.concatenate(
        [
            plane_color(pts.plane).reshape(-1, 3),
            np.repeat(plane_color(snapshot.lines.plane).reshape(-1, 3), 2, axis=0),
            *[np.repeat(plane_color(q)[None], len(h), axis=0) for q, h in zip(hull_planes, hulls)],
        ]
    ).reshape(-1, 3)
    vertex = np.empty(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    vertex["red"], vertex["green"], vertex["blue"] = rgb.T

    first = len(pts) + np.arange(len(snapshot.lines)) * 2
    edge = np.empty(len(first), dtype=[("vertex1", "i4"), ("vertex2", "i4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    edge["vertex1"], edge["vertex2"] = first, first + 1
    if len(first):
        edge["red"], edge["green"], edge["blue"] = plane_color(snapshot.lines.plane).reshape(-1, 3).T

    face = np.empty(len(hulls), dtype=[("vertex_indices", "O"), ("plane_id", "i4")])
    offset = len(pts) + len(segs)
    for i, (q, h) in enumerate(zip(hull_planes, hulls)):
        face["vertex_indices"][i] = np.arange(offset, offset + len(h), dtype=np.int32)
        face["plane_id"][i] = q
        offset += len(h)

    elements = [
        PlyElement.describe(vertex, "vertex"),
        PlyElement.describe(edge, "edge"),
        PlyElement.describe(face, "face", val_types={"vertex_indices": "i4"}, len_types={"vertex_indices": "u1"}),
    ]
    comments = [_ascii(f"coplanar map: {snapshot.source}"), f"keyframe {snapshot.keyframe}, variant {snapshot.variant}", "world frame, metres, z up"]
    buffer = io.BytesIO()
    PlyData(elements, text=False, byte_order="<", comments=comments).write(buffer)
    return buffer.getvalue()


def write_ply(path: pathlib.Path | str, snapshot: Snapshot) -> None:
    """Write :func:`snapshot_ply_bytes` to `path` (complete or not at all)."""
    from backend.common.atomic import write_bytes_atomic

    write_bytes_atomic(path, snapshot_ply_bytes(snapshot))


def _ascii(text: str) -> str:
    """A PLY header comment: ASCII on one line (the source names a folder or a scene, which
    may hold any character; non-ASCII ones become backslash escapes)."""
    return " ".join(text.encode("ascii", "backslashreplace").decode("ascii").split())
