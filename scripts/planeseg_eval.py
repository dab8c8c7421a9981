"""Evaluate the learned plane-instance segmenter (assets/planeseg.onnx).

    .venv/bin/python scripts/planeseg_eval.py [--layouts 25] [--views 8] [--gallery docs/segmentation]
    .venv/bin/python scripts/planeseg_eval.py --validation --model M.onnx --normal-weight W --no-doc   # choosing a setting

`--validation` renders other random layouts (seed 1) and skips the real pairs: settings
are chosen there, never on the held-out frames or the real pairs reported in
docs/results/segmenter.md. `--photos P` (with `--validation`) dresses that share of their
surfaces in real photographs (training/real_textures.py; needs scikit-image).

1. Held-out rendered frames: random room layouts from seed 0 (training uses seeds from
   1000 on) and frames of the built-in scenes (room, corridor, boxes; never trained on),
   against their exact plane ids: planar-mask IoU, matched-instance recall (ground-truth
   instances covering at least 1 % of the image matched by a predicted instance at IoU
   >= 0.5), adjusted Rand index over the pixels planar in both, instances per frame; for
   models with a normal output, the median angle between predicted and true normals
   over the planar pixels (random rooms; the real pairs against the geometric segmenter's
   fitted planes).
2. The four real V1_01 pairs (never trained on): the same figures against the geometric
   (stereo) segmenter's instances, and a PNG gallery beside the geometric one; and whether
   the floor and the main walls (other instances >= 10 % of the image) of the geometric
   segmenter are found (`planes_found`):
   covered at least half by learned instances that lie mostly (>= 70 %) on them, in one
   piece or several (pieces of one plane are harmless downstream: the co-planar filter
   merges planes that agree).
Writes the gallery (docs/segmentation/euroc_pair_{i}_learned.png), docs/pipeline/planeseg_eval.json
and the planeseg-eval block of docs/results/segmenter.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "training"))
sys.path.insert(0, str(ROOT / "scripts"))

import numpy as np

from backend.frontend.segmentation_learned import LearnedSegmenter, LearnedSegmenterSettings

MIN_SHARE = 0.01
WALL_SHARE = 0.10


def planes_found(R_world_camera: np.ndarray, reference, learned) -> list[dict]:
    """The floor (every reference instance whose normal is within 5° of the vertical and
    below the camera, together: the geometric segmenter itself may split it) and each main
    wall (any other reference instance covering >= 10 % of the image: the padded walls of
    the V1_01 room lean, 60-80° from the horizontal) of the
    geometric segmenter's `reference` masks: its kind, image share, the share of its pixels
    covered by learned instances lying mostly on it (>= 70 % of their pixels that the
    reference labels), how many such
    pieces hold >= 5 % of it, and whether they cover at least half of it."""
    up_camera = R_world_camera.T @ np.array([0.0, 0.0, 1.0])
    shares = reference.fractions()
    groups: list[tuple[str, np.ndarray]] = []
    floor = np.zeros(reference.labels.shape, bool)
    for r in range(reference.count):
        n_ref, d_ref = reference.normals_camera[r], reference.offsets_camera[r]
        cos_up = float(n_ref @ up_camera)  # d > 0: the normal points at the camera, up for a floor below it
        tilt = np.degrees(np.arccos(min(1.0, abs(cos_up))))
        if tilt < 5.0 and cos_up * d_ref > 0:
            floor |= reference.mask(r)
        elif shares[r] >= WALL_SHARE:
            groups.append(("wall", reference.mask(r)))
    if floor.any():
        groups.insert(0, ("floor", floor))
    rows = []
    labelled = (learned.labels >= 0) & (reference.labels >= 0)  # where the reference says nothing it is no evidence
    counts = np.bincount(learned.labels[labelled].ravel(), minlength=learned.count)
    for kind, mask in groups:
        inside = np.bincount(learned.labels[mask & (learned.labels >= 0)].ravel(), minlength=learned.count)
        on_it = np.flatnonzero((inside >= 0.7 * np.maximum(counts, 1)) & (inside > 0))
        covered = float(inside[on_it].sum() / mask.sum())
        pieces = int(np.sum(inside[on_it] >= 0.05 * mask.sum()))
        rows.append({"kind": kind, "share": float(mask.mean()), "covered": covered, "pieces": pieces, "found": covered >= 0.5})
    return rows


def reference_normals(reference) -> np.ndarray:
    """(3, h, w) unit normals at the network's output size of the geometric segmenter's
    instances (`PlaneMasks` with fitted planes), turned towards the camera; zero elsewhere."""
    from planeseg_data import normal_image, to_output_labels

    small = to_output_labels(reference.labels)
    normals = {q: (n if d > 0 else -n) for q, (n, d) in enumerate(zip(reference.normals_camera, reference.offsets_camera))}
    return normal_image(small, normals)


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
    return {
        "planar_iou": float(iou),
        "recall": float(matched / len(big)) if len(big) else float("nan"),
        "instances": int(len(big)),
        "matched": int(matched),
        "ari": adjusted_rand(pred[both], truth[both]),
        "predicted": int(len(np.unique(pred[p]))),
    }


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


def normal_error_deg(predicted: np.ndarray | None, truth: np.ndarray) -> float:
    """Median angle (°) between predicted unit normals (h, w, 3) and true ones (3, h, w)
    where the truth is known (non-zero); nan without a prediction or truth."""
    known = np.linalg.norm(truth.astype(np.float64), axis=0) > 0.5
    if predicted is None or not known.any():
        return float("nan")
    cos = np.einsum("hwc,chw->hw", predicted.astype(np.float64), truth.astype(np.float64))[known]
    return float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))


def rendered_frames(args: argparse.Namespace):
    """(name, left image, full-size truth labels, output-size true normals or None) of the
    held-out (or, with `--validation`, the validation) rendered frames."""
    from planeseg_data import camera_normals, normal_image, random_pose, random_room, to_output_labels

    from backend.data.render import NON_PLANAR_ID, render_view
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import CAMERA, SequenceSettings, SyntheticSequence

    photos = args.photos if args.validation else 0.0
    if photos > 0:
        from real_textures import register_photo_textures

        register_photo_textures()
    rng = np.random.default_rng([1 if args.validation else 0, 0x5E6])
    for k in range(args.layouts):
        scene = random_room(rng, f"held-out-{k}", photos=photos)
        for _ in range(args.views):
            R, t = random_pose(rng, scene)
            view = render_view(scene, CAMERA, R, t, gain=float(rng.uniform(0.55, 1.45)), blur_sigma_px=float(rng.uniform(0, 1.5)), noise_sigma=float(rng.uniform(0, 6)), rng=rng)
            truth = np.where(view.plane_id == NON_PLANAR_ID, -1, view.plane_id)
            small = to_output_labels(truth.astype(np.int16))
            yield "validation rooms" if args.validation else "random rooms", view.image, truth, normal_image(small, camera_normals(scene, R, t))
    if args.validation:
        return
    for name in ("room", "corridor", "boxes"):
        seq = SyntheticSequence(builtin_scene(name), settings=SequenceSettings(duration_s=30.0, image_noise=2.0))
        for i in range(0, len(seq), len(seq) // 20):
            view = seq.views(i)[0]
            yield name, view.image, np.where(view.plane_id == NON_PLANAR_ID, -1, view.plane_id), None


def summarize(rows: list[dict]) -> dict[str, float]:
    keys = ("planar_iou", "recall", "ari")
    out = {k: float(np.nanmean([r[k] for r in rows])) for k in keys}
    errors = [r["normal_error_deg"] for r in rows if np.isfinite(r.get("normal_error_deg", np.nan))]
    out["normal_error_deg"] = float(np.median(errors)) if errors else None  # None: a model without normals
    out["recall_pooled"] = float(sum(r["matched"] for r in rows) / max(sum(r["instances"] for r in rows), 1))
    out["frames"] = len(rows)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", type=int, default=25)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--gallery", type=pathlib.Path, default=ROOT / "docs" / "segmentation")
    parser.add_argument(
        "--no-doc",
        "--no-readme",
        dest="no_doc",
        action="store_true",
        help="print the table, leave docs/results/segmenter.md and docs/pipeline/planeseg_eval.json alone (--no-readme: the old name, from when the tables were in README.md)",
    )
    parser.add_argument("--model", type=pathlib.Path, default=None, help="another .onnx file (default: the shipped one)")
    parser.add_argument("--normal-weight", type=float, default=None, help="mean shift's normal weight (default: the contract's)")
    parser.add_argument("--bandwidth", type=float, default=None, help="mean shift's bandwidth (default: the contract's)")
    parser.add_argument("--validation", action="store_true", help="validation layouts (seed 1) only; no real pairs, no gallery")
    parser.add_argument("--photos", type=float, default=0.0, help="with --validation: share of surfaces wearing real photographs (0-1)")
    args = parser.parse_args()
    if args.validation:
        args.no_doc = True
    settings = LearnedSegmenterSettings(normal_weight=args.normal_weight, bandwidth=args.bandwidth)
    if args.model is not None:
        settings = dataclasses.replace(settings, model=args.model)
    seg = LearnedSegmenter(settings=settings)
    results: dict[str, dict] = {}
    by_set: dict[str, list[dict]] = {}
    for name, image, truth, normals in rendered_frames(args):
        labels = seg.segment(image, image, None).labels  # type: ignore[arg-type]
        row = instance_figures(labels, truth)
        if normals is not None:
            row["normal_error_deg"] = normal_error_deg(seg.predict(image)[2], normals)
        by_set.setdefault(name, []).append(row)
    for name, rows in by_set.items():
        results[name] = summarize(rows)
    results["all rendered"] = summarize([r for rows in by_set.values() for r in rows])
    from segmentation_gallery import PAIRS, overlay, real_pairs
    from table_sweep import publish

    if PAIRS.is_dir() and not args.validation:
        import cv2

        from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

        geo = GeometricPlaneSegmenter()
        rows = []
        found_lines = []
        args.gallery.mkdir(parents=True, exist_ok=True)
        for i, left, right, camera, R_world_camera in real_pairs():
            ref_masks = geo.segment(left, right, camera)
            ref = ref_masks.labels
            masks = seg.segment(left, right, camera)
            row = instance_figures(masks.labels, ref)
            row["normal_error_deg"] = normal_error_deg(seg.predict(left)[2], reference_normals(ref_masks))
            rows.append(row)
            found = planes_found(R_world_camera, ref_masks, masks)
            results[f"V1_01 pair {i} planes"] = found  # type: ignore[assignment]
            cells = [f"{f['kind']} ({100 * f['share']:.0f} %): {'found' if f['found'] else 'missed'}, {100 * f['covered']:.0f} % in {f['pieces']} piece{'s' * (f['pieces'] != 1)}" for f in found]
            found_lines.append(f"| {i} | " + "; ".join(cells) + " |")
            cv2.imwrite(str(args.gallery / f"euroc_pair_{i}_learned.png"), cv2.cvtColor(overlay(left, masks), cv2.COLOR_RGB2BGR))
        results["V1_01 pairs vs geometric"] = summarize(rows)
    lines = [
        "`.venv/bin/python scripts/planeseg_eval.py`: planar-mask IoU, matched-instance recall (instances covering ≥ 1 % of the "
        "image matched by a predicted instance at IoU ≥ 0.5; mean per frame, and pooled over all instances), adjusted Rand index "
        "over the pixels planar in both. Rendered frames against their exact plane ids (random layouts from seed 0, never "
        "trained on; 21 frames of each built-in scene, with 2 grey levels of noise); the real V1_01 pairs against the geometric "
        "segmenter's instances (not a ground truth: it splits and merges planes its own way).",
        "",
    ]
    with_normals = seg.has_normals  # the column only for a model with a normal output
    lines += ["| frames | n | planar IoU | recall@0.5 | pooled recall | ARI |" + (" median normal error ° |" if with_normals else ""), "|---|---|---|---|---|---|" + ("---|" if with_normals else "")]
    for name, r in results.items():
        if name.endswith(" planes"):
            continue
        normal = ("–" if r["normal_error_deg"] is None else f"{r['normal_error_deg']:.1f}") + " |" if with_normals else ""
        lines.append(f"| {name} | {r['frames']} | {r['planar_iou']:.3f} | {r['recall']:.3f} | {r['recall_pooled']:.3f} | {r['ari']:.3f} | {normal}".rstrip())
    if PAIRS.is_dir() and not args.validation:
        lines += [
            "",
            "Real V1_01 pairs, the floor (within 5° of the vertical by the ground-truth pose) and the main walls (its other instances "
            "covering ≥ 10 % of the image) of the geometric segmenter, with their share of the image: found when learned instances lying mostly "
            "(≥ 70 %) on it cover at least half of it; the share they cover and in how many pieces (instances holding ≥ 5 % of it).",
            "",
            "| pair | floor and main walls |",
            "|---|---|",
            *found_lines,
        ]
    results["model_sha256"] = seg.contract.get("sha256")
    # An experiment (--no-doc) only prints: the published JSON and results page stay the shipped model's.
    return publish(results, "\n".join(lines), json_name="planeseg_eval.json", block="planeseg-eval", write_doc=not args.no_doc)


if __name__ == "__main__":
    sys.exit(main())
