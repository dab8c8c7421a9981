"""The Hessian's pattern kept packed: unpacked exactly, and much smaller than the CSR matrix."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from backend.optim.structure import HessianStructure, PackedPattern, hessian_structure
from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot_codec import decode, encode, same


def _csr_bytes(m: sp.csr_matrix) -> int:
    return int(m.data.nbytes + m.indices.nbytes + m.indptr.nbytes)


def test_a_window_pattern_unpacks_to_the_same_csr_arrays() -> None:
    """The snapshot of a Monte-Carlo window: the unpacked pattern has the index arrays the
    linearization gave, in their order, and True at every entry."""
    engine = SimEngine(SimSettings(sequence="a", window=10))
    for _ in range(12):
        snapshot = engine.step()
    h = snapshot.hessian
    assert h is not None
    P = h.pattern
    assert P.shape == (h.params, h.params) and P.nnz == h.nnz > 0
    assert P.dtype == np.bool_ and P.data.all()
    again = PackedPattern.of(P).unpack()
    np.testing.assert_array_equal(again.indices, P.indices)
    np.testing.assert_array_equal(again.indptr, P.indptr)
    assert (P != P.T).nnz == 0  # H = JᵀJ is symmetric
    assert len(h.packed.blob) * 10 < _csr_bytes(P)  # what the debugger's history holds of it


def test_any_pattern_round_trips_unsorted_rows_and_empty_ones_included() -> None:
    rng = np.random.default_rng(4)
    dense = rng.random((40, 30)) < 0.2
    dense[7] = False  # an empty row
    m = sp.csr_matrix(dense)
    order = rng.permutation(m.indices.size)  # unsorted indices within rows stay as given
    for r in range(m.shape[0]):
        a, b = m.indptr[r], m.indptr[r + 1]
        m.indices[a:b] = m.indices[a:b][order[a:b].argsort()]
    m.has_sorted_indices = False
    back = PackedPattern.of(m).unpack()
    np.testing.assert_array_equal(back.indices, m.indices)
    np.testing.assert_array_equal(back.indptr, m.indptr)
    np.testing.assert_array_equal(back.toarray(), dense)
    empty = PackedPattern.of(sp.csr_matrix((5, 5), dtype=bool))
    assert empty.nnz == 0 and empty.unpack().shape == (5, 5) and empty.unpack().nnz == 0


def test_a_damaged_blob_is_an_error_not_a_wrong_pattern() -> None:
    good = PackedPattern.of(sp.identity(6, format="csr", dtype=bool))
    with pytest.raises(ValueError, match="12 numbers, expected 6 row lengths and 5 indices"):
        PackedPattern(shape=(6, 6), nnz=5, blob=good.blob).unpack()


def test_recorded_structures_keep_their_format_and_read_back() -> None:
    """A recording writes the pattern as its CSR arrays, as before it was packed, so files
    of both versions read back into the same structure."""
    from backend.eval import montecarlo, sequences
    from backend.optim.problem import build_problem

    world = sequences.make_world("b", seed=0)
    data = montecarlo.make_problem_data(world, np.random.default_rng([0, 0]))
    h = hessian_structure(build_problem(data, "PL-w"))
    encoded = encode(h)
    assert encoded.tree["fields"]["pattern"]["csr"] == "pattern" and "packed" not in encoded.tree["fields"]
    back = decode(encoded)
    assert isinstance(back, HessianStructure) and same(back, h) and back.groups == h.groups
    assert (back.pattern != h.pattern).nnz == 0
