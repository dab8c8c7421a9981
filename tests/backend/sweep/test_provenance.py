"""backend.sweep.provenance: what a table says about where its runs were made."""

from __future__ import annotations

from backend.sweep.provenance import Provenance, current, summary


def test_this_process_names_its_cpu_and_blas_kernel() -> None:
    here = current()
    assert here.cpu and here.cpu != "unknown"
    assert here.blas.startswith("openblas")  # NumPy's wheels bundle OpenBLAS; the kernel follows the CPU
    assert Provenance.from_dict(here.to_dict()) == here


def test_a_record_without_or_with_a_broken_provenance_reads_as_none() -> None:
    assert Provenance.from_dict(None) is None
    assert Provenance.from_dict({"commit": "abc", "cpu": 3, "blas": "x"}) is None


def test_summary_counts_each_commit_and_machine_most_runs_first() -> None:
    a = Provenance(commit="1111111", cpu="AMD EPYC", blas="openblas Haswell")
    b = Provenance(commit="2222222", cpu="Intel Xeon", blas="openblas SkylakeX")
    assert summary([a, b, a, None]) == ("1111111 on AMD EPYC, openblas Haswell (2 runs); 2222222 on Intel Xeon, openblas SkylakeX (1 run); not recorded (1 run)")
