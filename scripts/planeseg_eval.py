"""Evaluate the learned plane-instance segmenter (assets/planeseg.onnx).

    .venv/bin/python scripts/planeseg_eval.py [--layouts 25] [--views 8] [--gallery docs/segmentation]

1. Held-out rendered frames: random room layouts from seed 0 (training uses seeds from
   1000 on) and frames of the built-in scenes (room, corridor, boxes; never trained on),
   against their exact plane ids: planar-mask IoU, matched-instance recall (ground-truth
   instances covering at least 1 % of the image matched by a predicted instance at IoU
   >= 0.5), adjusted Rand index over the pixels planar in both, instances per frame.
2. The four real V1_01 pairs (never trained on): the same figures against the geometric
   (stereo) segmenter's instances, and a PNG gallery beside the geometric one.
Writes the gallery (docs/segmentation/euroc_pair_{i}_learned.png), docs/pipeline/planeseg_eval.json
and the planeseg-eval block of README.md.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "training"))
sys.path.insert(0, str(ROOT / "scripts"))

import numpy as np  # noqa: E402

from backend.frontend.segmentation_learned import LearnedSegmenter  # noqa: E402

MIN_SHARE = 0.01


def instance_figures(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Planar IoU, matched-instance recall at IoU 0.5 and ARI of two label images (>= 0:
    instance, < 0: none) of the same size."""
    p, t = pred >= 0, truth >= 0
    union = np.count_nonzero(p | t)
    iou = np.count_nonzero(p & t) / union if union else 1.0
    ids, counts = np.unique(truth[t], return_counts=True)
    big = ids[counts >= MIN_SHARE * truth.size]
    matched = 0
    for i in big:
        g = truth == i
        cand, overlap = np.unique(pred[g & p], return_counts=True)
        best = 0.0
        for c, o in zip(cand, overlap):
            best = max(best, o / np.count_nonzero(g | (pred == c)))
        matched += best >= 0.5
    both = p & t
    return {"planar_iou": float(iou), "recall": float(matched / len(big)) if len(big) else float("nan"), "instances": int(len(big)),
            "matched": int(matched), "ari": adjusted_rand(pred[both], truth[both]), "predicted": int(len(np.unique(pred[p])))}


def adjusted_rand(a: np.ndarray, b: np.ndarray) -> float:
    """Adjusted Rand index of two labelings of the same items (Hubert and Arabie)."""
    if len(a) < 2:
        return float("nan")
    _, ai = np.unique(a, return_inverse=True)
    _, bi = np.unique(b, return_inverse=True)
    table = np.zeros((ai.max() + 1, bi.max() + 1), np.int64)
    np.add.at(table, (ai, bi), 1)
    comb = lambda x: (x * (x - 1) / 2.0).sum()  # noqa: E731
    s_ij, s_a, s_b = comb(table.astype(float)), comb(table.sum(1).astype(float)), comb(table.sum(0).astype(float))
    expected = s_a * s_b / comb(np.array([float(len(a))]))
    top = 0.5 * (s_a + s_b) - expected
    return float((s_ij - expected) / top) if top else 1.0


def rendered_frames(args: argparse.Namespace):  # noqa: ANN201
    """(name, left image, full-size truth labels) of the held-out rendered frames."""
    from planeseg_data import random_pose, random_room

    from backend.data.render import NON_PLANAR_ID, render_view
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import CAMERA, SequenceSettings, SyntheticSequence

    rng = np.random.default_rng([0, 0x5E6])
    for k in range(args.layouts):
        scene = random_room(rng, f"held-out-{k}")
        for _ in range(args.views):
            R, t = random_pose(rng, scene)
            view = render_view(scene, CAMERA, R, t, gain=float(rng.uniform(0.55, 1.45)), blur_sigma_px=float(rng.uniform(0, 1.5)), noise_sigma=float(rng.uniform(0, 6)), rng=rng)
            yield "random rooms", view.image, np.where(view.plane_id == NON_PLANAR_ID, -1, view.plane_id)
    for name in ("room", "corridor", "boxes"):
        seq = SyntheticSequence(builtin_scene(name), settings=SequenceSettings(duration_s=30.0, image_noise=2.0))
        for i in range(0, len(seq), len(seq) // 20):
            view = seq.views(i)[0]
            yield name, view.image, np.where(view.plane_id == NON_PLANAR_ID, -1, view.plane_id)


def summarize(rows: list[dict]) -> dict[str, float]:
    keys = ("planar_iou", "recall", "ari")
    out = {k: float(np.nanmean([r[k] for r in rows])) for k in keys}
    out["recall_pooled"] = float(sum(r["matched"] for r in rows) / max(sum(r["instances"] for r in rows), 1))
    out["frames"] = len(rows)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", type=int, default=25)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--gallery", type=pathlib.Path, default=ROOT / "docs" / "segmentation")
    parser.add_argument("--no-readme", action="store_true", help="print the table, leave README.md alone")
    args = parser.parse_args()
    seg = LearnedSegmenter()
    results: dict[str, dict] = {}
    by_set: dict[str, list[dict]] = {}
    for name, image, truth in rendered_frames(args):
        labels = seg.segment(image, image, None).labels  # type: ignore[arg-type]
        by_set.setdefault(name, []).append(instance_figures(labels, truth))
    for name, rows in by_set.items():
        results[name] = summarize(rows)
    results["all rendered"] = summarize([r for rows in by_set.values() for r in rows])
    from euroc_table import publish
    from segmentation_gallery import PAIRS, overlay, real_pairs

    if PAIRS.is_dir():
        import cv2

        from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

        geo = GeometricPlaneSegmenter()
        rows = []
        args.gallery.mkdir(parents=True, exist_ok=True)
        for i, left, right, camera, _ in real_pairs():
            ref = geo.segment(left, right, camera).labels
            masks = seg.segment(left, right, camera)
            rows.append(instance_figures(masks.labels, ref))
            cv2.imwrite(str(args.gallery / f"euroc_pair_{i}_learned.png"), cv2.cvtColor(overlay(left, masks), cv2.COLOR_RGB2BGR))
        results["V1_01 pairs vs geometric"] = summarize(rows)
    lines = [
        "`.venv/bin/python scripts/planeseg_eval.py`: planar-mask IoU, matched-instance recall (instances covering ≥ 1 % of the "
        "image matched by a predicted instance at IoU ≥ 0.5; mean per frame, and pooled over all instances), adjusted Rand index "
        "over the pixels planar in both. Rendered frames against their exact plane ids (random layouts from seed 0, never "
        "trained on; 21 frames of each built-in scene, with 2 grey levels of noise); the real V1_01 pairs against the geometric "
        "segmenter's instances (not a ground truth: it splits and merges planes its own way).",
        "",
        "| frames | n | planar IoU | recall@0.5 | pooled recall | ARI |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines.append(f"| {name} | {r['frames']} | {r['planar_iou']:.3f} | {r['recall']:.3f} | {r['recall_pooled']:.3f} | {r['ari']:.3f} |")
    results["model_sha256"] = seg.contract.get("sha256")
    return publish(results, "\n".join(lines), json_name="planeseg_eval.json", block="planeseg-eval", readme=not args.no_readme)


if __name__ == "__main__":
    sys.exit(main())
