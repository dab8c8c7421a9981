"""The engine interface: what the viewer and the command line drive (DESIGN §5, §6).

An engine runs a SLAM pipeline one keyframe at a time. Every call that changes its state
returns an immutable :class:`~backend.pipeline.snapshot.Snapshot`; the viewer draws only
snapshots, so the Monte-Carlo engine, the stereo pipeline and VIO are interchangeable.
Ground truth, where the input has it, travels in every snapshot (`Snapshot.ground_truth`).
"""

from __future__ import annotations

import copy
from collections.abc import Iterable
from typing import Any, Protocol, runtime_checkable

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

    def checkpoint(self) -> object:
        """The engine's state now (map, window, estimates, position in the input), to be
        given back to :meth:`restore`: the debugger re-optimizes every variant from the same
        state and returns to a variant's result without recomputing it."""
        ...

    def restore(self, state: object) -> None:
        """Return to a state from :meth:`checkpoint` (any number of times)."""
        ...


def checkpoint_of(engine: object, *, shared: Iterable[str]) -> dict[str, Any]:
    """A deep copy of an engine's attributes except those named in `shared` (the input,
    settings, callbacks and immutable snapshots, which are kept by reference)."""
    keep = set(shared)
    state = vars(engine)
    return {"copied": copy.deepcopy({k: v for k, v in state.items() if k not in keep}), "shared": {k: state[k] for k in keep if k in state}}


def restore_from(engine: object, checkpoint: dict[str, Any]) -> None:
    """Put a :func:`checkpoint_of` state back (copied again, so it can be restored again)."""
    vars(engine).update(copy.deepcopy(checkpoint["copied"]))
    vars(engine).update(checkpoint["shared"])
