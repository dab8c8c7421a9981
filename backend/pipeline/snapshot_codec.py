"""Snapshots as JSON and arrays, and back: what a recording stores of each snapshot
(`backend.pipeline.recording`).

A snapshot is a tree of frozen dataclasses (`backend.pipeline.snapshot`). :func:`encode`
turns it into a JSON-able tree in which every NumPy array is replaced by a reference into
a dict of arrays (written as one `.npz`), every byte string (the keyframe's JPEG) by a
reference into a dict of blobs, and every SciPy sparse matrix (the Hessian's pattern, which a
snapshot keeps packed and which is written unpacked, as before it was packed) by its
CSR arrays. Dataclasses are written as `{"type": NAME, "fields": {...}}` and only the types
named in :data:`TYPES` are read back, so a file cannot make the reader build anything else.
Non-finite floats are written as JSON's common extension (`NaN`, `Infinity`), which Python,
pandas and most JSON readers accept.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

import numpy as np
import scipy.sparse as sp

from backend.geometry.camera import PinholeCamera
from backend.optim.hessian_image import HessianGroup
from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
from backend.pipeline import snapshot as s

#: Every dataclass a recording may hold, by the name written for it.
TYPES: dict[str, type] = {
    cls.__name__: cls
    for cls in (
        s.Snapshot,
        s.Trajectory,
        s.PointLandmarks,
        s.LineLandmarks,
        s.PlaneLandmark,
        s.Detection,
        s.OptimizationReport,
        s.Metrics,
        s.KeyframeImage,
        s.Tracking,
        s.ImuState,
        PinholeCamera,
        HessianStructure,
        HessianGroup,
    )
}
#: Every enum a recording may hold.
ENUMS: dict[str, type[enum.Enum]] = {"Variant": Variant}


class CodecError(ValueError):
    """A tree that is not an encoded snapshot (names what is wrong, and where)."""


@dataclasses.dataclass
class Encoded:
    """An encoded object: its JSON-able `tree`, and the arrays and blobs it refers to by name."""

    tree: Any
    arrays: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    blobs: dict[str, bytes] = dataclasses.field(default_factory=dict)


def encode(value: object) -> Encoded:
    """`value` (a snapshot, or any tree of the :data:`TYPES`) encoded (module docstring)."""
    out = Encoded(tree=None)
    out.tree = _encode(value, "", out)
    return out


def _encode(value: object, path: str, out: Encoded) -> Any:
    if isinstance(value, np.ndarray):
        out.arrays[path] = np.ascontiguousarray(value)
        return {"array": path}
    if isinstance(value, bytes):
        out.blobs[path] = value
        return {"bytes": path}
    if sp.issparse(value):
        csr = sp.csr_matrix(value)
        for part in ("data", "indices", "indptr"):
            out.arrays[f"{path}.{part}"] = np.asarray(getattr(csr, part))
        return {"csr": path, "shape": list(csr.shape)}
    if isinstance(value, enum.Enum):  # before str: a Variant is a str too
        return {"enum": type(value).__name__, "value": value.value}
    if isinstance(value, HessianStructure):  # kept packed, written as its pattern's CSR arrays (as before it was packed)
        fields = {"variant": value.variant, "pattern": value.pattern, "groups": value.groups}
        return {"type": "HessianStructure", "fields": {name: _encode(v, _join(path, name), out) for name, v in fields.items()}}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = type(value).__name__
        if TYPES.get(name) is not type(value):
            raise CodecError(f"{path or 'the value'}: {name} cannot be recorded")
        return {"type": name, "fields": {f.name: _encode(getattr(value, f.name), _join(path, f.name), out) for f in dataclasses.fields(value)}}
    if isinstance(value, tuple):
        return {"tuple": [_encode(v, _join(path, str(i)), out) for i, v in enumerate(value)]}
    if isinstance(value, list):
        return [_encode(v, _join(path, str(i)), out) for i, v in enumerate(value)]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise CodecError(f"{path}: a dict with keys other than text")
        return {"dict": {k: _encode(v, _join(path, k), out) for k, v in value.items()}}
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise CodecError(f"{path or 'the value'}: a {type(value).__name__} cannot be recorded")


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def decode(encoded: Encoded) -> Any:
    """The object `encode` encoded; CodecError (naming the part) for anything else. Arrays
    come back read-only, as in a snapshot."""
    return _decode(encoded.tree, encoded, "")


def _decode(node: Any, enc: Encoded, where: str) -> Any:
    if node is None or isinstance(node, bool | int | float | str):
        return node
    if isinstance(node, list):
        return [_decode(v, enc, f"{where}[{i}]") for i, v in enumerate(node)]
    if not isinstance(node, dict):
        raise CodecError(f"{where or 'the root'}: unexpected {type(node).__name__}")
    if "array" in node:
        return _read_only(_array(enc, node["array"]))
    if "bytes" in node:
        if node["bytes"] not in enc.blobs:
            raise CodecError(f"{where}: the data {node['bytes']!r} is missing")
        return enc.blobs[node["bytes"]]
    if "csr" in node:
        key = node["csr"]
        parts = [_array(enc, f"{key}.{p}") for p in ("data", "indices", "indptr")]
        try:
            return sp.csr_matrix(tuple(parts), shape=tuple(int(n) for n in node["shape"]))
        except (ValueError, TypeError, KeyError) as e:
            raise CodecError(f"{where}: a damaged sparse matrix ({e})") from None
    if "enum" in node:
        cls = ENUMS.get(node["enum"])
        if cls is None:
            raise CodecError(f"{where}: unknown kind of value {node['enum']!r}")
        try:
            return cls(node["value"])
        except (ValueError, KeyError):
            raise CodecError(f"{where}: {node.get('value')!r} is not a {node['enum']}") from None
    if "tuple" in node:
        return tuple(_decode(v, enc, f"{where}[{i}]") for i, v in enumerate(node["tuple"]))
    if "dict" in node:
        return {str(k): _decode(v, enc, _join(where, str(k))) for k, v in node["dict"].items()}
    if "type" in node:
        cls = TYPES.get(node["type"])
        if cls is None:
            raise CodecError(f"{where or 'the root'}: unknown type {node['type']!r} (written by a newer coplanar?)")
        fields = node.get("fields")
        if not isinstance(fields, dict):
            raise CodecError(f"{where or 'the root'}: {node['type']} without fields")
        values = {name: _decode(v, enc, _join(where, name)) for name, v in fields.items()}
        try:
            if cls is HessianStructure:
                return HessianStructure.of(**values)
            return cls(**values)
        except (TypeError, ValueError) as e:
            raise CodecError(f"{where or 'the root'}: {node['type']} does not fit ({e})") from None
    raise CodecError(f"{where or 'the root'}: unexpected object with keys {sorted(node)[:4]}")


def _array(enc: Encoded, key: object) -> np.ndarray:
    if not isinstance(key, str) or key not in enc.arrays:
        raise CodecError(f"the array {key!r} is missing")
    return enc.arrays[key]


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def same(a: object, b: object) -> bool:
    """Whether two snapshots (or trees of the :data:`TYPES`) hold the same values: the same
    structure and scalars, equal arrays (NaN equal to NaN, same dtype and shape) and
    equal blobs."""
    ea, eb = encode(a), encode(b)
    if _canonical(ea.tree) != _canonical(eb.tree) or ea.arrays.keys() != eb.arrays.keys() or ea.blobs != eb.blobs:
        return False
    return all(
        ea.arrays[k].dtype == eb.arrays[k].dtype and ea.arrays[k].shape == eb.arrays[k].shape and np.array_equal(ea.arrays[k], eb.arrays[k], equal_nan=ea.arrays[k].dtype.kind in "fc")
        for k in ea.arrays
    )


def _canonical(node: Any) -> Any:
    """`node` with NaN made comparable (NaN != NaN in Python)."""
    if isinstance(node, float) and node != node:
        return "NaN"
    if isinstance(node, list):
        return [_canonical(v) for v in node]
    if isinstance(node, dict):
        return {k: _canonical(v) for k, v in node.items()}
    return node
