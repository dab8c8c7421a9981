"""Engine checkpoints (backend.pipeline.engine.EngineCheckpoint): a restored engine goes on
exactly as the original did, a checkpoint serves any number of restores, and every
attribute an engine holds is declared state (copied) or shared (by reference)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from backend.pipeline.engine import EngineCheckpoint
from backend.pipeline.factory import EngineConfig, make_engine

ENGINES: dict[str, Callable[[], object]] = {
    "monte-carlo": lambda: make_engine(EngineConfig(scene="mc-a", window=4)),
    "stereo": lambda: make_engine(EngineConfig(scene="room", duration_s=4.0, interactive=True)),
    "vio": lambda: make_engine(EngineConfig(scene="room", duration_s=6.0, speed=2.0, mode="vio", segmenter="oracle")),
}


def _same(a, b) -> None:
    assert a.keyframe == b.keyframe and a.report.final_cost == b.report.final_cost
    np.testing.assert_array_equal(a.estimate.t_world_camera, b.estimate.t_world_camera)
    np.testing.assert_array_equal(a.points.p_world, b.points.p_world)


@pytest.mark.parametrize("kind", list(ENGINES))
def test_a_restored_engine_goes_on_as_the_original(kind: str) -> None:
    engine = ENGINES[kind]()
    for _ in range(4):
        engine.step()
    saved = engine.checkpoint()
    assert isinstance(saved, EngineCheckpoint)
    ahead = [engine.step() for _ in range(2)]
    engine.set_variant("P-wo")
    engine.reoptimize()
    for _ in range(2):  # restore twice: the checkpoint is not consumed
        engine.restore(saved)
        assert engine.variant == "PL-w"
        again = [engine.step() for _ in range(2)]
        for a, b in zip(ahead, again):
            _same(a, b)


@pytest.mark.parametrize("kind", list(ENGINES))
def test_every_attribute_is_declared(kind: str) -> None:
    engine = ENGINES[kind]()
    for _ in range(3):
        engine.step()
    parts = getattr(engine, "PARTS", ())
    declared = set(engine.STATE) | set(engine.SHARED) | set(parts) | {"map"}
    assert set(vars(engine)) <= declared, sorted(set(vars(engine)) - declared)
    for name in parts:  # a part (the image engines' core) declares its own
        part = getattr(engine, name)
        assert set(vars(part)) <= set(part.STATE) | set(part.SHARED) | {"map"}, name
    engine.undeclared_attribute = 1
    with pytest.raises(RuntimeError, match="undeclared_attribute"):
        engine.checkpoint()
    for name in parts:
        del engine.undeclared_attribute
        getattr(engine, name).undeclared_attribute = 1
        with pytest.raises(RuntimeError, match="undeclared_attribute"):
            engine.checkpoint()
