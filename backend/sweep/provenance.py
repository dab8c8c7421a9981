"""Where a sweep run was made: the code's commit, the CPU and the BLAS kernel, kept in each
run's `run.json` so that a table built from a sweep folder can say what it measured.

Why the machine: the VIO's start is sensitive to rounding. `exposure` seed 2 VIO PL-w, the
same commit and inputs, gives an ATE of 8.09 cm with OpenBLAS's Haswell kernels and 5.20 cm
with its Sandy Bridge ones (`OPENBLAS_CORETYPE`), and a table once published 2.04 cm for it
from another machine. Runs of one table belong on one machine; the table says which.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import subprocess
from collections.abc import Iterable, Mapping
from typing import Any

_ROOT = pathlib.Path(__file__).resolve().parents[2]


@dataclasses.dataclass(frozen=True)
class Provenance:
    """`commit`: the git commit of the code (with `-dirty` when tracked files differ from
    it; None outside a git checkout); `cpu`: the processor's model name; `blas`: the BLAS
    library and the kernel it picked for this CPU (threadpoolctl's `internal_api` and
    `architecture`, e.g. `openblas Haswell`)."""

    commit: str | None
    cpu: str
    blas: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(data: Mapping[str, Any] | None) -> Provenance | None:
        """The provenance `to_dict` wrote, or None for a record without one (runs made before
        it was kept) or a malformed one."""
        if not isinstance(data, Mapping):
            return None
        commit, cpu, blas = data.get("commit"), data.get("cpu"), data.get("blas")
        if not (commit is None or isinstance(commit, str)) or not isinstance(cpu, str) or not isinstance(blas, str):
            return None
        return Provenance(commit=commit, cpu=cpu, blas=blas)

    def machine(self) -> str:
        """The CPU and BLAS kernel in words."""
        return f"{self.cpu}, {self.blas}"


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", *args], cwd=_ROOT, capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def code_commit() -> str | None:
    """The short commit of this checkout, `-dirty` when a tracked file differs from it; None
    where there is no git or no repository."""
    commit = _git("rev-parse", "--short=7", "HEAD")
    if not commit:
        return None
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    return f"{commit}-dirty" if dirty else commit


def cpu_model() -> str:
    """The first `model name` of /proc/cpuinfo, else `platform.processor()`, else "unknown"."""
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    import platform

    return platform.processor() or "unknown"


def blas_kernel() -> str:
    """Every BLAS the project's libraries bundle and the kernel each picks for this CPU
    (threadpoolctl), sorted and joined, e.g. `openblas Haswell + openblas Zen`: NumPy's,
    SciPy's and OpenCV's wheels each bundle their own OpenBLAS, and on one AMD EPYC VM NumPy's
    picks Haswell's kernels and OpenCV's Zen's. All three are imported first, so the answer
    depends on the machine only, not on what the process happened to load before; "unknown"
    when threadpoolctl sees none."""
    import cv2  # noqa: F401  (each import loads a BLAS threadpoolctl inspects)
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_info

    kernels = {" ".join(str(part) for part in (info.get("internal_api"), info.get("architecture")) if part) for info in threadpool_info() if info.get("user_api") == "blas"}
    return " + ".join(sorted(kernels)) or "unknown"


@functools.cache
def current() -> Provenance:
    """This process's provenance (computed once: the code and the machine do not change
    while it runs)."""
    return Provenance(commit=code_commit(), cpu=cpu_model(), blas=blas_kernel())


def summary(provenances: Iterable[Provenance | None]) -> str:
    """The provenances of a table's runs in one line: each distinct (commit, machine) with its
    count of runs, most runs first, runs without one counted as "not recorded"."""
    counts: dict[tuple[str, str], int] = {}
    for p in provenances:
        key = ("not recorded", "") if p is None else (p.commit or "no commit", p.machine())
        counts[key] = counts.get(key, 0) + 1
    parts = [f"{commit}{f' on {machine}' if machine else ''} ({n} run{'s' if n != 1 else ''})" for (commit, machine), n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))]
    return "; ".join(parts)
