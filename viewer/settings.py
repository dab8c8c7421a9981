"""The debugger's settings."""

from __future__ import annotations

import dataclasses
import pathlib


@dataclasses.dataclass(frozen=True)
class ViewerSettings:
    """`history`: keyframes kept for scrubbing (oldest dropped first), and at most
    `history_mb` MiB of their snapshots' arrays (the map's points weigh most: each snapshot
    holds the whole map). `rate_hz`: default
    Play rate. `compare`: compute the -wo | -r | -w comparison after each step. `plots`:
    draw the plots over time (in the background, after each update). `sweep`: a `coplanar
    sweep` output folder the Sweep tab shows (None: none)."""

    history: int = 500
    history_mb: float = 60.0  # as deep as 70 MiB was before the Hessian patterns were packed (43 keyframes after 500 steps of room; docs/results/debugger.md)
    rate_hz: float = 5.0
    compare: bool = True
    plots: bool = True
    sweep: pathlib.Path | None = None
