"""Recordings: a run's snapshots in one versioned file that `coplanar serve --replay`
opens without the engine or the dataset (`backend.pipeline.replay_engine`).

The file is a zip archive that other tools read with the standard library and NumPy:

- `manifest.json`: `{"format": "coplanar-recording", "version": 1, "source": ..., "created": ISO time,
  "keyframes": [{"keyframe": K, "stepped": VARIANT, "chosen": VARIANT, "variants": [...]}, ...],
  "comparisons": [{"keyframe": K, "features": "P" | "PL", "variants": [...]}, ...]}`:
  per keyframe, the variant it was stepped with, the one shown last there (what the user
  chose), and every variant computed there, in the order computed;
- `keyframes/KKKKKK/VARIANT.json` and `.npz`: one snapshot, its structure (JSON,
  `backend.pipeline.snapshot_codec`) and its arrays (`numpy.load` reads them; keys are the
  fields' dotted paths, e.g. `points.p_world`); `.jpg`: its keyframe image;
- `comparisons/KKKKKK-P.json` and `.npz` (or `-PL`): the keyframe's window, as its step left
  it, linearized under the three plane modes (the Hessian tab's comparison), where one was
  made.

Snapshots are encoded when added (:class:`RecordingWriter`), so a long recording holds
compressed bytes, not live snapshots. Reading (:meth:`Recording.open`) checks the whole
archive first (every entry's checksum, the manifest, every entry it names), so a truncated
or foreign file is one line (:class:`RecordingError`) before anything is shown.
"""

from __future__ import annotations

import dataclasses
import datetime
import io
import json
import os
import pathlib
import threading
import zipfile
import zlib
from typing import Any

import numpy as np

from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
from backend.pipeline.snapshot import Snapshot
from backend.pipeline.snapshot_codec import CodecError, Encoded, decode, encode

FORMAT = "coplanar-recording"
VERSION = 1
MANIFEST = "manifest.json"


class RecordingError(Exception):
    """A file that is not a readable recording: one line naming it and what is wrong."""


@dataclasses.dataclass(frozen=True)
class RecordedKeyframe:
    """What a recording holds of one keyframe: the variant it was stepped with, the one
    shown last there, and every variant computed there (in the order computed)."""

    keyframe: int
    stepped: Variant
    chosen: Variant
    variants: tuple[Variant, ...]


def _features(with_lines: bool) -> str:
    return "PL" if with_lines else "P"


def _snapshot_stem(keyframe: int, variant: Variant) -> str:
    return f"keyframes/{keyframe:06d}/{variant}"


def _comparison_stem(keyframe: int, with_lines: bool) -> str:
    return f"comparisons/{keyframe:06d}-{_features(with_lines)}"


@dataclasses.dataclass
class _Entry:
    """One encoded object: its JSON, its arrays as `.npz` bytes, its blobs (the JPEG)."""

    json: bytes
    npz: bytes
    blobs: dict[str, bytes]

    @property
    def size(self) -> int:
        return len(self.json) + len(self.npz) + sum(len(b) for b in self.blobs.values())


def _pack(value: object) -> _Entry:
    enc = encode(value)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **enc.arrays)  # type: ignore[arg-type]
    return _Entry(json=json.dumps(enc.tree, separators=(",", ":")).encode(), npz=buffer.getvalue(), blobs=dict(enc.blobs))


class RecordingWriter:
    """Collects a run's snapshots (encoded as they are added) and writes them to one file.
    `source`: the input's name, shown by the replay. Safe to write from one thread while
    another adds."""

    def __init__(self, *, source: str) -> None:
        self.source = source
        self._lock = threading.Lock()
        self._snapshots: dict[tuple[int, Variant], _Entry] = {}
        self._keyframes: dict[int, dict[str, Any]] = {}
        self._comparisons: dict[tuple[int, bool], tuple[_Entry, tuple[Variant, ...]]] = {}

    @property
    def keyframes(self) -> int:
        return len(self._keyframes)

    @property
    def size_bytes(self) -> int:
        """The encoded size so far (about the file's size)."""
        with self._lock:
            return self._size_bytes()

    def _size_bytes(self) -> int:
        return sum(e.size for e in self._snapshots.values()) + sum(e.size for e, _ in self._comparisons.values())

    def add(self, snapshot: Snapshot) -> None:
        """A snapshot: a keyframe's first is the one it was stepped with; another variant
        there (or the same again, re-optimized) becomes the one shown last there."""
        k, variant = snapshot.keyframe, snapshot.variant
        packed = _pack(snapshot)
        with self._lock:
            self._add(k, variant, packed)

    def _add(self, k: int, variant: Variant, packed: _Entry) -> None:
        entry = self._keyframes.get(k)
        if entry is None:
            entry = self._keyframes[k] = {"keyframe": k, "stepped": variant, "chosen": variant, "variants": []}
        if variant not in entry["variants"]:
            entry["variants"].append(variant)
        entry["chosen"] = variant
        self._snapshots[(k, variant)] = packed

    def choose(self, keyframe: int, variant: Variant) -> None:
        """The user returned to a variant already recorded at `keyframe`."""
        with self._lock:
            entry = self._keyframes.get(keyframe)
            if entry is not None and variant in entry["variants"]:
                entry["chosen"] = variant

    def add_comparison(self, keyframe: int, structures: dict[Variant, HessianStructure]) -> None:
        """The keyframe's window under each plane mode of one feature set (the Hessian tab's)."""
        if keyframe not in self._keyframes or not structures:
            return
        variants = tuple(structures)
        with_lines = variants[0].with_lines
        if (keyframe, with_lines) in self._comparisons:
            return
        packed = _pack({str(v): h for v, h in structures.items()})
        with self._lock:
            self._comparisons[(keyframe, with_lines)] = (packed, variants)

    def manifest(self) -> dict[str, Any]:
        keyframes = [{"keyframe": e["keyframe"], "stepped": str(e["stepped"]), "chosen": str(e["chosen"]), "variants": [str(v) for v in e["variants"]]} for _, e in sorted(self._keyframes.items())]
        comparisons = [{"keyframe": k, "features": _features(lines), "variants": [str(v) for v in variants]} for (k, lines), (_, variants) in sorted(self._comparisons.items())]
        return {
            "format": FORMAT,
            "version": VERSION,
            "source": self.source,
            "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "keyframes": keyframes,
            "comparisons": comparisons,
        }

    def to_bytes(self) -> bytes:
        """The recording file's bytes."""
        buffer = io.BytesIO()
        self._write(buffer)
        return buffer.getvalue()

    def write(self, path: pathlib.Path) -> None:
        """Write the file at `path`, whole or not at all (a temporary file beside it, renamed
        into place); OSError as the system gives it."""
        path = pathlib.Path(path)
        partial = path.with_name(f".{path.name}.partial")
        try:
            with open(partial, "wb") as f:
                self._write(f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)

    def _write(self, f: Any) -> None:
        with self._lock:
            self._write_locked(f)

    def _write_locked(self, f: Any) -> None:
        if not self._keyframes:
            raise RecordingError("nothing recorded yet: no keyframe")
        with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED) as z:  # npz and JPEG are compressed already
            z.writestr(MANIFEST, json.dumps(self.manifest(), indent=1), compress_type=zipfile.ZIP_DEFLATED)
            for (k, variant), entry in sorted(self._snapshots.items()):
                _write_entry(z, _snapshot_stem(k, variant), entry)
            for (k, lines), (entry, _) in sorted(self._comparisons.items()):
                _write_entry(z, _comparison_stem(k, lines), entry)


def _write_entry(z: zipfile.ZipFile, stem: str, entry: _Entry) -> None:
    z.writestr(f"{stem}.json", entry.json, compress_type=zipfile.ZIP_DEFLATED)
    z.writestr(f"{stem}.npz", entry.npz)
    for name, blob in entry.blobs.items():
        suffix = ".jpg" if name == "image.jpeg" else f".{name}.bin"
        z.writestr(f"{stem}{suffix}", blob)


class Recording:
    """A recording opened for reading (module docstring); snapshots are decoded on request."""

    def __init__(self, path: pathlib.Path, archive: zipfile.ZipFile, manifest: dict[str, Any], keyframes: list[RecordedKeyframe], comparisons: dict[tuple[int, bool], tuple[Variant, ...]]) -> None:
        self.path = path
        self._zip = archive
        self._names = frozenset(archive.namelist())  # listed once: a long recording holds thousands
        self.manifest = manifest
        self.source: str = str(manifest.get("source", "?"))
        self.keyframes = keyframes
        self._comparisons = comparisons

    @staticmethod
    def open(path: pathlib.Path | str) -> Recording:
        """Open and check `path`; RecordingError (one line naming the file) for a file that
        is missing, truncated, damaged, foreign or of a newer format version."""
        path = pathlib.Path(path)
        if not path.is_file():
            raise RecordingError(f"{path}: no such file" if not path.exists() else f"{path}: not a regular file")
        try:
            archive = zipfile.ZipFile(path)
        except zipfile.BadZipFile:
            raise RecordingError(f"{path}: not a coplanar recording (not a zip archive, or a truncated one)") from None
        except OSError as e:
            raise RecordingError(f"{path}: cannot read it: {e.strerror or e}") from None
        try:
            if min((info.header_offset for info in archive.infolist()), default=0) != 0:
                # The `.npz` entries are zip archives stored whole: cut short inside or just
                # after one, the file's last directory is that entry's, which starts past byte 0.
                raise RecordingError(f"{path}: truncated or damaged (its last zip directory is an entry's, not the file's)")
            return Recording._checked(path, archive)
        except BaseException:
            archive.close()
            raise

    @staticmethod
    def _checked(path: pathlib.Path, archive: zipfile.ZipFile) -> Recording:
        names = set(archive.namelist())
        if MANIFEST not in names:
            raise RecordingError(f"{path}: not a coplanar recording (a zip archive without {MANIFEST})")
        try:
            bad = archive.testzip()
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as e:
            raise RecordingError(f"{path}: damaged or truncated ({e})") from None
        if bad is not None:
            raise RecordingError(f"{path}: damaged: the entry {bad} fails its checksum")
        try:
            manifest = json.loads(archive.read(MANIFEST))
        except (ValueError, UnicodeDecodeError) as e:
            raise RecordingError(f"{path}: {MANIFEST} is not JSON ({e})") from None
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            raise RecordingError(f"{path}: not a coplanar recording ({MANIFEST} does not say format {FORMAT!r})")
        version = manifest.get("version")
        if not isinstance(version, int) or version < 1:
            raise RecordingError(f"{path}: {MANIFEST}: version {version!r} is not a format version")
        if version > VERSION:
            raise RecordingError(f"{path}: format version {version}, written by a newer coplanar (this one reads up to {VERSION})")
        try:
            keyframes = [
                RecordedKeyframe(
                    keyframe=int(e["keyframe"]),
                    stepped=Variant.parse(e["stepped"]),
                    chosen=Variant.parse(e["chosen"]),
                    variants=tuple(Variant.parse(v) for v in e["variants"]),
                )
                for e in manifest["keyframes"]
            ]
            comparisons = {(int(c["keyframe"]), c["features"] == "PL"): tuple(Variant.parse(v) for v in c["variants"]) for c in manifest.get("comparisons", [])}
        except (KeyError, TypeError, ValueError) as e:
            raise RecordingError(f"{path}: {MANIFEST}: a damaged keyframe list ({type(e).__name__}: {e})") from None
        if not keyframes:
            raise RecordingError(f"{path}: the recording holds no keyframe")
        order = [k.keyframe for k in keyframes]
        if order != sorted(set(order)):
            raise RecordingError(f"{path}: {MANIFEST}: keyframes out of order or repeated")
        for k in keyframes:
            if k.stepped not in k.variants or k.chosen not in k.variants:
                raise RecordingError(f"{path}: {MANIFEST}: keyframe {k.keyframe} names a variant it does not hold")
            for variant in k.variants:
                for suffix in (".json", ".npz"):
                    if _snapshot_stem(k.keyframe, variant) + suffix not in names:
                        raise RecordingError(f"{path}: {_snapshot_stem(k.keyframe, variant)}{suffix} is missing")
        for key in comparisons:
            if _comparison_stem(*key) + ".json" not in names:
                raise RecordingError(f"{path}: {_comparison_stem(*key)}.json is missing")
        return Recording(path, archive, manifest, keyframes, comparisons)

    def __len__(self) -> int:
        return len(self.keyframes)

    def snapshot(self, keyframe: int, variant: Variant) -> Snapshot:
        """The recorded snapshot; RecordingError if the file's entry cannot be read back."""
        value = self._unpack(_snapshot_stem(keyframe, variant))
        if not isinstance(value, Snapshot):
            raise RecordingError(f"{self.path}: {_snapshot_stem(keyframe, variant)}.json is not a snapshot")
        return value

    def comparison(self, keyframe: int, *, with_lines: bool) -> dict[Variant, HessianStructure]:
        """The keyframe's recorded plane-mode comparison ({} where none was made)."""
        if (keyframe, with_lines) not in self._comparisons:
            return {}
        value = self._unpack(_comparison_stem(keyframe, with_lines))
        if not isinstance(value, dict) or not all(isinstance(h, HessianStructure) for h in value.values()):
            raise RecordingError(f"{self.path}: {_comparison_stem(keyframe, with_lines)}.json is not a comparison")
        return {Variant.parse(k): h for k, h in value.items()}

    def _unpack(self, stem: str) -> Any:
        try:
            tree = json.loads(self._zip.read(f"{stem}.json"))
            with np.load(io.BytesIO(self._zip.read(f"{stem}.npz")), allow_pickle=False) as npz:
                arrays = {name: npz[name] for name in npz.files}
            image = f"{stem}.jpg"
            blobs = {"image.jpeg": self._zip.read(image)} if image in self._names else {}
            return decode(Encoded(tree=tree, arrays=arrays, blobs=blobs))
        except (CodecError, KeyError, ValueError, OSError, zipfile.BadZipFile, zlib.error) as e:
            raise RecordingError(f"{self.path}: {stem}: cannot be read back ({type(e).__name__}: {e})") from None

    def close(self) -> None:
        self._zip.close()
