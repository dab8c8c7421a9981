"""Hessian structure of a linearized problem: block groups and the nonzero pattern of
H = JᵀJ, for the viewer's live sparsity image and `coplanar sim --hessian-dir`.

Every snapshot keeps its window's pattern, and the debugger keeps tens of snapshots, so the
pattern is kept packed (:class:`PackedPattern`: its CSR index arrays differenced and
deflated, 14-33 times smaller than the boolean CSR matrix on room) and unpacked, exactly, where
it is drawn."""

from __future__ import annotations

import dataclasses
import pathlib
import zlib

import numpy as np
import scipy.sparse as sp

from backend.optim.hessian_image import HessianGroup, write_hessian_png
from backend.optim.problem import GROUPS, Problem, State


@dataclasses.dataclass(frozen=True)
class PackedPattern:
    """A sparse matrix's nonzero pattern, exactly (the CSR index arrays in their order, int32),
    in `blob`: the row lengths and the column indices, each differenced from the one
    before, deflated. `shape` (rows, columns), `nnz` nonzeros."""

    shape: tuple[int, int]
    nnz: int
    blob: bytes

    @classmethod
    def of(cls, matrix: sp.spmatrix | sp.sparray) -> PackedPattern:
        """The pattern of `matrix` (its stored entries, zeros included: call
        `eliminate_zeros` first for the numeric pattern)."""
        csr = sp.csr_matrix(matrix)
        rows, cols = csr.shape
        if max(rows, cols, csr.nnz) >= 2**31:
            raise ValueError(f"a {rows}x{cols} pattern with {csr.nnz} nonzeros is too large to pack (int32 indices)")
        lengths = np.diff(csr.indptr.astype(np.int64))
        steps = np.diff(csr.indices.astype(np.int64), prepend=0)
        raw = lengths.astype(np.int32).tobytes() + steps.astype(np.int32).tobytes()
        return cls(shape=(int(rows), int(cols)), nnz=int(csr.nnz), blob=zlib.compress(raw, 1))

    def unpack(self) -> sp.csr_matrix:
        """The pattern as a boolean CSR matrix (True at every nonzero)."""
        rows = self.shape[0]
        raw = np.frombuffer(zlib.decompress(self.blob), dtype=np.int32)
        if raw.size != rows + self.nnz:
            raise ValueError(f"a packed pattern of {raw.size} numbers, expected {rows} row lengths and {self.nnz} indices")
        indptr = np.zeros(rows + 1, np.int32)
        np.cumsum(raw[:rows], out=indptr[1:])
        indices = np.cumsum(raw[rows:], dtype=np.int64).astype(np.int32)
        return sp.csr_matrix((np.ones(self.nnz, dtype=bool), indices, indptr), shape=self.shape)


@dataclasses.dataclass(frozen=True)
class HessianStructure:
    """The nonzero pattern (n, n, boolean CSR) of H and its groups, in the column order
    cameras | points | lines | planes (DESIGN §6); the pattern kept packed (`packed`,
    module docstring), `pattern` unpacks it."""

    variant: str
    packed: PackedPattern
    groups: tuple[HessianGroup, ...]

    @classmethod
    def of(cls, variant: str, pattern: sp.spmatrix | sp.sparray, groups: tuple[HessianGroup, ...]) -> HessianStructure:
        """The structure of the nonzero `pattern` (packed here)."""
        return cls(variant, PackedPattern.of(pattern), groups)

    @property
    def pattern(self) -> sp.csr_matrix:
        """The nonzero pattern, a boolean CSR matrix unpacked on each call."""
        return self.packed.unpack()

    @property
    def items(self) -> int:
        return sum(g.items for g in self.groups)

    @property
    def params(self) -> int:
        return sum(g.size for g in self.groups)

    @property
    def nnz(self) -> int:
        return self.packed.nnz

    def write_png(self, path: pathlib.Path | str, *, max_px: int = 800) -> None:
        """Render to PNG: nonzeros coloured by group (cameras, points/lines, planes)."""
        write_hessian_png(path, self.pattern, self.groups, max_px=max_px, title=f"{self.variant}: H = J^T J")


def hessian_structure(problem: Problem, state: State | None = None) -> HessianStructure:
    """Linearize `problem` at `state` (its initial values by default) and return the block
    structure and numeric nonzero pattern of `H = JᵀJ`."""
    state = problem.initial_state() if state is None else state
    J = problem.linearize(state).jacobian
    H = (J.T @ J).tocsr()
    H.eliminate_zeros()  # the numeric pattern: what packing keeps of H is its index arrays
    L = problem.layout
    groups = tuple(HessianGroup(kind=name, start=L.group_start[name], size=L.group_size[name], items=L.group_items[name]) for name in GROUPS)
    return HessianStructure.of(problem.variant, H, groups)
