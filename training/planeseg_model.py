"""The plane-instance segmentation network (training time only): a simplified PlaneAE
(Yu et al., CVPR 2019) as the paper uses it. A shared encoder (strided convolutions down to
1/16), a decoder with skip connections up to 1/2 of the input, and heads on it: the
planar-mask logit (1 channel), a per-pixel embedding (`EMBED_DIM` channels) that the
runtime clusters into instances by mean shift, and (with `normals`) the surface normal in
the camera frame (3 channels, not normalized), as PlaneAE's per-pixel plane parameters.

Loss: binary cross-entropy on the planar mask, plus the discriminative loss of De
Brabandere et al. on the embeddings of planar pixels (pull each pixel within `DELTA_V` of
its instance's mean, push instance means `2 DELTA_D` apart, a small pull of the means to
the origin), as PlaneAE does; with normals, plus 1 - cos between the predicted and the
true normal (oriented towards the camera) on planar pixels whose normal is known.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

EMBED_DIM = 4
DELTA_V = 0.5
DELTA_D = 1.5


def _block(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class PlaneNet(nn.Module):
    """Input (B, 1, H, W) grey in [0, 1] (H, W multiples of 16); outputs the planar logit
    (B, 1, H/2, W/2), the embedding (B, EMBED_DIM, H/2, W/2) and, with `normals`, the
    camera-frame normal (B, 3, H/2, W/2)."""

    def __init__(self, width: int = 16, *, normals: bool = False) -> None:
        super().__init__()
        w = width
        self.enc1 = _block(1, w, 2)  # 1/2
        self.enc2 = _block(w, 2 * w, 2)  # 1/4
        self.enc3 = _block(2 * w, 4 * w, 2)  # 1/8
        self.enc4 = _block(4 * w, 6 * w, 2)  # 1/16
        self.dec3 = _block(6 * w + 4 * w, 4 * w, 1)
        self.dec2 = _block(4 * w + 2 * w, 2 * w, 1)
        self.dec1 = _block(2 * w + w, 2 * w, 1)
        self.mask_head = nn.Conv2d(2 * w, 1, 1)
        self.embed_head = nn.Conv2d(2 * w, EMBED_DIM, 1)
        self.normal_head = nn.Conv2d(2 * w, 3, 1) if normals else None

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        x = x - 0.5
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        up = lambda t, ref: F.interpolate(t, size=ref.shape[-2:], mode="bilinear", align_corners=False)  # noqa: E731
        d3 = self.dec3(torch.cat([up(e4, e3), e3], 1))
        d2 = self.dec2(torch.cat([up(d3, e2), e2], 1))
        d1 = self.dec1(torch.cat([up(d2, e1), e1], 1))
        if self.normal_head is None:
            return self.mask_head(d1), self.embed_head(d1)
        return self.mask_head(d1), self.embed_head(d1), self.normal_head(d1)


def discriminative_loss(embedding: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean over the batch of the discriminative loss; `labels` (B, h, w) long with
    instance ids >= 0 for planar pixels (others ignored)."""
    total = embedding.new_zeros(())
    B = embedding.shape[0]
    for b in range(B):
        lab = labels[b].reshape(-1)
        emb = embedding[b].reshape(embedding.shape[1], -1)
        ids = torch.unique(lab[lab >= 0])
        if len(ids) == 0:
            continue
        means, pull = [], embedding.new_zeros(())
        for i in ids:
            e = emb[:, lab == i]
            mu = e.mean(dim=1)
            means.append(mu)
            pull = pull + (F.relu((e - mu[:, None]).norm(dim=0) - DELTA_V) ** 2).mean()
        mu = torch.stack(means)
        pull = pull / len(ids)
        push = embedding.new_zeros(())
        if len(ids) > 1:
            dist = torch.cdist(mu, mu)
            off = ~torch.eye(len(ids), dtype=torch.bool)
            push = (F.relu(2 * DELTA_D - dist[off]) ** 2).mean()
        reg = mu.norm(dim=1).mean()
        total = total + pull + push + 0.001 * reg
    return total / B


def normal_loss(normal: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean of 1 - cos between predicted (B, 3, h, w) and true unit normals over the pixels
    whose true normal is known (non-zero)."""
    known = target.norm(dim=1) > 0.5
    if not known.any():
        return normal.sum() * 0
    cos = F.cosine_similarity(normal, target, dim=1, eps=1e-6)
    return (1.0 - cos[known]).mean()


def loss(
    mask_logit: torch.Tensor, embedding: torch.Tensor, labels: torch.Tensor, normal: torch.Tensor | None = None, normal_target: torch.Tensor | None = None, *, normal_weight: float = 1.0
) -> tuple[torch.Tensor, dict[str, float]]:
    """BCE on pixels with a planar / non-planar label (-2: ignored) plus the embedding loss
    (plus `normal_weight` times the normal loss when normals are given)."""
    known = labels != -2
    target = (labels >= 0).float()
    bce = F.binary_cross_entropy_with_logits(mask_logit[:, 0][known], target[known]) if known.any() else mask_logit.sum() * 0
    disc = discriminative_loss(embedding, labels)
    parts = {"bce": float(bce.detach()), "disc": float(disc.detach())}
    total = bce + disc
    if normal is not None and normal_target is not None:
        nl = normal_loss(normal, normal_target)
        total = total + normal_weight * nl
        parts["normal"] = float(nl.detach())
    return total, parts
