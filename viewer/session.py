"""What the debugger keeps of a run, apart from the screen: the engine, its snapshots per
keyframe and variant (`SnapshotHistory`), the engine's checkpoints at the newest keyframe
(after its step, and after each variant's re-optimization there), and the A/B run, a second
engine on the same input in lockstep with its snapshots. Everything here runs on the
debugger's worker thread; it decides, the debugger shows."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable

from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.engine import EndOfSequence, Engine, EngineCheckpoint
from backend.pipeline.snapshot import Snapshot
from viewer.history import SnapshotHistory


@dataclasses.dataclass(frozen=True)
class Stepped:
    """A step's snapshot, the A/B run's (None: off or ended) and why B stopped ('' if not)."""

    snapshot: Snapshot
    other: Snapshot | None
    b_stopped: str = ""


class Session:
    """The run behind the debugger (module docstring); `keep`: keyframes kept."""

    def __init__(self, engine: Engine, *, keep: int) -> None:
        self.engine = engine
        self.keep = keep
        self.history = SnapshotHistory(keep)
        self._states_keyframe: int | None = None
        self._states: dict[object, EngineCheckpoint] = {}
        self.engine_b: Engine | None = None
        self.history_b: dict[int, Snapshot] = {}

    @property
    def can_checkpoint(self) -> bool:
        return hasattr(self.engine, "checkpoint")

    def step(self) -> Stepped:
        """One keyframe (both engines of an A/B run); EndOfSequence when A has no more."""
        snapshot = self.engine.step()
        other, why = None, ""
        if self.engine_b is not None:
            try:
                other = self.engine_b.step()
                self._keep_b(other)
            except EndOfSequence:
                self.stop_ab()
                why = "B reached the end of the sequence"
        self._states_keyframe = None
        self._states = {}
        self.history.add_step(snapshot)
        return Stepped(snapshot, other, why)

    def switch_variant(self, variant: Variant, *, busy: Callable[[str], None]) -> Snapshot | None:
        """`variant` at the newest keyframe: its kept result, or the window re-optimized with
        it from the state the step left (`busy` says so first). None before the first step:
        the engine then uses it from the first step."""
        if not self.history:
            self.engine.set_variant(variant)
            return None
        k = self.history.newest_keyframe
        has_states = self.can_checkpoint
        if has_states and self._states_keyframe != k:
            self._states_keyframe = k
            base = self.engine.checkpoint()  # restore() copies it again, so one serves both
            self._states = {"base": base, self.engine.variant: base}
        kept = self.history.variants_at(k).get(variant)
        if has_states and kept is not None and variant in self._states:
            self.engine.restore(self._states[variant])
            self.engine.set_variant(variant)
            self.history.choose(k, variant)
            return kept
        busy(f"re-optimizing the window with {variant} …")
        if has_states:
            self.engine.restore(self._states["base"])
        self.engine.set_variant(variant)
        snapshot = self.engine.reoptimize()
        if has_states:
            self._states[variant] = self.engine.checkpoint()
        self.history.add_variant(snapshot)
        return snapshot

    def missing_variants(self) -> list[Variant]:
        """The variants not yet computed at the newest keyframe."""
        have = self.history.variants_at(self.history.newest_keyframe)
        return [v for v in VARIANTS if v not in have]

    def start_ab(self, variant: Variant) -> None:
        """B: a copy of the engine from its state now, with `variant` (its window re-optimized
        at once when there is a keyframe). The engine must be able to checkpoint."""
        engine_b = copy.copy(self.engine)
        engine_b.restore(self.engine.checkpoint())
        engine_b.set_variant(variant)
        self.engine_b = engine_b
        self.history_b = {}
        if self.history:
            self._keep_b(engine_b.reoptimize())

    def stop_ab(self) -> None:
        self.engine_b = None
        self.history_b = {}

    def other_at(self, keyframe: int) -> Snapshot | None:
        """B's snapshot at `keyframe` (None: none, or no A/B run)."""
        return self.history_b.get(keyframe) if self.engine_b is not None else None

    def reset(self) -> None:
        """The engine back to the start; nothing kept, no A/B run."""
        self.engine.reset()
        self.history.clear()
        self.stop_ab()
        self._states_keyframe = None
        self._states = {}

    def _keep_b(self, snapshot: Snapshot) -> None:
        self.history_b[snapshot.keyframe] = snapshot
        while len(self.history_b) > self.keep:
            self.history_b.pop(next(iter(self.history_b)))
