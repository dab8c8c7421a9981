"""Test-wide settings: single-threaded BLAS, as the command line uses (small dense solves)."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
