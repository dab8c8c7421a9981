"""An engine that plays a recording back (`coplanar serve --replay FILE`): each step is the
next recorded keyframe, as it was stepped; every variant recorded there is offered beside
it (`recorded_variants`), the one the user chose last shown; the Hessian tab's comparison
is the recorded one. Nothing is computed: no dataset, no optimizer. What was not recorded
cannot be shown, and says so (:class:`NotRecorded`).
"""

from __future__ import annotations

from backend.optim.structure import HessianStructure
from backend.optim.variant import Variant
from backend.pipeline.engine import EndOfSequence
from backend.pipeline.recording import RecordedKeyframe, Recording
from backend.pipeline.snapshot import Snapshot


class NotRecorded(RuntimeError):
    """A variant asked for at a keyframe where the recording has none."""


class ReplayEngine:
    """The :class:`~backend.pipeline.engine.Engine` of a recording (no `checkpoint`: the
    debugger then offers no A/B run and computes nothing ahead)."""

    replay = True

    def __init__(self, recording: Recording) -> None:
        self.recording = recording
        self._index = -1
        self._variant = recording.keyframes[0].stepped

    @property
    def source(self) -> str:
        return f"{self.recording.source} (replay of {self.recording.path.name})"

    @property
    def variant(self) -> Variant:
        return self._variant

    @property
    def keyframes(self) -> int:
        """Keyframes the recording holds."""
        return len(self.recording)

    def _current(self) -> RecordedKeyframe:
        if self._index < 0:
            raise RuntimeError("no keyframe replayed yet")
        return self.recording.keyframes[self._index]

    def step(self) -> Snapshot:
        """The next recorded keyframe as it was stepped; EndOfSequence after the last."""
        if self._index + 1 >= len(self.recording):
            raise EndOfSequence(f"end of the recording ({len(self.recording)} keyframes)")
        self._index += 1
        current = self._current()
        self._variant = current.stepped
        return self.recording.snapshot(current.keyframe, current.stepped)

    def recorded_variants(self) -> list[Snapshot]:
        """The other variants recorded at the current keyframe, in the order computed; the
        engine's variant becomes the one shown last there (`chosen`)."""
        current = self._current()
        self._variant = current.chosen
        return [self.recording.snapshot(current.keyframe, v) for v in current.variants if v != current.stepped]

    def set_variant(self, variant: Variant) -> None:
        self._variant = Variant.parse(variant)

    def reoptimize(self) -> Snapshot:
        """The current variant's recorded snapshot at the current keyframe; NotRecorded
        (saying which are) where there is none."""
        current = self._current()
        if self._variant not in current.variants:
            have = ", ".join(current.variants)
            raise NotRecorded(f"{self._variant} was not recorded at keyframe {current.keyframe} (recorded there: {have})")
        return self.recording.snapshot(current.keyframe, self._variant)

    def reset(self) -> None:
        self._index = -1
        self._variant = self.recording.keyframes[0].stepped

    def compare_hessians(self, variants: tuple[Variant, ...]) -> dict[Variant, HessianStructure]:
        """The recorded comparison at the current keyframe for `variants`' features ({}: none)."""
        if self._index < 0 or not variants:
            return {}
        found = self.recording.comparison(self._current().keyframe, with_lines=variants[0].with_lines)
        return {v: found[v] for v in variants if v in found}
