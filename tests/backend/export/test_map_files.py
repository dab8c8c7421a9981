"""The map as separate files each tool reads as what it is (open3d here), with the
snapshot's counts; the zip the debugger offers; a missing system library is one line."""

from __future__ import annotations

import builtins
import io
import pathlib
import zipfile

import numpy as np
import pytest
from plyfile import PlyData

from backend.common.optional import MissingLibraryError, require_open3d
from backend.export.map_files import MAP_FILES, map_files_zip, write_map_files

o3d = pytest.importorskip("open3d")


@pytest.fixture(scope="module")
def snapshot():
    """Eight keyframes of the Monte-Carlo sequence a: points, lines and planes."""
    from backend.pipeline.sim_engine import SimEngine, SimSettings

    engine = SimEngine(SimSettings(sequence="a"))
    for _ in range(8):
        s = engine.step()
    assert len(s.points) and len(s.lines) and len(s.planes)
    return s


def test_each_file_opens_as_its_type_with_the_snapshots_counts(snapshot, tmp_path: pathlib.Path) -> None:
    paths = write_map_files(snapshot, tmp_path)
    assert [p.name for p in paths] == list(MAP_FILES)
    cloud = o3d.io.read_point_cloud(str(tmp_path / "points.ply"))
    assert len(cloud.points) == len(snapshot.points) and cloud.has_colors()
    np.testing.assert_allclose(np.asarray(cloud.points), snapshot.points.p_world, atol=1e-5)
    tensor = o3d.t.io.read_point_cloud(str(tmp_path / "points.ply"))
    np.testing.assert_array_equal(tensor.point["plane_id"].numpy().ravel(), snapshot.points.plane)
    lines = o3d.io.read_line_set(str(tmp_path / "lines.ply"))
    assert len(lines.lines) == len(snapshot.lines) and len(lines.points) == 2 * len(snapshot.lines)
    np.testing.assert_allclose(np.asarray(lines.points).reshape(-1, 2, 3), snapshot.lines.segment_world, atol=1e-9)
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "planes.ply"))
    hulls = [p for p in snapshot.planes if len(p.hull_world) >= 3]
    assert len(mesh.triangles) == sum(len(p.hull_world) - 2 for p in hulls) and mesh.has_vertex_colors()
    face = PlyData.read(str(tmp_path / "planes.ply"))["face"]
    assert sorted(set(face["plane_id"].tolist())) == sorted(p.id for p in hulls)
    cameras = o3d.io.read_line_set(str(tmp_path / "cameras.ply"))
    assert len(cameras.lines) == 8 * len(snapshot.estimate) and len(cameras.points) == 5 * len(snapshot.estimate)
    np.testing.assert_allclose(np.asarray(cameras.points)[::5], snapshot.estimate.t_world_camera, atol=1e-9)  # frustum apexes at the centres
    # The combined file stays what the debugger's PLY download writes.
    assert PlyData.read(str(tmp_path / "map.ply"))["vertex"].count == len(snapshot.points) + 2 * len(snapshot.lines) + sum(len(p.hull_world) for p in hulls)


def test_the_zip_holds_the_five_files(snapshot) -> None:
    with zipfile.ZipFile(io.BytesIO(map_files_zip(snapshot))) as archive:
        assert sorted(archive.namelist()) == sorted(MAP_FILES)


def test_missing_libusb_is_one_line_that_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    real_import = builtins.__import__

    def no_open3d(name, *args, **kwargs):
        if name == "open3d":
            raise OSError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(__import__("sys").modules, "open3d")
    monkeypatch.setattr(builtins, "__import__", no_open3d)
    with pytest.raises(MissingLibraryError) as info:
        require_open3d()
    message = str(info.value)
    assert "\n" not in message and "libusb-1.0-0" in message and "apt-get install" in message


def test_a_map_without_lines_writes_an_empty_line_set(snapshot, tmp_path: pathlib.Path) -> None:
    """P variants map no lines: lines.ply is there, empty, and open3d reads it as a line set."""
    import dataclasses

    from backend.pipeline.snapshot import LineLandmarks

    empty = np.zeros(0, np.int64)
    no_lines = dataclasses.replace(snapshot, lines=LineLandmarks(empty, np.zeros((0, 2, 3)), empty, empty, np.zeros(0, np.uint8)))
    write_map_files(no_lines, tmp_path)
    assert len(o3d.io.read_line_set(str(tmp_path / "lines.ply")).lines) == 0
    assert len(o3d.io.read_point_cloud(str(tmp_path / "points.ply")).points) == len(snapshot.points)


def test_run_without_open3d_keeps_its_results_and_dense_says_why(monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path, capsys) -> None:
    """Without libusb (open3d cannot be imported) `run` still writes its results and the
    combined map, with a one-line warning; `--dense` refuses at once, one line, exit 2."""
    from app import cli
    from backend.common import optional
    from backend.export import map_files

    def missing():
        raise MissingLibraryError("open3d cannot be imported: the system library libusb-1.0 is missing (Debian: apt-get install libusb-1.0-0)")

    monkeypatch.setattr(map_files, "require_open3d", missing)
    monkeypatch.setattr(optional, "require_open3d", missing)
    out = tmp_path / "out"
    assert cli.main(["run", "--scene", "mc-b", "--variant", "PL-w", "--keyframes", "3", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: open3d cannot be imported" in err and "Traceback" not in err
    assert (out / "map.ply").is_file() and (out / "metrics.json").is_file() and not (out / "points.ply").exists()
    assert cli.main(["run", "--scene", "room", "--variant", "PL-w", "--dense", "--out", str(tmp_path / "dense")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: open3d cannot be imported") and "libusb-1.0-0" in lines[0]
