"""Fine-tuning starts where the exported model stands (needs torch and onnx: the `train`
extra; skipped without them)."""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "training"))

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")


def test_the_shipped_model_unfolds_into_the_same_function_in_eval_and_train_mode() -> None:
    import onnxruntime as ort
    from planeseg_model import PlaneNet
    from warm_start import warm_start

    model_path = ROOT / "assets" / "planeseg.onnx"
    images = np.random.default_rng(0).uniform(0, 1, (4, 1, 128, 192)).astype(np.float32)
    session = ort.InferenceSession(str(model_path))
    expected = [np.concatenate(o) for o in zip(*[session.run(None, {"image": images[i : i + 1]}) for i in range(len(images))])]
    torch.manual_seed(0)
    model = PlaneNet(width=16)
    warm_start(model, model_path, images)
    for mode in (model.eval, model.train):  # train mode: on the calibration batch's own statistics
        mode()
        with torch.no_grad():
            got = model(torch.from_numpy(images))
        for e, g in zip(expected, got):
            np.testing.assert_allclose(g.numpy(), e, atol=1e-4)
    with pytest.raises(ValueError, match="convolutions"):
        warm_start(PlaneNet(width=8), model_path, images)
