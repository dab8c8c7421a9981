"""Recordings: what a run recorded reads back value for value (maps, images, Hessians, the
VIO's state, the variants chosen), a replay steps through it as it was recorded, and a
truncated, damaged, foreign or newer file is one line naming it."""

from __future__ import annotations

import json
import re
import zipfile

import numpy as np
import pytest

from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.factory import EngineConfig, make_engine
from backend.pipeline.recording import FORMAT, Recording, RecordingError, RecordingWriter
from backend.pipeline.replay_engine import NotRecorded, ReplayEngine
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot_codec import CodecError, Encoded, decode, encode, same


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """mc-a, 6 keyframes stepped with PL-w; at keyframe 3 P-wo re-optimized and shown last,
    at keyframe 4 P-r re-optimized and PL-w shown again; at keyframe 5 the PL comparison.
    Returns the snapshots and the file."""
    engine = SimEngine(SimSettings(sequence="a"))
    writer = RecordingWriter(source=engine.source)
    snapshots = {}
    for _ in range(6):
        s = engine.step()
        writer.add(s)
        snapshots[(s.keyframe, s.variant)] = s
        if s.keyframe == 3:
            engine.set_variant(Variant.P_WO)
            other = engine.reoptimize()
            writer.add(other)
            snapshots[(3, Variant.P_WO)] = other
            engine.set_variant(Variant.PL_W)
        if s.keyframe == 4:
            engine.set_variant(Variant.P_R)
            other = engine.reoptimize()
            writer.add(other)
            snapshots[(4, Variant.P_R)] = other
            engine.set_variant(Variant.PL_W)
            writer.choose(4, Variant.PL_W)
    comparison = engine.compare_hessians(Variant.PL_W.family())
    writer.add_comparison(5, comparison)
    path = tmp_path_factory.mktemp("rec") / "mc-a.recording.zip"
    writer.write(path)
    return snapshots, comparison, path


def test_every_recorded_snapshot_reads_back_the_same(recorded) -> None:
    snapshots, comparison, path = recorded
    recording = Recording.open(path)
    assert recording.source == "Monte-Carlo sequence a (seed 0)" and len(recording) == 6
    for (k, variant), snapshot in snapshots.items():
        back = recording.snapshot(k, variant)
        assert same(back, snapshot), (k, variant)
        assert not back.points.p_world.flags.writeable  # read-only, as a snapshot's arrays
    back = recording.comparison(5, with_lines=True)
    assert list(back) == list(comparison)
    for variant, h in comparison.items():
        assert (back[variant].pattern != h.pattern).nnz == 0 and back[variant].groups == h.groups
    assert recording.comparison(5, with_lines=False) == {} and recording.comparison(2, with_lines=True) == {}


def test_the_file_is_a_zip_of_json_and_npz_other_tools_read(recorded) -> None:
    snapshots, _, path = recorded
    with zipfile.ZipFile(path) as z:
        manifest = json.loads(z.read("manifest.json"))
        assert manifest["format"] == FORMAT and manifest["version"] == 1
        assert manifest["keyframes"][3] == {"keyframe": 3, "stepped": "PL-w", "chosen": "P-wo", "variants": ["PL-w", "P-wo"]}
        with z.open("keyframes/000004/PL-w.npz") as f:
            arrays = np.load(f)
            np.testing.assert_array_equal(arrays["points.p_world"], snapshots[(4, Variant.PL_W)].points.p_world)


def test_a_replay_steps_as_recorded_and_shows_the_variant_chosen(recorded) -> None:
    snapshots, _, path = recorded
    engine = ReplayEngine(Recording.open(path))
    for k in range(4):
        assert same(engine.step(), snapshots[(k, Variant.PL_W)])
    others = engine.recorded_variants()  # keyframe 3: P-wo re-optimized there, shown last
    assert [s.variant for s in others] == [Variant.P_WO] and engine.variant is Variant.P_WO
    engine.set_variant(Variant.PL_W)
    assert same(engine.reoptimize(), snapshots[(3, Variant.PL_W)])
    engine.set_variant(Variant.PL_R)
    with pytest.raises(NotRecorded, match="PL-r was not recorded at keyframe 3 \\(recorded there: PL-w, P-wo\\)"):
        engine.reoptimize()
    engine.step()
    assert [s.variant for s in engine.recorded_variants()] == [Variant.P_R] and engine.variant is Variant.PL_W  # P-r tried, PL-w chosen again
    engine.step()
    assert set(engine.compare_hessians(Variant.PL_W.family())) == set(Variant.PL_W.family())
    with pytest.raises(EndOfSequence, match="end of the recording \\(6 keyframes\\)"):
        engine.step()
    engine.reset()
    assert engine.step().keyframe == 0


def test_image_and_inertial_snapshots_read_back_the_same(tmp_path) -> None:
    """A rendered VIO run: the keyframe image (JPEG), the Hessian, the tracking figures and
    the inertial state (velocities, biases, the initialization's report dict)."""
    engine = make_engine(EngineConfig(scene="room", duration_s=3.0, mode="vio", interactive=True))
    writer = RecordingWriter(source=engine.source)
    kept = []
    for _ in range(4):
        s = engine.step()
        writer.add(s)
        kept.append(s)
    writer.write(tmp_path / "vio.zip")
    recording = Recording.open(tmp_path / "vio.zip")
    for s in kept:
        back = recording.snapshot(s.keyframe, s.variant)
        assert back.image is not None and back.image.jpeg == s.image.jpeg and back.imu is not None
        assert same(back, s)


def _damaged(tmp_path, path, edit) -> str:
    """The one-line error for a copy of `path` changed by `edit(name, bytes) -> bytes | None`."""
    out = tmp_path / "damaged.zip"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = edit(info.filename, src.read(info.filename))
            if data is not None:
                dst.writestr(info.filename, data)
    with pytest.raises(RecordingError) as e:
        Recording.open(out).snapshot(0, Variant.PL_W)
    message = str(e.value)
    assert "\n" not in message and str(out) in message
    return message


def test_truncated_damaged_foreign_and_newer_files_are_one_line(recorded, tmp_path) -> None:
    _, _, path = recorded
    data = path.read_bytes()
    truncated = tmp_path / "truncated.zip"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match=r"\.zip: (not a coplanar recording \(.*)?truncated"):
        Recording.open(truncated)
    # cut anywhere, in particular inside or just after an `.npz` entry (itself a zip archive
    # stored whole: the standard library alone then reads that entry's directory and sees an
    # archive of arrays, not a truncated file)
    inner_ends = [m.start() + 22 for m in re.finditer(b"PK\x05\x06", data)][:-1]  # each end-of-directory record, 22 bytes
    assert len(inner_ends) >= 6
    cuts = sorted({*inner_ends, *(i + 100 for i in inner_ends), *np.linspace(30, len(data) - 1, 40, dtype=int).tolist()})
    cut_short = tmp_path / "cut.zip"  # a name the messages' match cannot find
    for cut in cuts:
        cut_short.write_bytes(data[:cut])
        with pytest.raises(RecordingError, match=r"cut\.zip: (not a coplanar recording \(.*)?(truncated|damaged)"):
            Recording.open(cut_short)
    flipped = bytearray(data)
    flipped[len(data) // 3] ^= 0xFF  # inside a stored entry: its checksum fails
    (tmp_path / "flipped.zip").write_bytes(bytes(flipped))
    with pytest.raises(RecordingError, match="damaged|checksum|truncated"):
        Recording.open(tmp_path / "flipped.zip")
    (tmp_path / "notes.txt").write_text("not a recording")
    with pytest.raises(RecordingError, match="not a coplanar recording"):
        Recording.open(tmp_path / "notes.txt")
    with pytest.raises(RecordingError, match="no such file"):
        Recording.open(tmp_path / "missing.zip")

    def bump(name, raw):
        if name != "manifest.json":
            return raw
        manifest = json.loads(raw)
        manifest["version"] = 2
        return json.dumps(manifest).encode()

    assert "written by a newer coplanar" in _damaged(tmp_path, path, bump)
    assert "without manifest.json" in _damaged(tmp_path, path, lambda name, raw: None if name == "manifest.json" else raw)
    assert "keyframes/000002/PL-w.npz is missing" in _damaged(tmp_path, path, lambda name, raw: None if name == "keyframes/000002/PL-w.npz" else raw)
    foreign_type = _damaged(tmp_path, path, lambda name, raw: raw.replace(b'"Metrics"', b'"os.system"') if name == "keyframes/000000/PL-w.json" else raw)
    assert "cannot be read back" in foreign_type and "unknown type 'os.system'" in foreign_type


def test_the_codec_builds_only_the_recorded_types() -> None:
    with pytest.raises(CodecError, match="unknown type"):
        decode(Encoded(tree={"type": "Popen", "fields": {}}))
    with pytest.raises(CodecError, match="the array 'x' is missing"):
        decode(Encoded(tree={"array": "x"}))
    with pytest.raises(CodecError, match="cannot be recorded"):
        encode(object())


def test_an_empty_recording_is_not_written(tmp_path) -> None:
    with pytest.raises(RecordingError, match="no keyframe"):
        RecordingWriter(source="x").write(tmp_path / "empty.zip")
    assert not list(tmp_path.iterdir())
