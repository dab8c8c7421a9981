"""The keyframe image of a snapshot: the rectified left image with what the front end and
the co-planar detection made of it, drawn once per keyframe and stored as JPEG
(:class:`~backend.pipeline.snapshot.KeyframeImage`).

Layers, bottom to top:

- plane instances of the segmenter: accepted instances tinted (35 %) with their map plane's
  colour (`backend.common.palette.plane_color`), instances the co-planar RANSAC rejected
  (or did not test) tinted light grey and hatched; a thin contour around every instance;
- segments, 2 px, in their plane's colour (grey: no plane);
- points: tracked (green), new stereo landmarks (cyan), detections without a landmark
  (small grey dots), outliers of the robust pose refinement (red), each with a dark rim
  so they read on bright and dark texture alike.

Pixel coordinates are those of the full-resolution rectified left image (OpenCV: x right,
y down, pixel centres at integer coordinates). Colours are RGB; the JPEG is written so
that any decoder returns those colours (OpenCV's BGR order is handled here).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from backend.common.palette import plane_color
from backend.pipeline.snapshot import KeyframeImage

# Point states (`point_status`).
POINT_TRACKED = 0  # matched to an existing map point
POINT_NEW = 1  # new landmark created from stereo
POINT_UNUSED = 2  # detected, no landmark
POINT_OUTLIER = 3  # rejected by the robust pose refinement

#: RGB colour and radius (output pixels) of each point state, indexed by state.
POINT_COLORS = np.array([[40, 230, 40], [0, 230, 255], [200, 200, 200], [255, 40, 40]], dtype=np.uint8)
POINT_RADII = (3, 3, 1, 3)
_DRAW_ORDER = (POINT_UNUSED, POINT_TRACKED, POINT_NEW, POINT_OUTLIER)  # later on top
RIM = np.array([20, 20, 20], dtype=np.uint8)

SEGMENT_THICKNESS_PX = 2
TINT_ALPHA = 0.35
REJECTED_TINT = np.array([225, 225, 225], dtype=np.uint8)
REJECTED_ALPHA = 0.35
REJECTED_HATCH = np.array([245, 245, 245], dtype=np.uint8)
REJECTED_CONTOUR = np.array([120, 120, 120], dtype=np.uint8)
HATCH_PERIOD_PX = 8

_SHIFT = 4  # fixed-point bits of the sub-pixel coordinates given to cv2.polylines
_FAR_PX = 1e6


def _as_float(array: np.ndarray, item_shape: tuple[int, ...]) -> np.ndarray:
    """`array` as float; an empty one (e.g. `np.zeros(0)`) as shape (0, *item_shape)."""
    out = np.asarray(array, dtype=float)
    return out.reshape(0, *item_shape) if out.size == 0 else out


@functools.lru_cache(maxsize=16)
def _disk(radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column offsets of a filled disk of `radius` pixels."""
    d = np.arange(-radius, radius + 1)
    dy, dx = np.meshgrid(d, d, indexing="ij")
    inside = dx * dx + dy * dy <= radius * radius + radius
    return dy[inside], dx[inside]


def _stamp(rgb: np.ndarray, rows: np.ndarray, cols: np.ndarray, radius: int, color: np.ndarray) -> None:
    """Paint a disk of `radius` around each (row, col) of `rgb` (H, W, 3, contiguous) in
    place; parts outside the image are skipped."""
    h, w = rgb.shape[:2]
    dy, dx = _disk(radius)
    flat = rgb.reshape(-1, 3)
    inner = (rows >= radius) & (rows < h - radius) & (cols >= radius) & (cols < w - radius)
    # Disks inside the image: flat indices, no bounds check.
    flat[((rows[inner] * w + cols[inner])[:, None] + (dy * w + dx)[None, :]).ravel()] = color
    if not inner.all():
        r = (rows[~inner, None] + dy[None, :]).ravel()
        c = (cols[~inner, None] + dx[None, :]).ravel()
        keep = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        flat[r[keep] * w + c[keep]] = color


@functools.lru_cache(maxsize=4)
def _hatch(h: int, w: int) -> np.ndarray:
    """(H, W) bool, read-only: diagonal lines every HATCH_PERIOD_PX pixels."""
    out = (np.arange(h)[:, None] + np.arange(w)[None, :]) % HATCH_PERIOD_PX == 0
    out.setflags(write=False)
    return out


def _tint_instances(grey: np.ndarray, labels: np.ndarray, instance_plane: np.ndarray | None) -> np.ndarray:
    """RGB (H, W, 3) uint8 of `grey` (H, W) uint8 with the instances of `labels` (H, W)
    tinted, hatched (not accepted) and outlined.

    A pixel's colour depends only on its grey level, its label and whether it lies on a
    contour or a hatching line, so the whole layer is one look-up in a table of
    3 x (K + 1) x 256 RGB entries: key = ((block * (K + 1)) + label + 1) * 256 + grey, with
    block 0 plain, 1 hatching line, 2 contour.
    """
    top = int(labels.max()) if labels.size else -1
    if top < 0:
        return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)
    # Labels >= K (no entry in instance_plane) share one not-accepted row: the table stays
    # small whatever the label values; contours still separate them.
    k = 0 if instance_plane is None else int(instance_plane.shape[0])
    n_labels = min(top + 1, k + 1)
    plane = np.full(n_labels, -1, dtype=np.int64)
    if instance_plane is not None:
        plane[: min(n_labels, k)] = instance_plane[: min(n_labels, k)]
    accepted = plane >= 0
    n1 = n_labels + 1  # rows per block, row 0: no instance

    g = np.arange(256, dtype=np.int64)
    plain = np.repeat(g[None, :, None], 3, axis=2)  # (1, 256, 3) grey levels
    tint = np.where(accepted[:, None], plane_color(plane), REJECTED_TINT).astype(np.int64)
    alpha = np.where(accepted, round(256 * TINT_ALPHA), round(256 * REJECTED_ALPHA))[:, None, None]  # 8-bit fixed point
    tinted = (plain * (256 - alpha) + tint[:, None, :] * alpha + 128) >> 8  # (K, 256, 3)
    table = np.empty((3, n1, 256, 3), dtype=np.uint8)
    table[:, 0] = plain[0]
    table[0, 1:] = tinted
    table[1, 1:] = np.where(accepted[:, None, None], tinted, REJECTED_HATCH)
    table[2, 1:] = np.where(accepted[:, None], plane_color(plane), REJECTED_CONTOUR)[:, None, :]

    key = labels.astype(np.intp)
    if labels.min() < -1 or top >= n_labels:
        np.clip(key, -1, n_labels - 1, out=key)
    key += 1
    # Contour: pixels with a 4-neighbour of another label (row 0 of the block stays grey).
    h, w = labels.shape
    edge = np.zeros((h, w), dtype=bool)
    dh = labels[:, 1:] != labels[:, :-1]
    dv = labels[1:, :] != labels[:-1, :]
    edge[:, 1:] |= dh
    edge[:, :-1] |= dh
    edge[1:, :] |= dv
    edge[:-1, :] |= dv
    np.add(key, 2 * n1, out=key, where=edge)
    if not accepted.all():
        np.add(key, n1, out=key, where=_hatch(h, w) & ~edge)
    key <<= 8
    key |= grey
    return np.take(table.reshape(-1, 3), key, axis=0)


def draw_keyframe_image(
    image_left: np.ndarray,
    *,
    points_uv: np.ndarray,
    point_status: np.ndarray,
    segments_uv: np.ndarray,
    segment_plane: np.ndarray,
    instance_labels: np.ndarray | None,
    instance_plane: np.ndarray | None,
    scale: float = 1.0,
    quality: int = 85,
) -> KeyframeImage:
    """Draw a keyframe's features over its left image and encode the result as JPEG.

    Args:
        image_left: (H, W) uint8 grey, the rectified left image.
        points_uv: (N, 2) pixels (u right, v down) of the keyframe's point features.
        point_status: (N,) uint8, one of POINT_TRACKED, POINT_NEW, POINT_UNUSED,
            POINT_OUTLIER per point.
        segments_uv: (L, 2, 2) start and end pixels of the line segments.
        segment_plane: (L,) map plane id of each segment, -1 for none.
        instance_labels: (H, W) int16 plane-instance masks of the segmenter (-1: no
            instance), or None.
        instance_plane: (K,) map plane id each instance was accepted into (-1: rejected or
            not tested), or None (every instance drawn as not accepted). Labels >= K count
            as not accepted.
        scale: output size / input size (e.g. 0.5); markers and lines keep their size in
            output pixels.
        quality: JPEG quality, 1-100.

    Returns:
        The encoded RGB image and its size in pixels.

    Raises:
        ValueError: on arrays of the wrong shape or type, an unknown point status, a
            non-positive scale or a quality outside 1-100.
    """
    image_left = np.asarray(image_left)
    if image_left.ndim != 2 or image_left.dtype != np.uint8 or image_left.size == 0:
        raise ValueError(f"image_left must be a non-empty (H, W) uint8 grey image, got {image_left.shape} {image_left.dtype}")
    if not (scale > 0 and np.isfinite(scale)):
        raise ValueError(f"scale must be positive, got {scale}")
    if not 1 <= quality <= 100:
        raise ValueError(f"quality must be within 1-100, got {quality}")
    points_uv = _as_float(points_uv, (2,))
    point_status = np.asarray(point_status).reshape(-1)
    if points_uv.ndim != 2 or points_uv.shape[1] != 2 or point_status.shape[0] != points_uv.shape[0]:
        raise ValueError(f"points_uv must be (N, 2) with point_status (N,), got {points_uv.shape} and {point_status.shape}")
    if point_status.size and (point_status.min() < 0 or point_status.max() > POINT_OUTLIER):
        raise ValueError(f"unknown point status {sorted(set(point_status.tolist()) - {0, 1, 2, 3})}")
    segments_uv = _as_float(segments_uv, (2, 2))
    segment_plane = np.asarray(segment_plane).reshape(-1)
    if segments_uv.ndim != 3 or segments_uv.shape[1:] != (2, 2) or segment_plane.shape[0] != segments_uv.shape[0]:
        raise ValueError(f"segments_uv must be (L, 2, 2) with segment_plane (L,), got {segments_uv.shape} and {segment_plane.shape}")
    h0, w0 = image_left.shape
    if instance_labels is not None:
        instance_labels = np.asarray(instance_labels)
        if instance_labels.shape != (h0, w0) or not np.issubdtype(instance_labels.dtype, np.integer):
            raise ValueError(f"instance_labels must be integer {(h0, w0)}, got {instance_labels.shape} {instance_labels.dtype}")
    if instance_plane is not None:
        instance_plane = np.asarray(instance_plane).reshape(-1)

    # Resize (INTER_AREA down, nearest for labels); map pixel centres: u' = (u + ½)·s − ½.
    w, h = max(1, round(w0 * scale)), max(1, round(h0 * scale))
    sx, sy = w / w0, h / h0
    grey = image_left
    if (w, h) != (w0, h0):
        grey = cv2.resize(image_left, (w, h), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
        if instance_labels is not None:
            labels_type = np.int16 if instance_labels.dtype in (np.int8, np.uint8, np.int16) else np.int32
            instance_labels = cv2.resize(instance_labels.astype(labels_type), (w, h), interpolation=cv2.INTER_NEAREST)
    if instance_labels is None:
        rgb = cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)
    else:
        rgb = _tint_instances(grey, instance_labels, instance_plane)

    if segments_uv.shape[0]:
        end_uv = (segments_uv + 0.5) * np.array([sx, sy]) - 0.5
        finite = np.isfinite(end_uv).all(axis=(1, 2))
        fixed = np.round(np.clip(end_uv[finite], -_FAR_PX, _FAR_PX) * (1 << _SHIFT)).astype(np.int32)
        planes = segment_plane[finite]
        for plane in np.unique(planes):  # one call per colour
            color = tuple(int(c) for c in plane_color(int(plane)))
            cv2.polylines(rgb, list(fixed[planes == plane]), False, color, SEGMENT_THICKNESS_PX, cv2.LINE_AA, _SHIFT)

    if points_uv.shape[0]:
        uv = (points_uv + 0.5) * np.array([sx, sy]) - 0.5
        finite = np.isfinite(uv).all(axis=1)
        pixel = np.round(np.clip(uv[finite], -_FAR_PX, _FAR_PX)).astype(np.int64)
        status = point_status[finite]
        for state in _DRAW_ORDER:
            mine = status == state
            if mine.any():
                rows, cols = pixel[mine, 1], pixel[mine, 0]
                _stamp(rgb, rows, cols, POINT_RADII[state] + 1, RIM)
                _stamp(rgb, rows, cols, POINT_RADII[state], POINT_COLORS[state])

    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("cv2.imencode failed to write the keyframe JPEG")
    return KeyframeImage(jpeg=jpeg.tobytes(), width=w, height=h)


def decode_keyframe_image(image: KeyframeImage) -> np.ndarray:
    """The keyframe image as (H, W, 3) uint8 RGB. Raises ValueError if it does not decode."""
    bgr = cv2.imdecode(np.frombuffer(image.jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError("the keyframe image is not a valid JPEG")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
