"""PLY export of a snapshot's map: vertices, edges for lines, faces for plane hulls, colours."""

from __future__ import annotations

import dataclasses
import io
import pathlib

import numpy as np
import pytest
from plyfile import PlyData

from backend.common.palette import NON_PLANAR, plane_color
from backend.export.ply import snapshot_ply_bytes, write_ply
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import PlaneLandmark, Snapshot, frozen


@pytest.fixture(scope="module")
def snapshot() -> Snapshot:
    """Sequence a after 20 keyframes with mislabelled features: points, lines, planes and
    landmarks without a plane. A plane without a hull is added (it must get no face)."""
    engine = SimEngine(SimSettings(sequence="a", mislabel=0.1))
    for _ in range(20):
        snap = engine.step()
    assert len(snap.points) > 0 and len(snap.lines) > 0
    assert sum(len(p.hull_world) >= 3 for p in snap.planes) >= 1
    assert np.any(snap.points.plane < 0) and np.any(snap.points.plane >= 0)
    no_hull = PlaneLandmark(id=len(snap.planes), n=frozen(np.array([0.0, 0.0, 1.0])), d=1.0, hull_world=frozen(np.zeros((2, 3))), n_points=0, n_lines=0, last_consensus=1.0, last_candidates=10)
    return dataclasses.replace(snap, planes=(*snap.planes, no_hull))


@pytest.fixture(scope="module")
def ply(snapshot: Snapshot) -> PlyData:
    return PlyData.read(io.BytesIO(snapshot_ply_bytes(snapshot)))


def _xyz(ply: PlyData) -> np.ndarray:
    v = ply["vertex"].data
    return np.column_stack([v["x"], v["y"], v["z"]]).astype(float)


def _rgb(data: np.ndarray) -> np.ndarray:
    return np.column_stack([data["red"], data["green"], data["blue"]])


def test_binary_little_endian_with_three_elements(snapshot: Snapshot, ply: PlyData) -> None:
    raw = snapshot_ply_bytes(snapshot)
    assert raw.startswith(b"ply\nformat binary_little_endian 1.0\n")
    assert [e.name for e in ply.elements] == ["vertex", "edge", "face"]
    assert any(f"keyframe {snapshot.keyframe}" in c for c in ply.comments)


def test_vertex_count_and_positions(snapshot: Snapshot, ply: PlyData) -> None:
    hulls = [p.hull_world for p in snapshot.planes if len(p.hull_world) >= 3]
    P, L = len(snapshot.points), len(snapshot.lines)
    assert len(ply["vertex"].data) == P + 2 * L + sum(len(h) for h in hulls)
    xyz = _xyz(ply)
    expected = np.concatenate([snapshot.points.p_world, snapshot.lines.segment_world.reshape(-1, 3), *hulls])
    np.testing.assert_allclose(xyz, expected, rtol=1e-6, atol=1e-5)


def test_edges_are_the_line_segments(snapshot: Snapshot, ply: PlyData) -> None:
    edges = ply["edge"].data
    assert len(edges) == len(snapshot.lines)
    xyz = _xyz(ply)
    P = len(snapshot.points)
    for i, e in enumerate(edges):
        assert (int(e["vertex1"]), int(e["vertex2"])) == (P + 2 * i, P + 2 * i + 1)
        np.testing.assert_allclose(xyz[[e["vertex1"], e["vertex2"]]], snapshot.lines.segment_world[i], rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(_rgb(edges), plane_color(snapshot.lines.plane))


def test_faces_are_plane_hulls_on_their_planes(snapshot: Snapshot, ply: PlyData) -> None:
    planes = {p.id: p for p in snapshot.planes if len(p.hull_world) >= 3}
    faces = ply["face"].data
    assert len(faces) == len(planes) == len(snapshot.planes) - 1  # the hull-less plane has no face
    xyz = _xyz(ply)
    first = len(snapshot.points) + 2 * len(snapshot.lines)
    used = []
    for f in faces:
        plane = planes[int(f["plane_id"])]
        idx = np.asarray(f["vertex_indices"])
        assert len(idx) == len(plane.hull_world)
        assert idx.min() >= first
        used.extend(idx.tolist())
        np.testing.assert_allclose(xyz[idx] @ plane.n + plane.d, 0.0, atol=1e-4)
        np.testing.assert_allclose(xyz[idx], plane.hull_world, rtol=1e-6, atol=1e-5)
        assert np.all(_rgb(ply["vertex"].data[idx]) == plane_color(plane.id))
    assert sorted(used) == list(range(first, len(xyz)))  # every hull vertex in exactly one face


def test_vertex_colours(snapshot: Snapshot, ply: PlyData) -> None:
    rgb = _rgb(ply["vertex"].data)
    P, L = len(snapshot.points), len(snapshot.lines)
    planes = snapshot.points.plane
    assert np.all(rgb[:P][planes < 0] == NON_PLANAR)
    assert tuple(NON_PLANAR) == (170, 170, 170)
    for q in np.unique(planes[planes >= 0]):
        assert np.all(rgb[:P][planes == q] == plane_color(q))
        assert not np.array_equal(plane_color(q), NON_PLANAR)
    np.testing.assert_array_equal(rgb[P : P + 2 * L], np.repeat(plane_color(snapshot.lines.plane), 2, axis=0))


def test_plane_colours_are_distinct_and_grey_is_reserved() -> None:
    colours = plane_color(np.arange(10))
    assert len({tuple(c) for c in colours}) == 10
    assert not any(np.array_equal(c, NON_PLANAR) for c in colours)
    np.testing.assert_array_equal(plane_color(np.array([-1, 3, 13])), [NON_PLANAR, colours[3], colours[3]])
    assert plane_color(-1).tolist() == NON_PLANAR.tolist()


def test_empty_map(snapshot: Snapshot) -> None:
    points = dataclasses.replace(snapshot.points, **{k: getattr(snapshot.points, k)[:0] for k in ("id", "p_world", "plane", "anchor", "detection")})
    lines = dataclasses.replace(snapshot.lines, **{k: getattr(snapshot.lines, k)[:0] for k in ("id", "segment_world", "plane", "anchor", "detection")})
    empty = dataclasses.replace(snapshot, points=points, lines=lines, planes=())
    ply = PlyData.read(io.BytesIO(snapshot_ply_bytes(empty)))
    assert [len(ply[name].data) for name in ("vertex", "edge", "face")] == [0, 0, 0]


def test_write_ply_writes_the_same_bytes(snapshot: Snapshot, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "map.ply"
    write_ply(path, snapshot)
    assert path.read_bytes() == snapshot_ply_bytes(snapshot)
    write_ply(str(tmp_path / "again.ply"), snapshot)
    assert (tmp_path / "again.ply").read_bytes() == path.read_bytes()


def test_any_source_name_becomes_an_ascii_comment(snapshot: Snapshot) -> None:
    """The source names a scene or a folder (`2× speed`, a path with accents or a newline):
    the header stays ASCII on one line per comment and the map is written."""
    named = dataclasses.replace(snapshot, source="rendered scene room (2× speed) in /données/é\nnext")
    ply = PlyData.read(io.BytesIO(snapshot_ply_bytes(named)))
    assert ply.comments[0] == "coplanar map: rendered scene room (2\\xd7 speed) in /donn\\xe9es/\\xe9 next"
    assert len(ply["vertex"].data) == len(snapshot.points) + 2 * len(snapshot.lines) + sum(len(p.hull_world) for p in snapshot.planes if len(p.hull_world) >= 3)
