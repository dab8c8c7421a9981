"""What the debugger keeps of a run, apart from the screen: the engine, its snapshots per
keyframe and variant (`SnapshotHistory`), the engine's checkpoints at the newest keyframe
(after its step, and after each variant's re-optimization there), the A/B run, a second
engine on the same input in lockstep with its snapshots, and the next step computed ahead.

Stepping ahead: while the user looks at a keyframe, the worker computes the next one
(`step_ahead`) from a checkpoint of the engine(s), so that Step only has to show it. The
step is kept aside, not in the history; Step takes it; anything else that changes what the
next step would be (another variant, the A/B run, the segmenter, Reset) or reads the
engine's newest state (the -wo | -r | -w comparison) first puts the engines back where they
were (`cancel_ahead`). The engine's results do not depend on when a step is computed, so
what Step shows is what it would have computed then.

Recording (`start_recording`): from then on every snapshot the history gains (steps and
variants), the variant chosen last at each keyframe and the plane-mode comparison of each
step's window go to a `RecordingWriter` (backend/pipeline/recording.py), encoded at once;
what the history keeps when it starts is recorded first. A replay engine
(backend/pipeline/replay_engine.py) offers every variant it recorded at a keyframe with the
step; they enter the history with it, the one chosen last shown.

Everything here runs on the debugger's worker thread; it decides, the debugger shows."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from backend.optim.structure import HessianStructure
from backend.optim.variant import VARIANTS, Variant
from backend.pipeline.engine import EndOfSequence, Engine, EngineCheckpoint, fork
from backend.pipeline.recording import RecordingWriter
from backend.pipeline.snapshot import FrameTrajectory, Snapshot
from viewer.history import DEFAULT_MAX_BYTES, SnapshotHistory


@dataclasses.dataclass(frozen=True)
class _Ahead:
    """A step computed ahead: its result (A's snapshot, B's or None, why B stopped, or
    `ended`: A had no next keyframe), the engines' checkpoints before it, and A's frame
    trajectory before it (what an export of the newest keyframe shows)."""

    snapshot: Snapshot | None
    other: Snapshot | None
    b_stopped: str
    ended: EndOfSequence | None
    before: EngineCheckpoint
    before_b: EngineCheckpoint | None
    frame_trajectory: FrameTrajectory | None


@dataclasses.dataclass(frozen=True)
class Stepped:
    """A step's snapshot, the A/B run's (None: off or ended) and why B stopped ('' if not)."""

    snapshot: Snapshot
    other: Snapshot | None
    b_stopped: str = ""


class Session:
    """The run behind the debugger (module docstring); `keep`: keyframes kept, `max_bytes`:
    bytes of their snapshots' arrays kept (viewer/history.py)."""

    def __init__(self, engine: Engine, *, keep: int, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.engine = engine
        self.keep = keep
        self.history = SnapshotHistory(keep, max_bytes=max_bytes)
        self._states_keyframe: int | None = None
        self._states: dict[object, EngineCheckpoint] = {}
        self.engine_b: Engine | None = None
        self.history_b: dict[int, Snapshot] = {}
        self._ahead: _Ahead | None = None
        self._ahead_failed = False  # the last step ahead raised: the next Step meets the error in place
        # the newest keyframe's window, as its step left it, under each plane family (computed once)
        self._compared: dict[tuple[int, bool], dict[Variant, HessianStructure]] = {}
        self.recorder: RecordingWriter | None = None  # the last recording (kept for download after it stops)
        self.recording = False

    @property
    def can_checkpoint(self) -> bool:
        return hasattr(self.engine, "checkpoint")

    @property
    def keyframes(self) -> int:
        """Keyframes stepped (not counting one computed ahead)."""
        return self.history.newest_keyframe + 1 if self.history else 0

    @property
    def has_ahead(self) -> bool:
        return self._ahead is not None

    def wants_ahead(self) -> bool:
        """Whether a step ahead would be computed now (none kept, the engine can be put back)."""
        return self._ahead is None and not self._ahead_failed and self.can_checkpoint

    def step_ahead(self) -> None:
        """Compute the next step aside (module docstring). It raises nothing: the end of the
        sequence is kept for the Step that follows, and after an error the engines are put
        back, so that the Step meets it again in place."""
        if not self.wants_ahead():
            return
        before = self.engine.checkpoint()
        before_b = self.engine_b.checkpoint() if self.engine_b is not None else None
        trajectory = self.frame_trajectory()
        try:
            snapshot, other, why = self._advance()
        except EndOfSequence as end:
            self._ahead = _Ahead(None, None, "", end, before, before_b, trajectory)
            return
        except Exception:  # met again by the Step that follows, where the user sees it
            self._restore(before, before_b)
            self._ahead_failed = True
            return
        self._ahead = _Ahead(snapshot, other, why, None, before, before_b, trajectory)

    def cancel_ahead(self) -> None:
        """The engines back to where the last Step left them (no step kept aside)."""
        ahead, self._ahead = self._ahead, None
        self._ahead_failed = False
        if ahead is not None:
            self._restore(ahead.before, ahead.before_b)

    def frame_trajectory(self) -> FrameTrajectory | None:
        """The engine's frame trajectory up to the newest keyframe stepped (None: it has none)."""
        ahead = self._ahead
        if ahead is not None:
            return ahead.frame_trajectory
        method = getattr(self.engine, "frame_trajectory", None)
        return method() if method is not None else None

    def step(self) -> Stepped:
        """One keyframe (both engines of an A/B run); EndOfSequence when A has no more. The
        step computed ahead, if any, is taken."""
        ahead, self._ahead = self._ahead, None
        self._ahead_failed = False
        if ahead is not None:
            if ahead.ended is not None:
                raise ahead.ended
            assert ahead.snapshot is not None
            snapshot, other, why = ahead.snapshot, ahead.other, ahead.b_stopped
        else:
            snapshot, other, why = self._advance()
        if other is not None:
            self._keep_b(other)
        if why:
            self.stop_ab()
        self._states_keyframe = None
        self._states = {}
        self._compared = {}
        self.history.add_step(snapshot)
        self._record(snapshot)
        recorded = getattr(self.engine, "recorded_variants", None)
        if recorded is not None:  # a replay: the variants recorded at this keyframe, the one chosen last shown
            for kept in recorded():
                self.history.add_variant(kept)
                self._record(kept)
            self.history.choose(snapshot.keyframe, self.engine.variant)
            if self.recording and self.recorder is not None:
                self.recorder.choose(snapshot.keyframe, self.engine.variant)
            snapshot = self.history.get(snapshot.keyframe) or snapshot
        if self.recording:
            self.compare_hessians(snapshot.variant.family())  # recorded as the Hessian tab would show it
        return Stepped(snapshot, other, why)

    def _advance(self) -> tuple[Snapshot, Snapshot | None, str]:
        """The engines' next step, nothing kept (EndOfSequence when A has no more)."""
        snapshot = self.engine.step()
        other, why = None, ""
        if self.engine_b is not None:
            try:
                other = self.engine_b.step()
            except EndOfSequence:
                why = "B reached the end of the sequence"
        return snapshot, other, why

    def _restore(self, before: EngineCheckpoint, before_b: EngineCheckpoint | None) -> None:
        self.engine.restore(before)
        if self.engine_b is not None and before_b is not None:
            self.engine_b.restore(before_b)

    def switch_variant(self, variant: Variant, *, busy: Callable[[str], None]) -> Snapshot | None:
        """`variant` at the newest keyframe: its kept result, or the window re-optimized with
        it from the state the step left (`busy` says so first). None before the first step:
        the engine then uses it from the first step."""
        self.cancel_ahead()
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
            if self.recording and self.recorder is not None:
                self.recorder.choose(k, variant)
            return kept
        busy(f"re-optimizing the window with {variant} …")
        if has_states:
            self.engine.restore(self._states["base"])
        self.engine.set_variant(variant)
        snapshot = self.engine.reoptimize()
        if has_states:
            self._states[variant] = self.engine.checkpoint()
        self.history.add_variant(snapshot)
        self._record(snapshot)
        return snapshot

    def compare_hessians(self, family: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        """The newest window as its step left it (not as a variant chosen there re-optimized
        it) linearized under each of `family`; the engine is left as it was. Computed once
        per keyframe and feature set (and recorded while recording)."""
        key = (self.history.newest_keyframe if self.history else -1, bool(family) and family[0].with_lines)
        if key in self._compared:
            return self._compared[key]
        structures = self._compare(family)
        self._compared[key] = structures
        if self.recording and self.recorder is not None and structures:
            self.recorder.add_comparison(key[0], dict(structures))
        return structures

    def _compare(self, family: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        self.cancel_ahead()
        base = self._states.get("base") if self._states_keyframe == self.history.newest_keyframe else None
        current = self._states.get(self.engine.variant)
        if base is None or current is None or current is base:
            return self.engine.compare_hessians(family)
        variant = self.engine.variant
        self.engine.restore(base)
        try:
            return self.engine.compare_hessians(family)
        finally:
            self.engine.restore(current)
            self.engine.set_variant(variant)

    def missing_variants(self) -> list[Variant]:
        """The variants not yet computed at the newest keyframe."""
        have = self.history.variants_at(self.history.newest_keyframe)
        return [v for v in VARIANTS if v not in have]

    def start_ab(self, variant: Variant) -> None:
        """B: a copy of the engine from its state now, with `variant` (its window re-optimized
        at once when there is a keyframe). The engine must be able to checkpoint."""
        self.cancel_ahead()
        engine_b = fork(self.engine)
        engine_b.set_variant(variant)
        self.engine_b = engine_b
        self.history_b = {}
        if self.history:
            self._keep_b(engine_b.reoptimize())

    def stop_ab(self) -> None:
        self.cancel_ahead()
        self.engine_b = None
        self.history_b = {}

    def other_at(self, keyframe: int) -> Snapshot | None:
        """B's snapshot at `keyframe` (None: none, or no A/B run)."""
        return self.history_b.get(keyframe) if self.engine_b is not None else None

    def reset(self) -> None:
        """The engine back to the start; nothing kept, no A/B run."""
        self.cancel_ahead()
        self.engine.reset()
        self.history.clear()
        self.stop_ab()
        self._states_keyframe = None
        self._states = {}
        self._compared = {}
        self.recording = False  # the recording so far stays for download; keyframe numbers start again

    def start_recording(self) -> RecordingWriter:
        """Record from now on (module docstring), starting with what the history keeps."""
        recorder = RecordingWriter(source=self.engine.source)
        for k in self.history.keyframes():
            for snapshot in self.history.variants_at(k).values():
                recorder.add(snapshot)
            latest = self.history.get(k)
            if latest is not None:
                recorder.choose(k, latest.variant)
        for (k, _), structures in self._compared.items():
            recorder.add_comparison(k, dict(structures))
        self.recorder, self.recording = recorder, True
        return recorder

    def stop_recording(self) -> None:
        """Stop recording; what was recorded stays (`recorder`)."""
        self.recording = False

    def _record(self, snapshot: Snapshot) -> None:
        if self.recording and self.recorder is not None:
            self.recorder.add(snapshot)

    def _keep_b(self, snapshot: Snapshot) -> None:
        self.history_b[snapshot.keyframe] = snapshot
        first = self.history.first_keyframe if self.history else snapshot.keyframe
        while len(self.history_b) > self.keep or next(iter(self.history_b)) < first:  # B's kept keyframes follow A's
            self.history_b.pop(next(iter(self.history_b)))
