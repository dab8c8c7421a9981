"""The learned plane-instance segmenter (paper §III-A, a simplified PlaneAE): a small
encoder-decoder network, shipped as ONNX in `assets/` and run with onnxruntime, predicts a
planar mask, a per-pixel embedding and (models with a `normal` output) the surface normal in
the camera frame at half its input resolution; mean shift clusters the planar pixels'
embeddings, with their unit normals scaled by the contract's `normal_weight` appended,
into instances.

Works on the left image alone (no stereo), so the VIO can use it. The model's contract
(input and output names and shapes) lives in a JSON file beside it and is checked when the
model is loaded: a missing, corrupt or mismatched file raises :class:`ModelError` with one
line naming the file and what is wrong. The network was trained by
`training/train_planeseg.py` (PyTorch, training time only; never imported here).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import cv2
import numpy as np

from backend.frontend.segmentation import NO_PLANE, PlaneMasks
from backend.geometry.camera import PinholeCamera

DEFAULT_MODEL = pathlib.Path(__file__).resolve().parents[2] / "assets" / "planeseg.onnx"


class ModelError(ValueError):
    """A model file that cannot be used (one line: the file and what is wrong)."""


def prepare_input(image: np.ndarray, *, width: int, height: int, clahe: dict | None = None) -> np.ndarray:
    """The network's input (height, width) float32 in [0, 1] from a grey uint8 image of any
    size: with `clahe` (`{"clip_limit": c, "tiles": n}`, the contract's), contrast-limited
    adaptive histogram equalization on the full image first (OpenCV; it evens out the
    exposure and contrast that differ between rendered and real images), then area
    averaging to the input size. Training prepares its images with this same function."""
    if clahe is not None:
        tiles = int(clahe["tiles"])
        image = cv2.createCLAHE(clipLimit=float(clahe["clip_limit"]), tileGridSize=(tiles, tiles)).apply(image)
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0


@dataclasses.dataclass(frozen=True)
class LearnedSegmenterSettings:
    """`bandwidth`: mean-shift radius in embedding space (None: the model's, from its
    JSON); `normal_weight`: scale of the unit normals appended to the embedding for mean
    shift, for models with a normal output (None: the contract's; 0: embeddings alone);
    `planar_threshold`: probability above which a pixel is planar; `seeds`: planar
    pixels that seed the modes (a random subset, fixed by `seed`); `iterations` of mean
    shift; `min_share`: smallest instance kept, as a fraction of the image; `threads`:
    onnxruntime's intra-op threads (2 cores here: one keeps the other for tracking)."""

    model: pathlib.Path = DEFAULT_MODEL
    bandwidth: float | None = None
    normal_weight: float | None = None
    planar_threshold: float = 0.5
    seeds: int = 150
    sample: int = 1500
    iterations: int = 8
    min_share: float = 0.01
    threads: int = 1
    seed: int = 0


def load_contract(model: pathlib.Path) -> dict:
    """The model's JSON contract beside `model`: both files present, the JSON parseable
    with the keys used (its match with the ONNX file's inputs and outputs is checked by
    :class:`LearnedSegmenter`)."""
    path = pathlib.Path(model).with_suffix(".json")
    if not pathlib.Path(model).is_file():
        raise ModelError(f"{model}: model file missing")
    if not path.is_file():
        raise ModelError(f"{path}: model contract missing (the JSON beside the .onnx file)")
    try:
        contract = json.loads(path.read_text())
        _ = contract["input"]["name"], contract["input"]["shape"], contract["outputs"]["planar_logit"]["shape"], contract["outputs"]["embedding"]["shape"]
        if "normal" in contract["outputs"]:
            _ = contract["outputs"]["normal"]["shape"], float(contract["clustering"]["normal_weight"])
        clahe = contract["input"].get("clahe")
        if clahe is not None and not (float(clahe["clip_limit"]) > 0 and 1 <= int(clahe["tiles"]) <= 64):
            raise ValueError(f"input.clahe {clahe}: expected a clip_limit > 0 and 1 to 64 tiles")
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ModelError(f"{path}: not a segmenter contract ({type(e).__name__}: {e})") from None
    return contract


class LearnedSegmenter:
    """`PlaneSegmenter` with the shipped network (module docstring)."""

    def __init__(self, *, settings: LearnedSegmenterSettings = LearnedSegmenterSettings()) -> None:
        import onnxruntime as ort

        self.settings = settings
        model = pathlib.Path(settings.model)
        self.contract = load_contract(model)
        options = ort.SessionOptions()
        options.intra_op_num_threads = settings.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(model), sess_options=options, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own types for corrupt files
            raise ModelError(f"{model}: not a loadable ONNX model ({' '.join(str(e).split())[:160]})") from None
        self._check(model)
        _, _, self.input_h, self.input_w = self.contract["input"]["shape"]
        _, self.embed_dim, self.output_h, self.output_w = self.contract["outputs"]["embedding"]["shape"]
        self.bandwidth = float(settings.bandwidth if settings.bandwidth is not None else self.contract["clustering"]["bandwidth"])
        self.has_normals = "normal" in self.contract["outputs"]
        self.normal_weight = 0.0
        if self.has_normals:
            self.normal_weight = float(settings.normal_weight if settings.normal_weight is not None else self.contract["clustering"]["normal_weight"])
        self._outputs = ["planar_logit", "embedding"] + (["normal"] if self.has_normals else [])

    def _check(self, model: pathlib.Path) -> None:
        c = self.contract
        inputs = {i.name: i.shape for i in self._session.get_inputs()}
        outputs = {o.name: o.shape for o in self._session.get_outputs()}
        name = c["input"]["name"]
        if list(inputs) != [name] or list(inputs[name]) != list(c["input"]["shape"]):
            raise ModelError(f"{model}: input {dict(inputs)} does not match its contract ({name}: {c['input']['shape']})")
        for out in c["outputs"]:
            if out not in outputs or list(outputs[out]) != list(c["outputs"][out]["shape"]):
                raise ModelError(f"{model}: output {out} is {outputs.get(out)}, its contract says {c['outputs'][out]['shape']}")

    def predict(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Planar probability (h, w), embeddings (h, w, D) and unit normals (h, w, 3) in the
        camera frame (None for a model without them) at the output resolution of a grey
        uint8 image (H, W) of any size."""
        if image.ndim != 2 or image.dtype != np.uint8:
            raise ValueError(f"expected a grey uint8 (H, W) image, got {image.shape} {image.dtype}")
        x = prepare_input(image, width=self.input_w, height=self.input_h, clahe=self.contract["input"].get("clahe"))
        logit, emb, *rest = self._session.run(self._outputs, {self.contract["input"]["name"]: x[None, None]})
        prob = 1.0 / (1.0 + np.exp(-logit[0, 0]))
        normals = None
        if rest:
            n = np.moveaxis(rest[0][0], 0, -1)
            normals = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
        return prob, np.moveaxis(emb[0], 0, -1), normals

    def clustering_features(self, embedding: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
        """What mean shift clusters (h, w, D'): the embedding, with the unit normals scaled by
        `normal_weight` appended when the model has them and the weight is positive."""
        if normals is None or self.normal_weight <= 0:
            return embedding
        return np.concatenate([embedding, self.normal_weight * normals], axis=-1)

    def segment(self, left: np.ndarray, right: np.ndarray, camera: PinholeCamera) -> PlaneMasks:
        """Instance masks of the left image (`right` and `camera` are not needed)."""
        prob, emb, normals = self.predict(left)
        labels = cluster_embeddings(
            self.clustering_features(emb, normals),
            prob >= self.settings.planar_threshold,
            bandwidth=self.bandwidth,
            seeds=self.settings.seeds,
            iterations=self.settings.iterations,
            min_share=self.settings.min_share,
            seed=self.settings.seed,
            sample=self.settings.sample,
        )
        H, W = left.shape
        full = cv2.resize(labels.astype(np.int16), (W, H), interpolation=cv2.INTER_NEAREST)
        return PlaneMasks(labels=full.astype(np.int16))


def cluster_embeddings(embedding: np.ndarray, planar: np.ndarray, *, bandwidth: float, seeds: int = 150, iterations: int = 8, min_share: float = 0.01, seed: int = 0, sample: int = 1500) -> np.ndarray:
    """Instances (h, w) int16 (`NO_PLANE` elsewhere) from embeddings (h, w, D) of the
    `planar` pixels: flat-kernel mean shift over a random `sample` of them from `seeds` of
    those (vectorized over seeds), modes closer than `bandwidth` merged, each planar pixel given to its nearest
    mode if within `1.5 bandwidth`; instances under `min_share` of the image dropped and
    the rest numbered by size (largest first)."""
    h, w, D = embedding.shape
    labels = np.full((h, w), NO_PLANE, np.int16)
    idx = np.flatnonzero(planar.reshape(-1))
    if len(idx) == 0:
        return labels
    points = embedding.reshape(-1, D)[idx].astype(np.float32)
    rng = np.random.default_rng(seed)
    density = points[rng.choice(len(points), size=min(sample, len(points)), replace=False)]  # the density mean shift climbs
    modes = density[rng.choice(len(density), size=min(seeds, len(density)), replace=False)]
    b2 = bandwidth * bandwidth
    density_sq = (density**2).sum(1)
    for _ in range(iterations):
        near = (_sq_dist(modes, density, density_sq) <= b2).astype(np.float32)
        count = near.sum(1, keepdims=True)
        modes = np.where(count > 0, (near @ density) / np.maximum(count, 1), modes)
    # Merge modes: greedily, the most supported first.
    support = (_sq_dist(modes, density, density_sq) <= b2).sum(1)
    centres: list[np.ndarray] = []
    for m in modes[np.argsort(-support)]:
        if all(((m - c) ** 2).sum() > b2 for c in centres):
            centres.append(m)
    C = np.stack(centres)
    d2 = _sq_dist(points, C, (C**2).sum(1))
    nearest = d2.argmin(1)
    ok = d2[np.arange(len(points)), nearest] <= (1.5 * bandwidth) ** 2
    assign = np.where(ok, nearest, -1)
    counts = np.bincount(assign[assign >= 0], minlength=len(C))
    keep = [c for c in np.argsort(-counts) if counts[c] >= min_share * h * w]
    remap = np.full(len(C), -1, np.int64)
    remap[keep] = np.arange(len(keep))
    flat = labels.reshape(-1)
    flat[idx] = np.where(assign >= 0, remap[np.maximum(assign, 0)], -1)
    return flat.reshape(h, w)


def _sq_dist(a: np.ndarray, b: np.ndarray, b_sq: np.ndarray) -> np.ndarray:
    """Squared distances (len(a), len(b)) through one matrix product (no (A, B, D) temporary)."""
    return np.maximum((a**2).sum(1)[:, None] + b_sq[None, :] - 2.0 * (a @ b.T), 0.0)
