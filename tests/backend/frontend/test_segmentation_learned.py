"""The learned plane segmenter: the shipped model and its contract, bad model files, mean
shift, and instances on a rendered frame (onnxruntime only: the tests never need torch)."""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pytest

from backend.frontend.segmentation import NO_PLANE
from backend.frontend.segmentation_learned import DEFAULT_MODEL, LearnedSegmenter, LearnedSegmenterSettings, ModelError, cluster_embeddings, prepare_input


@pytest.fixture(scope="module")
def segmenter() -> LearnedSegmenter:
    return LearnedSegmenter()


def test_the_shipped_model_matches_its_contract(segmenter: LearnedSegmenter) -> None:
    contract = json.loads(DEFAULT_MODEL.with_suffix(".json").read_text())
    import hashlib

    assert contract["sha256"] == hashlib.sha256(DEFAULT_MODEL.read_bytes()).hexdigest()
    assert DEFAULT_MODEL.stat().st_size < 8e6  # a few MB
    prob, emb, normals = segmenter.predict(np.full((480, 752), 128, np.uint8))
    assert prob.shape == tuple(contract["outputs"]["planar_logit"]["shape"][2:])
    assert emb.shape == (*prob.shape, contract["outputs"]["embedding"]["shape"][1])
    assert np.all((prob >= 0) & (prob <= 1))
    if "normal" in contract["outputs"]:
        assert normals is not None and normals.shape == (*prob.shape, 3)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-4)
    else:
        assert normals is None
    assert "train_planeseg.py" in contract["training"]["command"]


def _copy(tmp_path: pathlib.Path) -> pathlib.Path:
    model = tmp_path / "model.onnx"
    shutil.copy(DEFAULT_MODEL, model)
    shutil.copy(DEFAULT_MODEL.with_suffix(".json"), model.with_suffix(".json"))
    return model


def test_bad_model_files_give_one_line(tmp_path: pathlib.Path) -> None:
    model = _copy(tmp_path)
    model.write_bytes(b"\x08\x07 not an onnx model" * 10)
    with pytest.raises(ModelError, match="model.onnx: not a loadable ONNX model") as e:
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))
    assert "\n" not in str(e.value)

    model = _copy(tmp_path)
    contract = json.loads(model.with_suffix(".json").read_text())
    contract["input"]["shape"] = [1, 1, 256, 384]  # a model of another shape than its contract says
    model.with_suffix(".json").write_text(json.dumps(contract))
    with pytest.raises(ModelError, match=r"model.onnx: input .* does not match its contract"):
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))

    model.with_suffix(".json").write_text("{not json")
    with pytest.raises(ModelError, match="model.json: not a segmenter contract"):
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))
    model.with_suffix(".json").unlink()
    with pytest.raises(ModelError, match="model contract missing"):
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))
    with pytest.raises(ModelError, match="model file missing"):
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=tmp_path / "none.onnx"))


def test_the_contract_s_clahe_prepares_the_input(tmp_path: pathlib.Path) -> None:
    """A contract with `input.clahe` equalizes the image before the area average (as the
    training did); a bad one is one line."""
    import cv2

    rng = np.random.default_rng(0)
    image = np.clip(rng.normal(90, 12, (480, 752)), 0, 255).astype(np.uint8)  # dim, low contrast
    plain = prepare_input(image, width=192, height=128)
    assert plain.shape == (128, 192) and plain.dtype == np.float32
    assert np.allclose(plain, cv2.resize(image, (192, 128), interpolation=cv2.INTER_AREA) / 255.0)
    equalized = prepare_input(image, width=192, height=128, clahe={"clip_limit": 2.0, "tiles": 8})
    assert equalized.std() > 1.5 * plain.std()

    model = _copy(tmp_path)
    contract = json.loads(model.with_suffix(".json").read_text())
    contract["input"]["clahe"] = {"clip_limit": 2.0, "tiles": 8}
    model.with_suffix(".json").write_text(json.dumps(contract))
    seg = LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))
    session_input = {}
    seg._session = type("Recorder", (), {"run": lambda self, names, feed: (session_input.update(feed), [np.zeros((1, 1, 64, 96)), np.zeros((1, 4, 64, 96))])[1]})()
    seg.predict(image)
    assert np.allclose(session_input["image"][0, 0], equalized)
    contract["input"]["clahe"] = {"clip_limit": -1, "tiles": 8}
    model.with_suffix(".json").write_text(json.dumps(contract))
    with pytest.raises(ModelError, match=r"model.json: not a segmenter contract .*input.clahe"):
        LearnedSegmenter(settings=LearnedSegmenterSettings(model=model))


def test_mean_shift_separates_embedding_clusters() -> None:
    rng = np.random.default_rng(0)
    h, w = 40, 60
    truth = np.zeros((h, w), int)
    truth[:, 20:40] = 1
    truth[:, 40:] = 2
    truth[:5] = -1  # not planar
    centres = np.array([[0.0, 0.0, 0.0, 0.0], [3.0, 0.0, 0.0, 0.0], [0.0, 3.0, 0.0, 0.0]])
    emb = centres[np.maximum(truth, 0)] + rng.normal(0, 0.15, (h, w, 4))
    labels = cluster_embeddings(emb, truth >= 0, bandwidth=1.0)
    assert np.all(labels[truth < 0] == NO_PLANE)
    for k in range(3):
        found = np.unique(labels[truth == k])
        assert len(found) == 1 and found[0] >= 0
    assert len(np.unique(labels[truth >= 0])) == 3
    assert cluster_embeddings(emb, np.zeros((h, w), bool), bandwidth=1.0).max() == NO_PLANE


def test_rendered_room_walls_and_floor_are_found(segmenter: LearnedSegmenter) -> None:
    """A frame of the built-in room (never trained on): the planar mask covers the planes
    and the large planes each get one instance."""
    from backend.data.render import NON_PLANAR_ID
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, SyntheticSequence

    seq = SyntheticSequence(builtin_scene("room"), settings=SequenceSettings(duration_s=4.0))
    view = seq.views(40)[0]
    masks = segmenter.segment(view.image, view.image, seq.camera)
    assert masks.labels.shape == view.image.shape
    planar, truth = masks.labels >= 0, view.plane_id != NON_PLANAR_ID
    assert np.count_nonzero(planar & truth) / np.count_nonzero(planar | truth) > 0.8
    ids, counts = np.unique(view.plane_id[truth], return_counts=True)
    for i in ids[counts > 0.08 * truth.size]:
        found, overlap = np.unique(masks.labels[(view.plane_id == i) & planar], return_counts=True)
        assert overlap.max() > 0.5 * np.count_nonzero(view.plane_id == i), (i, found, overlap)


def test_normals_split_what_the_embedding_merges(segmenter: LearnedSegmenter) -> None:
    """A floor and a wall the embedding does not tell apart (one cluster) come out as two
    instances once their normals (90° apart) join the clustering, and as one without."""
    h, w = 40, 60
    rng = np.random.default_rng(1)
    emb = rng.normal(0, 0.1, (h, w, 4))
    normals = np.zeros((h, w, 3))
    normals[:20] = [0.0, 0.0, -1.0]  # the wall, facing the camera
    normals[20:] = [0.0, -1.0, 0.0]  # the floor (camera y points down)
    seg = segmenter  # the shipped model; the weight is set here
    old = seg.normal_weight
    try:
        seg.normal_weight = 1.5
        labels = cluster_embeddings(seg.clustering_features(emb, normals), np.ones((h, w), bool), bandwidth=1.0)
        assert len(np.unique(labels[:20])) == 1 and len(np.unique(labels[20:])) == 1 and labels[0, 0] != labels[-1, 0]
        seg.normal_weight = 0.0
        labels = cluster_embeddings(seg.clustering_features(emb, normals), np.ones((h, w), bool), bandwidth=1.0)
        assert len(np.unique(labels)) == 1
        assert seg.clustering_features(emb, None) is emb
    finally:
        seg.normal_weight = old
