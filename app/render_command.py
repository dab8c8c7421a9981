"""`coplanar render`: a synthetic stereo + IMU sequence as a dataset (DESIGN §7): an EuRoC
ASL folder by default, or another format (`--format`, backend.data.writers), converted from
the rendered EuRoC folder.

The output is written into a hidden staging folder inside `--out` and moved into place when
complete: a full disk or Ctrl-C leaves no partial output behind."""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile


def add_parser(sub: argparse._SubParsersAction) -> None:
    from app.options import bounded_float, name_or_path, path, seed
    from app.sources import MAX_DURATION_S
    from backend.data.scenes import DEFAULT_SCENE, SCENE_NAMES
    from backend.data.writers import DATASET_WRITERS

    p = sub.add_parser("render", help="render a synthetic scene to a dataset (stereo, IMU, ground truth; an EuRoC ASL folder by default)")
    p.add_argument("--scene", default=DEFAULT_SCENE, type=name_or_path, help=f"built-in scene ({', '.join(SCENE_NAMES)}; default {DEFAULT_SCENE}) or a scene JSON file")
    p.add_argument("--out", required=True, type=path, help="output folder (created; must not hold the format's files already)")
    formats = ", ".join(f"{w.name}: {w.description}" for w in DATASET_WRITERS)
    p.add_argument("--format", default="euroc", choices=[w.name for w in DATASET_WRITERS], help=f"what to write ({formats}; default euroc)")
    p.add_argument(
        "--duration",
        type=bounded_float(low=0.0, high=MAX_DURATION_S, low_open=True, unit=" seconds"),
        default=30.0,
        help="seconds of motion (default 30; at the scene rig's rates: 20 Hz stereo (street: 10 Hz), 200 Hz IMU)",
    )
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
    from backend.data.writers import dataset_writer

    scene = load_scene_argument(args.scene)
    try:
        settings = SequenceSettings(duration_s=args.duration, seed=args.seed, image_noise=args.image_noise, blur_px=args.blur, exposure=args.exposure)
    except ValueError as e:
        raise UsageError(str(e)) from None
    from backend.common.atomic import make_folder

    writer = dataset_writer(args.format)
    out: pathlib.Path = args.out
    written = " or ".join(writer.entries)
    created = False
    try:
        created = not out.exists()
        if not created and not out.is_dir():
            raise UsageError(f"--out {out}: exists and is not a folder")
        for entry in writer.entries:
            if (out / entry).exists():
                raise UsageError(f"--out {out}: already holds {entry}; choose a new folder")
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

            if writer.convert is None:
                n = render_sequence(scene, stage, settings=settings, on_frame=on_frame)
            else:
                with tempfile.TemporaryDirectory(dir=out, prefix=".render-") as rendered:  # hidden, removed after
                    n = render_sequence(scene, rendered, settings=settings, on_frame=on_frame)
                    writer.convert(pathlib.Path(rendered), stage)
    except OSError as e:
        where = "the sequence"
        if e.filename and stage is not None and str(e.filename).startswith(str(stage)):
            where = str(pathlib.Path(e.filename).relative_to(stage))
        raise UsageError(f"--out {out}: cannot write {where}: {e.strerror or e}; no {written} was left there") from None
    except InterruptedAfterCommit:
        raise
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"no {written} was left in {out}") from None
    finally:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # a failed render leaves no empty folder it made
    print(f"rendered {n} stereo pairs of {scene.name} ({args.duration:g} s) into {out} ({writer.description}); read it back with {writer.read_back.format(out=out)}")
    return 0
