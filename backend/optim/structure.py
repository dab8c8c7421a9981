"""Hessian structure of a linearized problem: block groups and the nonzero pattern of
H = JᵀJ, for the viewer's live sparsity image and `coplanar sim --hessian-dir`."""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import scipy.sparse as sp

from backend.optim.hessian_image import HessianGroup, write_hessian_png
from backend.optim.problem import GROUPS, Problem, State


@dataclasses.dataclass(frozen=True)
class HessianStructure:
    """The nonzero pattern (n, n, boolean CSR) of H and its groups, in the column order
    cameras | points | lines | planes (DESIGN §6)."""

    variant: str
    pattern: sp.csr_matrix
    groups: tuple[HessianGroup, ...]

    @property
    def items(self) -> int:
        return sum(g.items for g in self.groups)

    @property
    def params(self) -> int:
        return sum(g.size for g in self.groups)

    @property
    def nnz(self) -> int:
        return int(self.pattern.nnz)

    def write_png(self, path: pathlib.Path | str, *, max_px: int = 800) -> None:
        """Render to PNG: nonzeros coloured by group (cameras, points/lines, planes)."""
        write_hessian_png(path, self.pattern, self.groups, max_px=max_px, title=f"{self.variant}: H = J^T J")


def hessian_structure(problem: Problem, state: State | None = None) -> HessianStructure:
    """Linearize `problem` at `state` (its initial values by default) and return the block
    structure and numeric nonzero pattern of `H = JᵀJ`."""
    state = problem.initial_state() if state is None else state
    J = problem.linearize(state).jacobian
    H = (J.T @ J).tocsr()
    H.eliminate_zeros()
    pattern = sp.csr_matrix((np.ones(H.nnz, dtype=bool), H.indices, H.indptr), shape=H.shape)
    L = problem.layout
    groups = tuple(HessianGroup(kind=name, start=L.group_start[name], size=L.group_size[name], items=L.group_items[name]) for name in GROUPS)
    return HessianStructure(problem.variant, pattern, groups)
