"""`coplanar render`: a synthetic stereo + IMU sequence as an EuRoC ASL folder (DESIGN §7).

The sequence is rendered into a hidden staging folder inside `--out` and its `mav0` folder
moved into place when complete: a full disk or Ctrl-C leaves no partial `mav0` behind."""

from __future__ import annotations

import argparse
import pathlib
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import bounded_float, name_or_path, path, seed
    from app.sources import MAX_DURATION_S
    from backend.data.scenes import DEFAULT_SCENE, SCENE_NAMES

    p = sub.add_parser("render", help="render a synthetic scene to an EuRoC ASL folder (stereo, IMU, ground truth)")
    p.add_argument("--scene", default=DEFAULT_SCENE, type=name_or_path, help=f"built-in scene ({', '.join(SCENE_NAMES)}; default {DEFAULT_SCENE}) or a scene JSON file")
    p.add_argument("--out", required=True, type=path, help="output folder (created; must not hold a mav0 folder already)")
    p.add_argument("--duration", type=bounded_float(low=0.0, high=MAX_DURATION_S, low_open=True, unit=" seconds"), default=30.0, help="seconds of motion (default 30; 20 Hz stereo, 200 Hz IMU)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the trajectory and the noise (default 0)")
    p.add_argument("--image-noise", type=bounded_float(low=0.0, high=255.0, unit=" grey levels"), default=0.0, help="Gaussian image noise, grey levels (default 0)")
    p.add_argument("--blur", type=bounded_float(low=0.0, high=50.0, unit=" pixels"), default=0.0, help="Gaussian blur, pixels (default 0, at most 50)")
    p.add_argument("--exposure", type=bounded_float(low=0.0, high=0.99), default=0.0, help="relative exposure change, e.g. 0.2 for ±20%% (default 0)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from app.errors import UsageError
    from app.sources import load_scene_argument
    from backend.data.synthetic import SequenceSettings, render_sequence

    scene = load_scene_argument(args.scene)
    try:
        settings = SequenceSettings(duration_s=args.duration, seed=args.seed, image_noise=args.image_noise, blur_px=args.blur, exposure=args.exposure)
    except ValueError as e:
        raise UsageError(str(e)) from None
    from backend.common.atomic import make_folder

    out: pathlib.Path = args.out
    created = False
    try:
        created = not out.exists()
        if not created and not out.is_dir():
            raise UsageError(f"--out {out}: exists and is not a folder")
        if (out / "mav0").exists():
            raise UsageError(f"--out {out}: already holds a mav0 folder; choose a new folder")
        make_folder(out)
    except OSError as e:
        raise UsageError(f"--out {out}: cannot create it: {e.strerror or e}") from None
    from backend.common.atomic import InterruptedAfterCommit, staged_folder

    stage = None
    try:
        with staged_folder(out) as stage, tqdm(total=None, desc=f"render {scene.name}", unit="pair", file=sys.stderr, disable=None) as bar:

            def on_frame(done: int, total: int) -> None:
                bar.total = total
                bar.update(1)

            n = render_sequence(scene, stage, settings=settings, on_frame=on_frame)
    except OSError as e:
        where = "the sequence"
        if e.filename and stage is not None and str(e.filename).startswith(str(stage)):
            where = str(pathlib.Path(e.filename).relative_to(stage))
        raise UsageError(f"--out {out}: cannot write {where}: {e.strerror or e}; no mav0 folder was left there") from None
    except InterruptedAfterCommit:
        raise
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"no mav0 folder was left in {out}") from None
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed render leaves no empty folder it made
    print(f"rendered {n} stereo pairs of {scene.name} ({args.duration:g} s) into {out}; read it back with --dataset {out}")
    return 0
