"""Geometric plane segmentation from rectified stereo, in disparity space.

A plane `n·X + d = 0` of the left camera frame seen in a rectified pair has the disparity
`disp(u, v) = -(f·b / d) (n·x̂)` with `x̂ = ((u - cx)/fx, (v - cy)/fy, 1)`: an affine function
`a·u + b·v + c` of the pixel, and stereo noise is about uniform in disparity, so planes are
fitted there with one pixel threshold for near and far.

Steps (at `1/scale` resolution, labels upsampled at the end): SGBM disparity; affine fits
on small blocks, the flattest blocks (lowest RMS residual) are seeds; each seed grows as a
flood fill that tests every pixel against the region's own affine model (not against its
neighbour): the region is the connected component, containing the seed, of the free pixels
whose residual to the model is below `max_residual_px`; the model is refitted to the region
and the flood repeated until the region stops changing. The first floods use a looser
threshold: a seed's model, fitted on a small block, extrapolates poorly, and a tight
threshold would lock the region into a strip around the seed. Regions under `min_area` are dropped;
regions on the same plane (each model explains the other's pixels) are merged; holes of
invalid disparity inside a region are closed. Each model becomes a 3D plane in the camera
frame.
"""

from __future__ import annotations

import dataclasses

import cv2
import numba
import numpy as np

from backend.frontend.segmentation import NO_PLANE, PlaneMasks
from backend.geometry.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class GeometricSegmenterSettings:
    """Pixel quantities are in full-resolution pixels (disparities too); `min_area` is a share
    of the image."""

    scale: int = 2  # work at 1/scale resolution
    max_disparity_px: int = 96  # SGBM search range (full res): depths down to f·b/96 ≈ 0.5 m on EuRoC
    sgbm_block_size: int = 5
    seed_block_px: int = 32  # side of the blocks fitted for seeds
    seed_max_rms_px: float = 0.4  # RMS disparity residual of a seed block
    max_residual_px: float = 1.0  # a pixel joins a region when |disp - model| is below this
    loose_factor: float = 2.0  # the first `loose_iterations` floods use a threshold this many times larger
    loose_iterations: int = 3
    min_area: float = 0.02
    max_planes: int = 16
    max_iterations: int = 8  # flood + refit rounds per seed, loose ones included
    curved_rms_ratio: float = 0.85  # a region is curved when a quadratic fit has RMS below this share of the affine one
    merge_inlier_share: float = 0.8  # regions merge when each model explains this share of the other,
    merge_angle_deg: float = 10.0  # their normals agree within this angle
    merge_offset: float = 0.1  # and their offsets within this share
    hole_close_px: int = 9  # closing size for invalid-disparity holes inside a region

    def __post_init__(self) -> None:
        if self.scale < 1 or self.max_disparity_px < 16 or self.sgbm_block_size % 2 == 0:
            raise ValueError("scale >= 1, max_disparity_px >= 16 and an odd SGBM block size expected")


class GeometricPlaneSegmenter:
    """`PlaneSegmenter` from stereo disparity (module docstring)."""

    def __init__(self, *, settings: GeometricSegmenterSettings = GeometricSegmenterSettings()) -> None:
        self.settings = settings
        s = settings
        num = int(np.ceil(s.max_disparity_px / s.scale / 16.0)) * 16
        bs = s.sgbm_block_size
        self._sgbm = cv2.StereoSGBM_create(  # type: ignore[attr-defined]  # not in OpenCV's stubs
            minDisparity=0,
            numDisparities=num,
            blockSize=bs,
            P1=8 * bs * bs,
            P2=32 * bs * bs,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=50,
            speckleRange=1,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )

    def disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Left disparity at working resolution, float32 in working-resolution pixels; NaN where
        invalid."""
        s = self.settings
        if left.shape != right.shape or left.ndim != 2 or left.dtype != np.uint8 or right.dtype != np.uint8:
            raise ValueError(f"expected two uint8 (H, W) images of one size, got {left.shape} {left.dtype} and {right.shape} {right.dtype}")
        if s.scale > 1:
            size = (left.shape[1] // s.scale, left.shape[0] // s.scale)
            left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
        # SGBM leaves its first numDisparities columns invalid; pad both images on the left so
        # that every pixel whose match lies inside the right image gets a disparity.
        pad = self._sgbm.getNumDisparities()
        raw = self._sgbm.compute(
            cv2.copyMakeBorder(left, 0, 0, pad, 0, cv2.BORDER_REPLICATE),
            cv2.copyMakeBorder(right, 0, 0, pad, 0, cv2.BORDER_REPLICATE),
        )[:, pad:]
        disp = raw.astype(np.float32) / 16.0
        disp[raw <= 0] = np.nan
        return disp

    def segment(self, left: np.ndarray, right: np.ndarray, camera: PinholeCamera) -> PlaneMasks:
        """Plane instances of the left image, largest first, with their planes in the left
        camera frame (`camera.baseline` must be positive)."""
        if camera.baseline <= 0.0:
            raise ValueError("a stereo camera (baseline > 0) is needed")
        s = self.settings
        disp = self.disparity(left, right)
        # Working pixel (uw, vw) covers full pixels around u = scale·uw + (scale - 1)/2.
        work = PinholeCamera(
            fx=camera.fx / s.scale,
            fy=camera.fy / s.scale,
            cx=(camera.cx - (s.scale - 1) / 2.0) / s.scale,
            cy=(camera.cy - (s.scale - 1) / 2.0) / s.scale,
            width=disp.shape[1],
            height=disp.shape[0],
            baseline=camera.baseline,
        )
        models, labels = _grow_regions(disp, settings=s, camera=work)
        order = np.argsort([-np.count_nonzero(labels == k) for k in range(len(models))], kind="stable")
        remap = np.full(len(models) + 1, NO_PLANE, np.int16)
        remap[order] = np.arange(len(models), dtype=np.int16)
        labels = remap[labels]  # NO_PLANE (-1) indexes the last entry, which stays NO_PLANE
        models = [models[k] for k in order]
        if s.scale > 1:
            full = np.full((left.shape[0], left.shape[1]), NO_PLANE, np.int16)
            up = cv2.resize(labels, (labels.shape[1] * s.scale, labels.shape[0] * s.scale), interpolation=cv2.INTER_NEAREST)
            full[: up.shape[0], : up.shape[1]] = up
            labels = full
        planes = [affine_disparity_to_plane(m, camera=work) for m in models]
        normals = np.array([p[0] for p in planes]).reshape(-1, 3)
        offsets = np.array([p[1] for p in planes]).reshape(-1)
        return PlaneMasks(labels=labels, normals_camera=normals, offsets_camera=offsets)


def affine_disparity_to_plane(model: np.ndarray, *, camera: PinholeCamera) -> tuple[np.ndarray, float]:
    """Disparity `a·u + b·v + c` (pixels of `camera`) to the plane `(n, d)` of the camera frame,
    `n·X + d = 0`, metres, `d > 0`. From `disp = -(fx·b/d) (n·x̂)`: the vector
    `m = (a·fx, b·fy, a·cx + b·cy + c)` equals `-(fx·b/d) n`."""
    a, b, c = (float(x) for x in model)
    m = np.array([a * camera.fx, b * camera.fy, a * camera.cx + b * camera.cy + c])
    norm = float(np.linalg.norm(m))
    return -m / norm, camera.fx * camera.baseline / norm


def plane_to_affine_disparity(n_camera: np.ndarray, d_camera: float, *, camera: PinholeCamera) -> np.ndarray:
    """Inverse of `affine_disparity_to_plane`: `(a, b, c)` of the plane's disparity."""
    k = -camera.fx * camera.baseline / d_camera
    nx, ny, nz = (float(x) for x in n_camera)
    a = k * nx / camera.fx
    b = k * ny / camera.fy
    return np.array([a, b, k * nz - a * camera.cx - b * camera.cy])


def _fit(u: np.ndarray, v: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """Least-squares affine `(a, b, c)` of disparities `d` at pixels `(u, v)` (1-D arrays)."""
    if d.size < 3:
        return None
    uc, vc, dc = u.mean(), v.mean(), d.mean()  # centred for conditioning
    du, dv, dd = u - uc, v - vc, d - dc
    M = np.array([[du @ du, du @ dv], [du @ dv, dv @ dv]])  # float32 for the float32 grids, solved as such
    if _condition_2x2(float(M[0, 0]), float(M[0, 1]), float(M[1, 1])) > 1e8:
        return None
    a, b = np.linalg.solve(M, [du @ dd, dv @ dd])
    return np.array([a, b, dc - a * uc - b * vc])


def _condition_2x2(a: float, b: float, c: float) -> float:
    """2-norm condition number of the symmetric positive semi-definite matrix [[a, b], [b, c]]
    (its eigenvalues' ratio, in closed form: `np.linalg.cond`'s SVD of a 2×2 costs more than
    the rest of a region's fit; inf when singular)."""
    mean = 0.5 * (a + c)
    radius = float(np.hypot(0.5 * (a - c), b))
    low = mean - radius
    return (mean + radius) / low if low > 0.0 else float("inf")


def _curved(u: np.ndarray, v: np.ndarray, d: np.ndarray, model: np.ndarray, *, ratio: float, samples: int = 4000) -> bool:
    """Whether a quadratic in (u, v) explains the disparities `d` much better than the affine
    `model` (a sphere, a cylinder, a bent surface): RMS below `ratio` times the affine RMS."""
    step = max(1, d.size // samples)
    u, v, d = u[::step].astype(np.float64), v[::step].astype(np.float64), d[::step].astype(np.float64)
    affine = d - (model[0] * u + model[1] * v + model[2])
    uc, vc = (u - u.mean()) / 100.0, (v - v.mean()) / 100.0
    A = np.stack([np.ones_like(uc), uc, vc, uc * uc, uc * vc, vc * vc], axis=1)
    coeffs, *_ = np.linalg.lstsq(A, d, rcond=None)
    quadratic = d - A @ coeffs
    return float(np.sqrt(np.mean(quadratic**2))) < ratio * float(np.sqrt(np.mean(affine**2)))


def _seed_blocks(disp: np.ndarray, *, block: int, max_rms: float) -> list[tuple[int, int, np.ndarray]]:
    """Affine fits on a grid of `block`-sized squares: `(row, col, model)` of those fully valid
    with RMS residual below `max_rms`, flattest first."""
    h, w = disp.shape
    hb, wb = h // block, w // block
    D = disp[: hb * block, : wb * block].reshape(hb, block, wb, block).transpose(0, 2, 1, 3).reshape(hb, wb, -1)
    g = np.arange(block, dtype=np.float64) - (block - 1) / 2.0
    gu = np.tile(g, block)  # local u (column) of each block pixel, centred
    gv = np.repeat(g, block)
    ok = np.all(np.isfinite(D), axis=-1)
    Dm = np.where(ok[..., None], D, 0.0).astype(np.float64)
    mean = Dm.mean(axis=-1)
    a = (Dm @ gu) / (gu @ gu)  # centred grid: u, v and 1 are orthogonal
    b = (Dm @ gv) / (gv @ gv)
    res = Dm - mean[..., None] - a[..., None] * gu - b[..., None] * gv
    rms = np.sqrt((res**2).mean(axis=-1))
    rows, cols = np.nonzero(ok & (rms < max_rms))
    order = np.argsort(rms[rows, cols], kind="stable")
    seeds = []
    for r, c in zip(rows[order], cols[order]):
        u0 = c * block + (block - 1) / 2.0
        v0 = r * block + (block - 1) / 2.0
        seeds.append((int(r), int(c), np.array([a[r, c], b[r, c], mean[r, c] - a[r, c] * u0 - b[r, c] * v0])))
    return seeds


def _grow_regions(disp: np.ndarray, *, settings: GeometricSegmenterSettings, camera: PinholeCamera) -> tuple[list[np.ndarray], np.ndarray]:
    """Seeded, plane-checked flood fills (module docstring) on the disparity `disp` of the
    working-resolution `camera`. Returns the affine models and the (h, w) int16 labels
    (NO_PLANE elsewhere) at working resolution."""
    s = settings
    residual = s.max_residual_px / s.scale
    h, w = disp.shape
    valid = np.isfinite(disp)
    disp0 = np.where(valid, disp, 0.0).astype(np.float32)
    v_grid, u_grid = np.mgrid[0:h, 0:w].astype(np.float32)
    block = max(4, s.seed_block_px // s.scale)
    min_pixels = s.min_area * h * w
    labels = np.full((h, w), NO_PLANE, np.int16)
    tried = np.zeros((h // block, w // block), bool)  # seed blocks inside a rejected region
    models: list[np.ndarray] = []
    flat_u, flat_v, flat_disp = u_grid.reshape(-1), v_grid.reshape(-1), disp0.reshape(-1)
    # The flood tests pixels in the model's precision (float64 for a seed's model, float32 once
    # refitted by _fit), as NumPy would on the float32 grids.
    columns, rows = u_grid[0], v_grid[:, 0]
    grids: dict[np.dtype, tuple[np.ndarray, np.ndarray, np.ndarray]] = {
        np.dtype(np.float32): (disp0, columns, rows),
        np.dtype(np.float64): (disp0.astype(np.float64), columns.astype(np.float64), rows.astype(np.float64)),
    }
    flat_labels = labels.reshape(-1)
    in_region = np.zeros(h * w, bool)  # the current region's pixels (scratch, cleared per seed)
    mark = np.zeros((h, w), np.int32)  # the flood's scratch (cleared by each flood)
    stack = np.empty((2 * h * w, 2), np.int32)  # a pixel is pushed at most once from the row above and once from below
    runs = np.empty((h * w, 3), np.int32)
    component = np.empty(h * w, np.int64)
    free = valid.copy()  # valid and in no region yet
    for r, c, model in _seed_blocks(disp, block=block, max_rms=s.seed_max_rms_px / s.scale):
        if len(models) >= s.max_planes:
            break
        seed = (slice(r * block, (r + 1) * block), slice(c * block, (c + 1) * block))
        if tried[r, c] or np.any(labels[seed] != NO_PLANE):
            continue
        region = np.empty(0, np.int64)  # flat indices, in raster order
        for iteration in range(s.max_iterations):
            loose = iteration < s.loose_iterations
            threshold = residual * (s.loose_factor if loose else 1.0)
            if len(region) > LARGE_REGION * h * w:
                # One pass over the whole image costs less than flooding a region this large.
                inliers = free & (np.abs(disp0 - (model[0] * u_grid + model[1] * v_grid + model[2])) < threshold)
                count, components = cv2.connectedComponents(inliers.view(np.uint8), connectivity=4)
                hits = np.bincount(components[seed].ravel(), minlength=count)
                hits[0] = 0
                if hits.max() == 0:
                    break
                grown = np.flatnonzero(components.reshape(-1) == int(hits.argmax()))
            else:
                D, U, V = grids[model.dtype]
                size = _flood(D, free, U, V, model, model.dtype.type(threshold), r * block, (r + 1) * block, c * block, (c + 1) * block, mark, stack, runs, component)
                if size == 0:
                    break
                grown = component[:size].copy()
            overlap = np.count_nonzero(in_region[grown])
            changed = (len(grown) - overlap) + (len(region) - overlap)
            in_region[region] = False
            in_region[grown] = True
            region = grown
            refit = _fit(flat_u[region], flat_v[region], flat_disp[region])
            if refit is None:
                break
            model = refit
            if not loose and changed < 0.005 * len(region):
                break
        in_region[region] = False
        if len(region) < min_pixels or _curved(flat_u[region], flat_v[region], flat_disp[region], model, ratio=s.curved_rms_ratio):
            mask = np.zeros(h * w, bool)
            mask[region] = True
            big = mask.reshape(h, w)[: tried.shape[0] * block, : tried.shape[1] * block]
            tried |= big.reshape(tried.shape[0], block, tried.shape[1], block).any(axis=(1, 3))
            tried[r, c] = True
            continue
        flat_labels[region] = len(models)
        free.reshape(-1)[region] = False
        models.append(model)
    models, labels = _merge_coplanar(models, labels, disp0=disp0, u_grid=u_grid, v_grid=v_grid, residual=residual, settings=s, camera=camera)
    _close_holes(labels, valid=valid, size=max(3, s.hole_close_px // s.scale | 1))
    return models, labels


LARGE_REGION = 0.2  # share of the image above which a region grows by one pass over the image, not a flood


@numba.njit(cache=True, nogil=True)
def _flood(  # pragma: no cover - compiled
    disp: np.ndarray,
    free: np.ndarray,
    columns: np.ndarray,
    rows: np.ndarray,
    model: np.ndarray,
    threshold: float,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    mark: np.ndarray,
    stack: np.ndarray,
    runs: np.ndarray,
    out: np.ndarray,
) -> int:
    """The 4-connected component of the pixels that fit the affine disparity model, chosen
    as `cv2.connectedComponents` over the whole image and the most hits in the seed block
    would choose it, found by flooding (a scanline fill) only the components that touch
    the block.

    A pixel (row y, column x) fits when it is `free` and `|disp - (a·u + b·v + c)| <
    threshold`, `model` = (a, b, c), `u` = `columns[x]`, `v` = `rows[y]`, evaluated in the
    model's precision and order as NumPy evaluates it on the float32 grids: `disp` (h, w)
    and `columns`, `rows` in the model's dtype, `threshold` too. The seed block is rows
    `r0:r1`, columns `c0:c1`. The component with the most pixels in the block wins, a tie
    going to the one whose first pixel in raster order comes first (the order of OpenCV's
    labels). `mark` (h, w; zeros), `stack` (2·h·w, 2) and `runs` (h·w, 3) are scratch,
    `mark` left zero. Writes the chosen component's flat indices in raster order to `out` (h·w)
    and returns their number (0: no pixel of the block fits)."""
    h, w = disp.shape
    a, b, c = model[0], model[1], model[2]
    au = a * columns  # a·u of every column, b·v of every row: the same products as NumPy's
    bv = b * rows

    def fits(y: int, x: int) -> bool:  # not yet flooded, free, and on the model
        return mark[y, x] == 0 and free[y, x] and abs(disp[y, x] - (au[x] + bv[y] + c)) < threshold

    n_runs = 0
    label = 0
    best_label, best_hits, best_first = 0, 0, h * w
    best_box = (0, 0, 0, 0)
    for y in range(r0, r1):
        for x in range(c0, c1):
            if not fits(y, x):
                continue
            label += 1
            hits = 0
            first = y * w + x
            y0, y1, x0, x1 = y, y, x, x
            stack[0, 0], stack[0, 1] = y, x
            top = 1
            while top > 0:
                top -= 1
                sy, sx = stack[top, 0], stack[top, 1]
                if mark[sy, sx] != 0:
                    continue
                left, right = sx, sx
                while left > 0 and fits(sy, left - 1):
                    left -= 1
                while right < w - 1 and fits(sy, right + 1):
                    right += 1
                for xx in range(left, right + 1):
                    mark[sy, xx] = label
                runs[n_runs, 0], runs[n_runs, 1], runs[n_runs, 2] = sy, left, right
                n_runs += 1
                if r0 <= sy < r1:
                    hits += max(0, min(right + 1, c1) - max(left, c0))
                first = min(first, sy * w + left)
                y0, y1, x0, x1 = min(y0, sy), max(y1, sy), min(x0, left), max(x1, right)
                for side in range(2):
                    ny = sy - 1 if side == 0 else sy + 1
                    if ny < 0 or ny >= h:
                        continue
                    xx = left
                    while xx <= right:
                        if fits(ny, xx):
                            stack[top, 0], stack[top, 1] = ny, xx
                            top += 1
                            xx += 1
                            while xx <= right and fits(ny, xx):
                                xx += 1
                        xx += 1
            if hits > best_hits or (hits == best_hits and first < best_first):
                best_label, best_hits, best_first, best_box = label, hits, first, (y0, y1, x0, x1)
    size = 0
    if best_label > 0:
        y0, y1, x0, x1 = best_box
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if mark[y, x] == best_label:
                    out[size] = y * w + x
                    size += 1
    for t in range(n_runs):
        for x in range(runs[t, 1], runs[t, 2] + 1):
            mark[runs[t, 0], x] = 0
    return size


def _merge_coplanar(
    models: list[np.ndarray], labels: np.ndarray, *, disp0: np.ndarray, u_grid: np.ndarray, v_grid: np.ndarray, residual: float, settings: GeometricSegmenterSettings, camera: PinholeCamera
) -> tuple[list[np.ndarray], np.ndarray]:
    """Merge regions whose models each explain `merge_inlier_share` of the other's pixels and
    whose 3D planes agree within `merge_angle_deg` and `merge_offset` (relative); in place on
    `labels`. Returns the surviving models and the relabelled labels (0..K-1)."""
    k = len(models)
    share = settings.merge_inlier_share
    planes = [affine_disparity_to_plane(m, camera=camera) for m in models]
    cos_max = np.cos(np.radians(settings.merge_angle_deg))
    pixels = [np.nonzero(labels == i) for i in range(k)]
    parent = list(range(k))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    def explains(i: int, j: int) -> bool:
        vv, uu = pixels[j]
        m = models[i]
        return float(np.mean(np.abs(disp0[vv, uu] - (m[0] * uu + m[1] * vv + m[2])) < residual)) >= share

    for i in range(k):
        for j in range(i + 1, k):
            (ni, di), (nj, dj) = planes[i], planes[j]
            same = float(ni @ nj) > cos_max and abs(di - dj) < settings.merge_offset * max(di, dj)
            if same and root(i) != root(j) and explains(i, j) and explains(j, i):
                parent[root(j)] = root(i)
    roots = sorted({root(i) for i in range(k)})
    new_index = {r: n for n, r in enumerate(roots)}
    remap = np.full(k + 1, NO_PLANE, np.int16)
    for i in range(k):
        remap[i] = new_index[root(i)]
    labels[:] = remap[labels]
    merged = []
    for r in roots:
        region = labels == new_index[r]
        fit = _fit(u_grid[region], v_grid[region], disp0[region]) if len(roots) < k else None
        merged.append(fit if fit is not None else models[r])
    return merged, labels


def _close_holes(labels: np.ndarray, *, valid: np.ndarray, size: int) -> None:
    """Give unlabelled pixels without a valid disparity to the region whose morphological
    closing covers them (in place)."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    for i in range(int(labels.max(initial=NO_PLANE)) + 1):
        closed = cv2.morphologyEx((labels == i).view(np.uint8), cv2.MORPH_CLOSE, kernel).astype(bool)
        labels[closed & ~valid & (labels == NO_PLANE)] = i
