"""EngineConfig and make_engine (backend/pipeline/factory.py): the engines the command line,
the debugger and the scripts get from one description."""

from __future__ import annotations

import pathlib

import pytest

from app import cli
from app.sources import build_engine
from backend.data.scenes import builtin_scene
from backend.data.synthetic import SequenceSettings, render_sequence
from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter
from backend.frontend.segmentation_learned import LearnedSegmenter
from backend.frontend.segmenters import SegmenterError, SegmenterKind
from backend.optim.variant import Variant
from backend.pipeline.factory import EngineConfig, Mode, default_window, make_engine
from backend.pipeline.sim_engine import SimEngine
from backend.pipeline.stereo_engine import StereoEngine
from backend.pipeline.stereo_settings import StereoSettings
from backend.pipeline.vio_engine import VioEngine
from backend.pipeline.vio_settings import VioSettings


def test_a_monte_carlo_world() -> None:
    engine = make_engine(EngineConfig(scene="mc-b", variant="P-r", window=4, seed=3, mislabel=0.0))
    assert isinstance(engine, SimEngine) and engine.variant is Variant.P_R
    assert (engine.settings.sequence, engine.settings.window, engine.settings.seed, engine.settings.mislabel) == ("b", 4, 3, 0.0)
    with pytest.raises(ValueError, match="no images"):
        make_engine(EngineConfig(scene="mc-a", mode=Mode.VIO))


def test_a_rendered_scene_headless_and_interactive() -> None:
    run = make_engine(EngineConfig(scene="corridor", duration_s=2.5, stride=2, speed=1.5, seed=1))
    assert isinstance(run, StereoEngine) and isinstance(run.segmenter, GeometricPlaneSegmenter)
    assert run.source == "rendered scene corridor (2.5 s, seed 1, every 2th frame, 1.5× speed)" and len(run.data_source) == 26
    assert run.settings.skip_unused_stages and run.settings.image_scale is None and not run.settings.hessian
    debugger = make_engine(EngineConfig(scene="room", duration_s=1.0, interactive=True))
    assert not debugger.settings.skip_unused_stages and debugger.settings.image_scale == 1.0 and debugger.settings.hessian


def test_vio_takes_the_learned_segmenter_and_its_own_window_by_default(tmp_path: pathlib.Path) -> None:
    engine = make_engine(EngineConfig(scene="room", duration_s=1.0, mode="vio", variant="P-wo"))
    assert isinstance(engine, VioEngine) and isinstance(engine.segmenter, LearnedSegmenter)
    assert engine.source.endswith(", VIO, learned segmenter")
    assert engine.settings.window == default_window(Mode.VIO) == VioSettings().window == 20
    assert make_engine(EngineConfig(scene="room", duration_s=1.0, mode="vio", window=10)).settings.window == 10
    stereo = make_engine(EngineConfig(scene="room", duration_s=1.0))
    assert stereo.settings.window == default_window(Mode.STEREO) == StereoSettings().window == 10


def test_a_dataset_and_the_oracle_it_cannot_have(tmp_path: pathlib.Path) -> None:
    render_sequence(builtin_scene("room"), tmp_path, settings=SequenceSettings(duration_s=0.2))
    engine = make_engine(EngineConfig(dataset=tmp_path, frames=3))
    assert engine.source == f"EuRoC folder {tmp_path}" and len(engine.data_source) == 3
    with pytest.raises(SegmenterError, match="rendered scene"):
        make_engine(EngineConfig(dataset=tmp_path, segmenter=SegmenterKind.ORACLE))
    with pytest.raises(ValueError, match="not both"):
        EngineConfig(scene="room", dataset=tmp_path)


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--scene", "boxes", "--duration", "2", "--variant", "P-w", "--window", "5", "--seed", "2", "--out", "x"],
        ["serve", "--scene", "corridor", "--duration", "3", "--mode", "vio", "--segmenter", "geometric"],
        ["serve", "--scene", "mc-a", "--variant", "PL-r", "--mislabel", "0.3"],
    ],
)
def test_the_command_line_builds_through_the_same_config(argv: list[str]) -> None:
    """The CLI's engine equals the one its EngineConfig describes: same class, name, settings."""
    args = cli.build_parser().parse_args(argv)
    engine = build_engine(args, headless=argv[0] == "run")
    if argv[0] == "serve" and "mc-a" in argv:
        config = EngineConfig(scene="mc-a", variant="PL-r", mislabel=0.3)
    elif argv[0] == "serve":
        config = EngineConfig(scene="corridor", duration_s=3.0, mode="vio", segmenter="geometric", interactive=True)
    else:
        config = EngineConfig(scene="boxes", duration_s=2.0, variant="P-w", window=5, seed=2)
    direct = make_engine(config)
    assert type(engine) is type(direct) and engine.source == direct.source and engine.settings == direct.settings
