"""A forked engine (the debugger's A/B run) is a run of its own: on the stereo pipeline, whose engine is
composed of a core that holds its state, a shallow copy shared the core, so choosing B's
variant changed A's, and stepping B stepped A."""

from __future__ import annotations

from app.cli import build_parser
from app.serve_command import build_engine
from backend.optim.variant import Variant
from backend.pipeline.engine import fork


def test_a_fork_shares_no_state_with_the_engine() -> None:
    engine = build_engine(build_parser().parse_args(["serve", "--scene", "room", "--duration", "6"]))
    engine.step()
    b = fork(engine)
    b.set_variant(Variant.P_WO)
    assert engine.variant == Variant.PL_W and b.variant == Variant.P_WO
    assert b.core is not engine.core and b.core.plan is b  # type: ignore[attr-defined]
    b.step()
    assert b.keyframes == 2 and engine.keyframes == 1
    assert engine.step().keyframe == 1
