"""Start training from an exported segmenter (an .onnx written by train_planeseg.export)
instead of random weights (training time only; needs torch and onnx).

The export folds each BatchNorm into the convolution before it (`do_constant_folding`):
every `onnx::Conv_N` initializer pair is a folded weight and bias, in the graph's order
(encoder, then decoder blocks, as `PlaneNet` defines them); the heads keep their names.
`warm_start` puts the folded weights into the convolutions and sets each BatchNorm so
that the network computes the exported function both in eval mode and, on the
calibration batch, in train mode (batch statistics): its scale and shift absorb the
batch's mean and spread, so fine-tuning starts where the exported model stands.
"""

from __future__ import annotations

import pathlib
import re

import numpy as np


def folded_weights(path: pathlib.Path) -> tuple[list[tuple[np.ndarray, np.ndarray]], dict[str, np.ndarray]]:
    """(the folded (weight, bias) pairs in graph order, the named head tensors) of an
    exported model."""
    import onnx
    from onnx import numpy_helper

    tensors = {i.name: numpy_helper.to_array(i) for i in onnx.load(str(path)).graph.initializer}
    numbered = sorted((int(m.group(1)), name) for name in tensors if (m := re.fullmatch(r"onnx::Conv_(\d+)", name)))
    arrays = [tensors[name] for _, name in numbered]
    if len(arrays) % 2:
        raise ValueError(f"{path}: an odd number of folded convolution tensors")
    pairs = [(arrays[k], arrays[k + 1]) for k in range(0, len(arrays), 2)]
    heads = {name: value for name, value in tensors.items() if not name.startswith("onnx::")}
    return pairs, heads


def warm_start(model, path: pathlib.Path, calibration: np.ndarray) -> None:
    """Loads the exported model at `path` into `model` (a `PlaneNet` of the same width and
    heads); `calibration` (B, 1, H, W) float32 input images in 0–1 set the BatchNorms'
    train-mode statistics (see the module docstring). Raises ValueError on a mismatch."""
    import torch
    from torch import nn

    pairs, heads = folded_weights(path)
    convs = [m for block in model.children() if isinstance(block, nn.Sequential) for m in block if isinstance(m, nn.Conv2d)]
    norms = [m for block in model.children() if isinstance(block, nn.Sequential) for m in block if isinstance(m, nn.BatchNorm2d)]
    if len(convs) != len(pairs) or any(c.weight.shape != torch.Size(w.shape) for c, (w, _) in zip(convs, pairs)):
        raise ValueError(f"{path}: its convolutions do not match the model's")
    state = model.state_dict()
    missing = [name for name in state if name.split(".")[0].endswith("_head") and name not in heads]
    if missing or any(name not in state or state[name].shape != torch.Size(v.shape) for name, v in heads.items()):
        raise ValueError(f"{path}: its heads do not match the model's ({', '.join(missing) or 'shapes'})")
    with torch.no_grad():
        for name, value in heads.items():
            state[name].copy_(torch.from_numpy(np.array(value)))
        for conv, norm, (w, b) in zip(convs, norms, pairs):
            conv.weight.copy_(torch.from_numpy(np.array(w)))
            norm.bias.copy_(torch.from_numpy(np.array(b)))  # the folded bias; the batch mean is added below

        def calibrate(norm: nn.BatchNorm2d, inputs: tuple[torch.Tensor, ...]) -> None:
            z = inputs[0]
            mean, var = z.mean((0, 2, 3)), z.var((0, 2, 3), unbiased=False)
            norm.weight.copy_(torch.sqrt(var + norm.eps))  # (z - mean) / std * std + b + mean = z + b
            norm.bias.add_(mean)
            norm.running_mean.copy_(mean)
            norm.running_var.copy_(var)

        hooks = [norm.register_forward_pre_hook(calibrate) for norm in norms]
        momentum = [norm.momentum for norm in norms]
        for norm in norms:
            norm.momentum = 0.0  # this pass leaves the running statistics as calibrate set them
        model.train()
        try:
            model(torch.from_numpy(np.ascontiguousarray(calibration, np.float32)))
        finally:
            for hook in hooks:
                hook.remove()
            for norm, m in zip(norms, momentum):
                norm.momentum = m
