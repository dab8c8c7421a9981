"""The engine interface: what the viewer and the command line drive (DESIGN §5, §6).

An engine runs a SLAM pipeline one keyframe at a time. Every call that changes its state
returns an immutable :class:`~backend.pipeline.snapshot.Snapshot`; the viewer draws only
snapshots, so the Monte-Carlo engine, the stereo pipeline and VIO are interchangeable.
Ground truth, where the input has it, travels in every snapshot (`Snapshot.ground_truth`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from backend.optim.structure import HessianStructure
from backend.pipeline.snapshot import Snapshot


class EndOfSequence(Exception):
    """Raised by :meth:`Engine.step` when the input has no more keyframes."""


@runtime_checkable
class Engine(Protocol):
    """A step-able SLAM pipeline."""

    @property
    def source(self) -> str:
        """Human-readable name of the input (scene or dataset)."""
        ...

    @property
    def variant(self) -> str:
        """The parametrization used by the next optimization (DESIGN §2 names)."""
        ...

    def step(self) -> Snapshot:
        """Process the next keyframe and optimize the window. Raises EndOfSequence."""
        ...

    def set_variant(self, name: str) -> None:
        """Select the variant for following optimizations. Raises ValueError if unknown."""
        ...

    def reoptimize(self) -> Snapshot:
        """Re-solve the current window with the current variant. Raises RuntimeError before
        the first step."""
        ...

    def reset(self) -> None:
        """Start again from the first keyframe with the same settings."""
        ...

    def compare_hessians(self, variants: tuple[str, ...]) -> dict[str, HessianStructure]:
        """The current window linearized under each of `variants` (same data)."""
        ...
