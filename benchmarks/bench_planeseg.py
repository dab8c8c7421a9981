"""Time of the learned plane segmenter per keyframe (onnxruntime inference + mean shift) on
752×480 images: the four real V1_01 pairs and rendered room frames, `--runs` timed calls
each after one warm-up; prints the median, range and the split.

    .venv/bin/python benchmarks/bench_planeseg.py [--runs 50] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import statistics
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))


from backend.frontend.segmentation_learned import LearnedSegmenter, LearnedSegmenterSettings, cluster_embeddings


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=50)
    p.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")
    args = p.parse_args()
    seg = LearnedSegmenter(settings=LearnedSegmenterSettings(threads=args.threads))
    images = []
    from segmentation_gallery import PAIRS, real_pairs

    if PAIRS.is_dir():
        images += [left for _, left, _, _, _ in real_pairs()]
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=10.0))
    images += [seq.views(i)[0].image for i in (0, 60, 120, 180)]
    total, net, clus = [], [], []
    for image in images:
        seg.segment(image, image, None)  # type: ignore[arg-type]  # warm-up
        for _ in range(args.runs):
            t0 = time.perf_counter()
            prob, emb, normals = seg.predict(image)
            t1 = time.perf_counter()
            cluster_embeddings(seg.clustering_features(emb, normals), prob >= seg.settings.planar_threshold, bandwidth=seg.bandwidth, seeds=seg.settings.seeds, sample=seg.settings.sample)
            t2 = time.perf_counter()
            seg.segment(image, image, None)  # type: ignore[arg-type]
            total.append(1e3 * (time.perf_counter() - t2))
            net.append(1e3 * (t1 - t0))
            clus.append(1e3 * (t2 - t1))
    print(f"# python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cpus, onnxruntime threads {args.threads}; {len(images)} images × {args.runs} runs")
    for name, v in (("segment (per keyframe)", total), ("  network", net), ("  mean shift", clus)):
        print(f"{name:24s} median {statistics.median(v):6.2f} ms  (min {min(v):.2f}, max {max(v):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
