"""The engine interface: what the viewer and the command line drive (DESIGN §5, §6).

An engine runs a SLAM pipeline one keyframe at a time. Every call that changes its state
returns an immutable :class:`~backend.pipeline.snapshot.Snapshot`; the viewer draws only
snapshots, so the Monte-Carlo engine, the stereo pipeline and VIO are interchangeable.
Ground truth, where the input has it, travels in every snapshot (`Snapshot.ground_truth`).
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any, Protocol, runtime_checkable

from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
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
    def variant(self) -> Variant:
        """The parametrization used by the next optimization (DESIGN §2 names)."""
        ...

    def step(self) -> Snapshot:
        """Process the next keyframe and optimize the window. Raises EndOfSequence."""
        ...

    def set_variant(self, variant: Variant) -> None:
        """Select the variant for following optimizations. Raises ValueError if unknown."""
        ...

    def reoptimize(self) -> Snapshot:
        """Re-solve the current window with the current variant. Raises RuntimeError before
        the first step."""
        ...

    def reset(self) -> None:
        """Start again from the first keyframe with the same settings."""
        ...

    def compare_hessians(self, variants: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        """The current window linearized under each of `variants` (same data)."""
        ...

    def checkpoint(self) -> EngineCheckpoint:
        """The engine's state now (map, window, estimates, position in the input), to be
        given back to :meth:`restore`: the debugger re-optimizes every variant from the same
        state and returns to a variant's result without recomputing it."""
        ...

    def restore(self, state: EngineCheckpoint) -> None:
        """Return to a state from :meth:`checkpoint` (any number of times)."""
        ...


@dataclasses.dataclass(frozen=True)
class EngineCheckpoint:
    """An engine's state at one moment, explicitly: a copy of its map (None for an engine
    without a `backend.mapping.map.Map`), a deep copy of the attributes the engine declares
    in its `STATE`, and those it declares `SHARED` (the input, settings, callbacks, immutable
    snapshots), by reference; so are functions set on the instance (callbacks, patches). The
    parts an engine declares in `PARTS` (objects it is composed of that hold state of their
    own, such as the image engines' `PipelineCore`) checkpoint themselves: their
    `checkpoint()` is kept here and handed to their `restore()`. Any other attribute declared
    in none of these is an error at once, not a silent deep copy."""

    map: Any
    state: dict[str, Any]
    shared: dict[str, Any]
    parts: dict[str, EngineCheckpoint] = dataclasses.field(default_factory=dict)

    @staticmethod
    def of(engine: Any, the_map: Any = None) -> EngineCheckpoint:
        parts: tuple[str, ...] = getattr(engine, "PARTS", ())
        declared = set(engine.STATE) | set(engine.SHARED) | set(parts) | ({"map"} if the_map is not None else set())
        extra = set(vars(engine)) - declared
        functions = {name for name in extra if callable(getattr(engine, name))}  # callbacks or patches set on the instance: shared
        if extra - functions:
            raise RuntimeError(f"{type(engine).__name__}: attributes neither in STATE nor in SHARED: {', '.join(sorted(extra - functions))}")
        return EngineCheckpoint(
            map=None if the_map is None else the_map.copy(),
            state=copy.deepcopy({name: getattr(engine, name) for name in engine.STATE if hasattr(engine, name)}),
            shared={name: getattr(engine, name) for name in (*engine.SHARED, *sorted(functions)) if hasattr(engine, name)},
            parts={name: getattr(engine, name).checkpoint() for name in parts},
        )

    def restore_into(self, engine: Any) -> Any:
        """Put the state back into `engine` (copied again, so it can be restored again);
        returns a fresh copy of the map for the engine to hold (None without one)."""
        for name, value in copy.deepcopy(self.state).items():
            setattr(engine, name, value)
        for name, value in self.shared.items():
            setattr(engine, name, value)
        for name, part in self.parts.items():
            getattr(engine, name).restore(part)
        return None if self.map is None else self.map.copy()


def fork(engine: Any) -> Any:
    """A second engine: a copy of `engine` in its state now that shares only its input and
    settings (its `SHARED`), so that stepping, re-optimizing or changing the variant of one
    never moves the other (the debugger's A/B run). The parts it is composed of (`PARTS`,
    such as the image engines' `PipelineCore`) are copied too and refer to the copy: a
    shallow copy shared the stereo pipeline's core, and B's variant became A's."""
    copied = copy.copy(engine)
    parts: tuple[str, ...] = getattr(engine, "PARTS", ())
    for name in parts:
        setattr(copied, name, copy.copy(getattr(engine, name)))
    copied.restore(engine.checkpoint())
    for name in parts:  # a part's reference to its engine (the core's plan) names the copy
        part = getattr(copied, name)
        for attr, value in list(vars(part).items()):
            if value is engine:
                setattr(part, attr, copied)
    return copied
