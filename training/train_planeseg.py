"""Train the plane-instance segmenter and export it as ONNX with its contract (JSON).

    .venv/bin/pip install -e .[train]      # PyTorch (CPU), onnx and scikit-image: training only
    .venv/bin/python training/train_planeseg.py                 # writes assets/planeseg.onnx and .json

The same seed gives the same weights on the same machine and library versions (data,
initialization, shuffling and augmentation are all drawn from it; PyTorch runs with
deterministic algorithms). Rendered layouts use seeds 1000 + k for training; the
evaluation (scripts/planeseg_eval.py) renders layouts from seed 0, never trained on.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "training"))

import numpy as np
import planeseg_data
from photometric import Photometric, augment
from planeseg_data import INPUT_H, INPUT_W, OUTPUT_H, OUTPUT_W, Sample, real_samples, rendered_samples

TRAIN_SEED_BASE = 1000
DEFAULT_REAL = ROOT.parent / "shared" / "data" / "euroc_mh01_slice"  # the shipped model's; ../shared/data/euroc_mh01_vio holds its 300 frames and 100 more


def build_data(args: argparse.Namespace) -> list[Sample]:
    t0 = time.perf_counter()
    samples: list[Sample] = []
    for chunk in range(args.layouts // 25):
        samples += rendered_samples(TRAIN_SEED_BASE + args.seed * 100 + chunk, layouts=25, views_per_layout=args.views, leaning=args.leaning, photos=args.photos)
        print(f"  rendered {len(samples)} samples ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.real is not None and args.real.is_dir():
        real = real_samples(args.real, every=args.real_every)
        samples += real * args.real_repeat
        print(f"  {len(real)} real pseudo-labelled frames of {args.real.name} (each used {args.real_repeat}×) ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.v101_pairs:
        pairs = planeseg_data.v101_pair_samples(args.v101_pairs)
        samples += pairs * args.pairs_repeat
        print(f"  V1_01 test pairs {args.v101_pairs} pseudo-labelled, each used {args.pairs_repeat}× (held-out check only)", flush=True)
    return samples


def export(model, path: pathlib.Path, *, meta: dict) -> None:
    import torch

    model.eval()
    dummy = torch.zeros(1, 1, INPUT_H, INPUT_W)
    with_normals = model.normal_head is not None
    outputs = ["planar_logit", "embedding"] + (["normal"] if with_normals else [])
    torch.onnx.export(model, (dummy,), str(path), input_names=["image"], output_names=outputs, opset_version=17, dynamo=False, do_constant_folding=True)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    contract = {
        "format": "coplanar plane-instance segmenter",
        "version": 1,
        "input": {
            "name": "image",
            "shape": [1, 1, INPUT_H, INPUT_W],
            "dtype": "float32",
            "range": [0.0, 1.0],
            "preprocess": ("CLAHE, then " if meta.get("clahe") else "") + "grey image resized to the input size with area averaging, divided by 255",
            **({"clahe": meta["clahe"]} if meta.get("clahe") else {}),
        },
        "outputs": {
            "planar_logit": {"shape": [1, 1, OUTPUT_H, OUTPUT_W], "meaning": "logit of 'this pixel lies on a plane'"},
            "embedding": {"shape": [1, meta["embed_dim"], OUTPUT_H, OUTPUT_W], "meaning": "per-pixel embedding, instances by mean shift"},
            **(
                {"normal": {"shape": [1, 3, OUTPUT_H, OUTPUT_W], "meaning": "surface normal, left camera frame (x right, y down, z forward), towards the camera, not normalized"}}
                if with_normals
                else {}
            ),
        },
        "clustering": {"bandwidth": meta["delta_v"] * 2.0, "delta_v": meta["delta_v"], "delta_d": meta["delta_d"], **({"normal_weight": meta["cluster_normal_weight"]} if with_normals else {})},
        "sha256": digest,
        "training": meta,
    }
    path.with_suffix(".json").write_text(json.dumps(contract, indent=2) + "\n")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--layouts", type=int, default=300, help="random rooms rendered (multiple of 25)")
    p.add_argument("--views", type=int, default=8, help="views per room")
    p.add_argument("--real", type=pathlib.Path, default=DEFAULT_REAL, help="EuRoC folder for pseudo-labels (skipped if absent)")
    p.add_argument(
        "--leaning",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="rooms with panels leaning against the walls (see planeseg_data.random_room); tried once with --gamma 0.4, worse on held-out and real frames (README), so off by default",
    )
    p.add_argument("--gamma", type=float, default=0.0, help="an older gamma jitter after the brightness / contrast one: gamma drawn from exp(±gamma)")
    p.add_argument(
        "--photos",
        type=float,
        default=0.0,
        help="share of the rendered surfaces and decals wearing real photographs (training/real_textures.py); 0: procedural textures only (tried at 0.5, fine-tuning, not shipped: CHANGELOG)",
    )
    p.add_argument(
        "--photometric",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="photometric augmentation of every batch: gamma, blur, noise, vignetting, an illumination ramp (training/photometric.py, its default strengths; tried, not shipped: CHANGELOG)",
    )
    p.add_argument(
        "--clahe", action=argparse.BooleanOptionalAction, default=False, help="input preparation: CLAHE (clip 2, 8x8 tiles) before the area average, in training and (through the contract) at run time"
    )
    p.add_argument("--normals", action=argparse.BooleanOptionalAction, default=False, help="a third head predicting the surface normal (camera frame), trained with 1 - cos")
    p.add_argument("--normal-weight", type=float, default=1.0, help="weight of the normal loss")
    p.add_argument("--cluster-normal-weight", type=float, default=1.0, help="written into the contract: unit normals scaled by this join the embedding in mean shift")
    p.add_argument(
        "--v101-pairs",
        type=lambda v: [int(x) for x in v.split(",")],
        default=[],
        help="held-out check only, never for the shipped model: also train on these V1_01 test pairs (e.g. 0,1), pseudo-labelled by the geometric segmenter, and evaluate on the others",
    )
    p.add_argument("--pairs-repeat", type=int, default=25, help="copies of each --v101-pairs image in the training set")
    p.add_argument("--real-every", type=int, default=1)
    p.add_argument("--real-repeat", type=int, default=2)
    p.add_argument(
        "--init",
        type=pathlib.Path,
        default=None,
        help="start from this exported model (.onnx of the same width and heads, training/warm_start.py) instead of random weights: fine-tuning",
    )
    p.add_argument("--epochs", type=int, default=24)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--width", type=int, default=16, help="channels of the first encoder block")
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--out", type=pathlib.Path, default=ROOT / "assets" / "planeseg.onnx")
    args = p.parse_args()
    planeseg_data.CLAHE = {"clip_limit": 2.0, "tiles": 8} if args.clahe else None

    import torch
    from planeseg_model import DELTA_D, DELTA_V, EMBED_DIM, PlaneNet, loss

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    torch.use_deterministic_algorithms(True, warn_only=True)
    rng = np.random.default_rng([args.seed, 0x7A1])
    t_start = time.perf_counter()
    print(f"building data (seed {args.seed})", flush=True)
    samples = build_data(args)
    images = np.stack([s.image for s in samples])
    labels = np.stack([s.labels for s in samples]).astype(np.int64)
    normals = np.stack([s.normals for s in samples]) if args.normals else None
    t_data = time.perf_counter() - t_start
    print(f"{len(samples)} samples in {t_data:.0f} s; training on {args.device} with {args.threads} threads", flush=True)

    photometric = Photometric() if args.photometric else None
    device = torch.device(args.device)
    model = PlaneNet(width=args.width, normals=args.normals).to(device)
    init_sha256 = None
    if args.init is not None:
        from warm_start import warm_start

        calibration = images[:: max(1, len(images) // 64)][:64].astype(np.float32)[:, None] / 255.0
        warm_start(model, args.init, calibration)
        init_sha256 = hashlib.sha256(args.init.read_bytes()).hexdigest()
        print(f"started from {args.init} (sha256 {init_sha256[:12]})", flush=True)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    steps = args.epochs * (len(samples) // args.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=args.lr, total_steps=steps, pct_start=0.15)
    t_train = time.perf_counter()
    for epoch in range(args.epochs):
        model.train()
        order = rng.permutation(len(samples))
        sums = {"bce": 0.0, "disc": 0.0, **({"normal": 0.0} if args.normals else {})}
        n = 0
        for start in range(0, len(order) - args.batch + 1, args.batch):
            idx = order[start : start + args.batch]
            x = images[idx].astype(np.float32) / 255.0
            y = labels[idx].copy()
            flip = rng.random(len(idx)) < 0.5
            x[flip], y[flip] = x[flip, :, ::-1], y[flip, :, ::-1]
            if normals is not None:
                nrm = normals[idx].astype(np.float32)
                nrm[flip] = nrm[flip, :, :, ::-1]
                nrm[flip, 0] *= -1.0  # a mirrored image mirrors the camera x axis
            gain = rng.uniform(0.75, 1.25, (len(idx), 1, 1)).astype(np.float32)
            bias = rng.uniform(-0.1, 0.1, (len(idx), 1, 1)).astype(np.float32)
            x = np.clip(x * gain + bias, 0.0, 1.0)
            if args.gamma > 0:
                x = x ** np.exp(rng.uniform(-args.gamma, args.gamma, (len(idx), 1, 1))).astype(np.float32)
            if photometric is not None:
                x = augment(x, rng, photometric)
            xt = torch.from_numpy(np.ascontiguousarray(x[:, None])).to(device)
            yt = torch.from_numpy(np.ascontiguousarray(y)).to(device)
            if normals is None:
                logit, emb = model(xt)
                total, parts = loss(logit, emb, yt)
            else:
                logit, emb, nrm_pred = model(xt)
                total, parts = loss(logit, emb, yt, nrm_pred, torch.from_numpy(np.ascontiguousarray(nrm)).to(device), normal_weight=args.normal_weight)
            opt.zero_grad()
            total.backward()
            opt.step()
            sched.step()
            for k in sums:
                sums[k] += parts[k]
            n += 1
        figures = " ".join(f"{k} {v / n:.4f}" for k, v in sums.items())
        print(f"epoch {epoch + 1}/{args.epochs}: {figures} ({time.perf_counter() - t_train:.0f} s)", flush=True)
    t_train = time.perf_counter() - t_train
    model = model.cpu()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "command": "python training/train_planeseg.py " + " ".join(sys.argv[1:]),
        "seed": args.seed,
        "layouts": args.layouts,
        **({"v101_pairs": args.v101_pairs, "pairs_repeat": args.pairs_repeat} if args.v101_pairs else {}),
        "leaning": args.leaning,
        "gamma": args.gamma,
        "photos": args.photos,
        "photometric": dataclasses.asdict(photometric) if photometric else None,
        "clahe": planeseg_data.CLAHE,
        "views": args.views,
        "real": args.real.name if args.real and args.real.is_dir() else None,
        "samples": len(samples),
        "init_sha256": init_sha256,
        "epochs": args.epochs,
        "batch": args.batch,
        "lr": args.lr,
        "width": args.width,
        "normals": args.normals,
        "normal_weight": args.normal_weight,
        "cluster_normal_weight": args.cluster_normal_weight,
        "embed_dim": EMBED_DIM,
        "delta_v": DELTA_V,
        "delta_d": DELTA_D,
        "device": args.device,
        "threads": args.threads,
        "data_s": round(t_data, 1),
        "train_s": round(t_train, 1),
        "torch": torch.__version__,
    }
    export(model, args.out, meta=meta)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB) and {args.out.with_suffix('.json').name}; data {t_data:.0f} s, training {t_train:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
