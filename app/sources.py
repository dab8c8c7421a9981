"""What `serve` and `run` run: their shared input options (`--scene`, `--dataset`, ...) and
the engine built from them.

- `--scene NAME|FILE.json` (default `room`): a rendered scene (the standard `room`,
  `corridor`, `boxes`; the stress scenes `street`, `shake`, `slow-start`, `low-texture`,
  `exposure`), frames rendered on demand (`SyntheticSequence`), through the stereo pipeline
  (`StereoEngine`);
- `--dataset DIR`: an EuRoC ASL folder through the stereo pipeline;
- `--mode vio`: either of them through the monocular visual-inertial pipeline instead
  (`VioEngine`: the left images and `imu0`);
- `--scene mc-a|mc-b`: the paper's Monte-Carlo worlds (`SimEngine`: no images).

Bad values raise UsageError (one line, exit code 2); dataset problems raise DatasetError,
which the command line reports the same way.
"""

from __future__ import annotations

import argparse
import math
import pathlib
from typing import TYPE_CHECKING, Any

from backend.pipeline.factory import MC_SCENES, EngineConfig, make_engine

if TYPE_CHECKING:
    from backend.frontend.segmenters import SegmenterKind

MAX_DURATION_S = 3600.0  # the whole trajectory and its IMU samples are built up front


def scene_names() -> tuple[str, ...]:
    """Every name `--scene` accepts besides a scene file: rendered scenes first."""
    from backend.data.scenes import SCENE_NAMES

    return (*SCENE_NAMES, *MC_SCENES)


def default_scene() -> str:
    from backend.data.scenes import DEFAULT_SCENE

    return DEFAULT_SCENE


def load_scene_argument(text: str, *, other_names: tuple[str, ...] = ()):
    """A built-in rendered scene by name, or a scene JSON file; UsageError otherwise.
    `other_names` are further names the option accepts (named in the error message)."""
    from app.errors import UsageError
    from backend.data.scenes import SCENE_NAMES, SceneFileError, builtin_scene, load_scene

    if text in SCENE_NAMES:
        return builtin_scene(text)
    path = pathlib.Path(text)
    if not path.exists():
        names = ", ".join((*SCENE_NAMES, *other_names))
        raise UsageError(f"--scene {text}: neither a built-in scene ({names}) nor an existing scene file")
    try:
        return load_scene(path)
    except SceneFileError as e:
        raise UsageError(str(e)) from None


def add_source_arguments(p: argparse.ArgumentParser, *, duration_default: float) -> None:
    """`--scene` | `--dataset` and the options of the engines they start."""
    from app.options import name_or_path, seed

    names = scene_names()
    source = p.add_mutually_exclusive_group()
    source.add_argument(
        "--scene",
        default=None,
        metavar="NAME|FILE.json",
        type=name_or_path,
        help=f"rendered scene ({', '.join(names[: -len(MC_SCENES)])}, or a scene JSON file) through the stereo pipeline, "
        f"or a Monte-Carlo world ({', '.join(MC_SCENES)}; no images); default {default_scene()}",
    )
    source.add_argument("--dataset", default=None, metavar="PATH", type=name_or_path, help="a recorded dataset (its format recognized from its files: docs/usage.md) through the stereo pipeline")
    p.add_argument("--calib", default=None, metavar="PATH", type=name_or_path, help="with --dataset: calibration for an input without one (a ROS bag: sensor.yaml files or a Kalibr camchain.yaml)")
    p.add_argument("--topic", action="append", default=None, metavar="NAME=TOPIC", type=_topic, help="with --dataset (a ROS bag): read NAME (cam0, cam1, imu0, groundtruth) from TOPIC; repeatable")
    p.add_argument(
        "--duration", type=float, default=None, metavar="SECONDS", help=f"seconds of motion of a rendered scene (default {duration_default:g}; at its rig's frame rate: 20 Hz, street 10 Hz)"
    )
    p.add_argument("--stride", type=int, default=None, metavar="N", help="rendered scenes: keep every N-th frame (the scene's rate / N, N times the motion between frames; default 1)")
    p.add_argument("--speed", type=float, default=None, metavar="F", help="rendered scenes: move along the same path F times faster (default 1)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the scene, its noise and the RANSACs (default 0)")
    p.add_argument("--mislabel", type=float, default=None, help="mc-a / mc-b only: fraction of features with a wrong plane-instance label (default 0.1)")
    p.add_argument("--window", type=int, default=None, help="keyframes optimized per step (default 10 in stereo, 20 in VIO)")
    p.add_argument("--mode", choices=("stereo", "vio"), default="stereo", help="stereo SLAM (default) or monocular visual-inertial odometry (VIO: the left images and the IMU)")
    p.add_argument(
        "--segmenter",
        choices=("geometric", "learned", "oracle"),
        default=None,
        help="plane instances from stereo disparity (geometric, the stereo default), from the shipped network (learned, "
        "assets/planeseg.onnx, the VIO default), or on rendered scenes the renderer's exact plane ids (oracle: a reference, not a segmenter)",
    )
    p.add_argument("--segmenter-model", default=None, metavar="FILE.onnx", type=name_or_path, help="with --segmenter learned: another model file (its .json contract beside it)")
    p.set_defaults(duration_default=duration_default)


def _topic(text: str) -> tuple[str, str]:
    """`NAME=TOPIC` (argparse type for `--topic`)."""
    name, sep, topic = text.partition("=")
    if not sep or not name.strip() or not topic.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME=TOPIC, e.g. cam0=/left/image_raw")
    return name.strip(), topic.strip()


def _refuse(args: argparse.Namespace, what: str, names: tuple[str, ...]) -> None:
    from app.errors import UsageError

    for name in names:
        value = getattr(args, name.lstrip("-").replace("-", "_"), None)
        if value is not None:
            raise UsageError(f"{name} {value:g}: not used with {what}" if isinstance(value, float) else f"{name} {value}: not used with {what}")


def build_engine(args: argparse.Namespace, *, headless: bool):
    """The engine for `--scene` / `--dataset`; UsageError for bad values, DatasetError for
    a bad EuRoC folder. `headless` (`run`): the stereo pipeline skips the stages its variant
    does not use (as the paper's Table III), draws no keyframe image and no Hessian; the
    debugger gets every stage, the image and the Hessian."""
    from backend.frontend.segmenters import SegmenterError

    config = engine_config(args, headless=headless)
    try:
        return make_engine(config)  # DatasetError: one line naming the bad file
    except SegmenterError as e:
        raise segmenter_error(e, config) from None


def segmenter_error(error: Exception, config: EngineConfig) -> Exception:
    """The UsageError a SegmenterError from `make_engine(config)` is reported as."""
    from app.errors import UsageError
    from backend.frontend.segmenters import SegmenterKind

    if config.segmenter is SegmenterKind.ORACLE:
        return UsageError("--segmenter oracle: only with a rendered scene (it reads the renderer's plane ids)")
    return UsageError(str(error))


def engine_config(args: argparse.Namespace, *, headless: bool) -> EngineConfig:
    """The EngineConfig of `--scene` / `--dataset` and the engine options, checked: UsageError
    for a bad value (before anything runs). `headless`: as :func:`build_engine`."""
    from app.errors import UsageError

    if args.window is not None and args.window < 2:
        raise UsageError(f"--window {args.window}: must be at least 2")
    if getattr(args, "history", 1) < 1:
        raise UsageError(f"--history {args.history}: must be at least 1")
    history_mb = getattr(args, "history_mb", 1.0)
    if not history_mb > 0 or history_mb == float("inf"):
        raise UsageError(f"--history-mb {history_mb}: must be a positive number of MiB")
    frames = getattr(args, "frames", None)
    if frames is not None and frames < 1:
        raise UsageError(f"--frames {frames}: must be at least 1")
    scene = args.scene or default_scene()

    from backend.data.source import ReaderOptions
    from backend.data.synthetic import SequenceSettings

    for name in ("calib", "topic"):
        if args.dataset is None and getattr(args, name, None) is not None:
            raise UsageError(f"--{name}: only with --dataset")
    if args.dataset is None and scene in MC_SCENES:
        _refuse(args, f"the Monte-Carlo scene {scene} (no images)", ("--duration", "--frames", "--stride", "--speed", "--segmenter", "--segmenter-model"))
        if getattr(args, "mode", "stereo") != "stereo":
            raise UsageError(f"--mode {args.mode}: the Monte-Carlo scene {scene} has no images and no IMU")
        mislabel = 0.1 if args.mislabel is None else args.mislabel
        if not 0.0 <= mislabel <= 1.0:
            raise UsageError(f"--mislabel {args.mislabel}: must be a fraction in [0, 1]")
        return EngineConfig(scene=scene, seed=args.seed, variant=args.variant, window=args.window, mislabel=mislabel)

    options: dict[str, Any] = {}
    if args.dataset is not None:
        _refuse(args, "--dataset", ("--duration", "--mislabel", "--stride", "--speed"))
        options["dataset"] = args.dataset
        calib = getattr(args, "calib", None)
        options["reader"] = ReaderOptions(calib=None if calib is None else pathlib.Path(calib), topics=tuple(getattr(args, "topic", None) or ()))
    else:
        _refuse(args, f"the rendered scene {scene} (mc-a / mc-b only)", ("--mislabel",))
        stride = 1 if getattr(args, "stride", None) is None else args.stride
        if stride < 1:
            raise UsageError(f"--stride {stride}: must be at least 1")
        speed = 1.0 if getattr(args, "speed", None) is None else args.speed
        if not (math.isfinite(speed) and 0.0 < speed <= 10.0):
            raise UsageError(f"--speed {speed:g}: must be more than 0 and at most 10")
        duration = args.duration_default if args.duration is None else args.duration
        if not (math.isfinite(duration) and 0.0 < duration <= MAX_DURATION_S):
            raise UsageError(f"--duration {duration:g}: must be more than 0 and at most {MAX_DURATION_S:g} seconds")
        scene_obj = load_scene_argument(scene, other_names=tuple(MC_SCENES))  # UsageError for a bad name or file, before anything runs
        try:
            SequenceSettings(duration_s=duration, seed=args.seed, camera_rate_hz=scene_obj.rig.camera_rate_hz / stride, speed=speed)
        except ValueError as e:
            raise UsageError(f"--duration {duration:g}: {e}") from None
        options.update(scene=scene, duration_s=duration, stride=stride, speed=speed)
    mode = getattr(args, "mode", "stereo")
    kind = segmenter_kind_argument(args)
    return EngineConfig(
        **options,
        frames=frames,
        seed=args.seed,
        variant=args.variant,
        window=args.window,
        mode=mode,  # type: ignore[arg-type]
        segmenter=getattr(args, "segmenter", None),
        segmenter_model=kind[1],
        interactive=not headless,
    )


def segmenter_kind_argument(args: argparse.Namespace) -> tuple[SegmenterKind, pathlib.Path | None]:
    """`--segmenter` (the mode's default when absent) and `--segmenter-model`; UsageError for
    a model file with another segmenter than the learned one."""
    from app.errors import UsageError
    from backend.frontend.segmenters import SegmenterKind

    default = SegmenterKind.LEARNED if getattr(args, "mode", "stereo") == "vio" else SegmenterKind.GEOMETRIC
    kind = SegmenterKind(getattr(args, "segmenter", None) or default)
    model = getattr(args, "segmenter_model", None)
    if model is not None and kind is not SegmenterKind.LEARNED:
        raise UsageError("--segmenter-model: only with --segmenter learned")
    return kind, None if model is None else pathlib.Path(model)
