"""One way to build an engine: :class:`EngineConfig` (frozen, every choice that decides an
engine) and :func:`make_engine`. The command line, the debugger, the scripts and the
benchmarks all build engines here; the command line checks its options first and turns
them into a config.

Inputs: a built-in rendered scene or a scene file (frames rendered on demand), a dataset
read by `backend.data.source.open_dataset` (an EuRoC folder), or one of the paper's
Monte-Carlo worlds (`mc-a`, `mc-b`: no images). Modes: stereo SLAM, or monocular VIO (the
left images and the IMU). `interactive` engines (the debugger's) run every stage for every
variant and draw the keyframe image and the Hessian; the others (`run`, the tables) skip
the stages their variant does not use, as the paper's Table III.
"""

from __future__ import annotations

import dataclasses
import enum
import pathlib
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from backend.data.source import ReaderOptions
from backend.optim.variant import Variant

if TYPE_CHECKING:  # the readers, segmenters and engines are imported when an engine is made
    from backend.data.source import InertialSource
    from backend.frontend.segmenters import SegmenterKind
    from backend.pipeline.engine import Engine

MC_SCENES: dict[str, str] = {
    "mc-a": "Monte-Carlo sequence a: four walls, camera on a circle (DESIGN §4)",
    "mc-b": "Monte-Carlo sequence b: one wall, camera sliding along it",
}


class Mode(enum.StrEnum):
    STEREO = "stereo"
    VIO = "vio"


# Keyframes optimized per step where not given (StereoSettings' and VioSettings' `window`):
# VIO's keyframes come at least every 0.3 s, and a slow camera needs ~6 s of them for its
# IMU factors to hold the scale (room at speed 1: ATE 12.5 cm with 10, 1.8 cm with 20).
DEFAULT_WINDOW: dict[Mode, int] = {Mode.STEREO: 10, Mode.VIO: 20}


def default_window(mode: Mode | str) -> int:
    """The keyframes a window of `mode` optimizes unless told (`DEFAULT_WINDOW`)."""
    return DEFAULT_WINDOW[Mode(mode)]


@dataclasses.dataclass(frozen=True)
class EngineConfig:
    """What to run and how (module docstring).

    Input: `scene` (a built-in rendered scene's name, a scene file, or `mc-a` / `mc-b`;
    None: the default scene) or `dataset` (a path `open_dataset` reads). Rendered scenes:
    `duration_s` seconds of motion at the scene rig's frame rate / `stride` (20 Hz, `street`
    10 Hz), moving
    `speed` times as fast along the same path. `frames`: only the first N frames of an
    image input (None: all). `mislabel`: the Monte-Carlo worlds' fraction of features with
    a wrong plane label. `window`: keyframes optimized per step (None: the mode's,
    `DEFAULT_WINDOW`). `seed`: the scene's, its noise's and the RANSACs'. `segmenter`:
    None for the mode's default (stereo: geometric, VIO: learned); `segmenter_model`: the
    learned segmenter's model file (None: the shipped one). `reader`: what a dataset's reader
    may need besides its path (a calibration file, topic names; `ReaderOptions`).
    `preload`: every frame read (or rendered) into memory before the run, so that the run's
    times leave out reading, as from a camera (benchmarks). `read_ahead`: the next frame
    read and its keypoints detected while the current one is tracked (the outputs are the
    same either way; off: one thread, for comparing)."""

    scene: str | None = None
    dataset: pathlib.Path | str | None = None
    duration_s: float = 30.0
    stride: int = 1
    speed: float = 1.0
    frames: int | None = None
    mislabel: float = 0.1
    seed: int = 0
    variant: Variant = Variant.PL_W
    window: int | None = None
    mode: Mode = Mode.STEREO
    segmenter: SegmenterKind | None = None
    segmenter_model: pathlib.Path | None = None
    reader: ReaderOptions = ReaderOptions()
    interactive: bool = False
    preload: bool = False
    read_ahead: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "variant", Variant.parse(self.variant))
        object.__setattr__(self, "mode", Mode(self.mode))
        if self.segmenter is not None:
            from backend.frontend.segmenters import SegmenterKind

            object.__setattr__(self, "segmenter", SegmenterKind(self.segmenter))
        if self.scene is not None and self.dataset is not None:
            raise ValueError("a scene or a dataset, not both")

    @property
    def is_monte_carlo(self) -> bool:
        return self.dataset is None and self.scene in MC_SCENES


class FirstFrames:
    """The first `count` frames of an image source (everything else delegated to it)."""

    def __init__(self, source: object, count: int) -> None:
        self._source = source
        self._count = min(int(count), len(source))  # type: ignore[arg-type]

    def __len__(self) -> int:
        return self._count

    def __getattr__(self, name: str) -> object:
        return getattr(self._source, name)


class Preloaded:
    """An image source with every rectified pair read into memory at construction
    (everything else delegated to it): a run's times without reading or rendering."""

    def __init__(self, source: object) -> None:
        self._source = source
        self._pairs = [source.rectified_pair(i) for i in range(len(source))]  # type: ignore[attr-defined, arg-type]

    def __len__(self) -> int:
        return len(self._pairs)

    def rectified_pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        return self._pairs[index]

    def __getattr__(self, name: str) -> object:
        return getattr(self._source, name)


def make_engine(config: EngineConfig) -> Engine:
    """The engine `config` describes (ValueError for a combination that cannot run;
    backend.data.errors.DatasetError for a bad dataset, one line; SegmenterError)."""
    from backend.frontend.segmenters import SegmenterKind, make_segmenter

    if config.is_monte_carlo:
        from backend.pipeline.sim_engine import SimEngine, SimSettings

        if config.mode is not Mode.STEREO:
            raise ValueError(f"the Monte-Carlo scene {config.scene} has no images and no IMU")
        return SimEngine(SimSettings(sequence=str(config.scene)[-1], seed=config.seed, variant=config.variant, window=config.window or default_window(Mode.STEREO), mislabel=config.mislabel))
    source, name = _open_images(config)
    if config.frames is not None:
        source = FirstFrames(source, config.frames)
    if config.preload:
        source = Preloaded(source)
    segmenter = make_segmenter(_segmenter_kind(config), source=source, model=config.segmenter_model)
    if config.mode is Mode.VIO:
        from backend.pipeline.vio_engine import VioEngine, VioSettings

        vio_settings = VioSettings(variant=config.variant, window=config.window or default_window(Mode.VIO), seed=config.seed, **_stage_options(config))
        inertial = cast("InertialSource", source)  # asked for its IMU at once: without one, a DatasetError (one line)
        if config.dataset is not None:  # a recorded IMU: its units (rendered ones are the simulator's)
            from backend.data.plausibility import check_imu

            imu = inertial.imu
            check_imu(imu.timestamp_ns, imu.gyro, imu.accel, where=inertial.imu_label)
        return VioEngine(inertial, settings=vio_settings, name=f"{name}, VIO, {_segmenter_kind(config)} segmenter", segmenter=segmenter)
    from backend.pipeline.stereo_engine import StereoEngine, StereoSettings

    if config.segmenter in (SegmenterKind.LEARNED, SegmenterKind.ORACLE):
        name = f"{name}, {config.segmenter} segmenter"
    settings = StereoSettings(variant=config.variant, window=config.window or default_window(Mode.STEREO), seed=config.seed, **_stage_options(config))
    return StereoEngine(source, settings=settings, name=name, segmenter=segmenter)  # type: ignore[arg-type]


def _segmenter_kind(config: EngineConfig) -> SegmenterKind:
    from backend.frontend.segmenters import SegmenterKind

    if config.segmenter is not None:
        return config.segmenter
    return SegmenterKind.LEARNED if config.mode is Mode.VIO else SegmenterKind.GEOMETRIC


def _stage_options(config: EngineConfig) -> dict[str, Any]:
    if config.interactive:
        return {"skip_unused_stages": False, "hessian": True, "image_scale": 1.0, "read_ahead": config.read_ahead}
    return {"skip_unused_stages": True, "image_scale": None, "hessian": False, "read_ahead": config.read_ahead}


def _open_images(config: EngineConfig) -> tuple[object, str]:
    """The image source and its name as the debugger and the reports show it."""
    if config.dataset is not None:
        from backend.data.source import dataset_format, open_dataset

        fmt = dataset_format(config.dataset)
        return open_dataset(config.dataset, config.reader), f"{fmt.label} {config.dataset}"  # read and checked (plausibility)
    from backend.data.scenes import DEFAULT_SCENE, SCENE_NAMES, builtin_scene, load_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    scene = config.scene or DEFAULT_SCENE
    scene_obj = builtin_scene(scene) if scene in SCENE_NAMES else load_scene(pathlib.Path(scene))
    settings = SequenceSettings(duration_s=config.duration_s, seed=config.seed, camera_rate_hz=scene_obj.rig.camera_rate_hz / config.stride, speed=config.speed)
    label = scene if scene == scene_obj.name else f"{scene_obj.name} from {scene}"
    every = f", every {config.stride}th frame" if config.stride > 1 else ""
    faster = f", {config.speed:g}× speed" if config.speed != 1.0 else ""
    return SyntheticSequence(scene_obj, settings=settings), f"rendered scene {label} ({config.duration_s:g} s, seed {config.seed}{every}{faster})"
