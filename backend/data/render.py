"""Render a camera view of a `Scene`: grayscale image, exact depth and plane-instance mask.

Planar rectangles use homographies, not per-pixel ray casting: texture coordinates map to
pixels by a 3×3 homography, so each rectangle is one `cv2.warpPerspective` over the pixel
bounding box of its projection (clipped to the near plane and the view frustum), masked by
the filled projected polygon. Its depth is analytic: for a plane `(n_c, d_c)` in the camera
frame, `1/z = -(n_c · K⁻¹[u v 1]ᵀ) / d_c` is affine in the pixel (u, v). A z-buffer
composites everything; later rectangles win ties, so decals cover the wall they lie on.
Spheres and vertical cylinders are ray-cast per pixel inside their projected bounding box.
Before any of that, one vectorized test over the whole scene skips what lies entirely
outside the view frustum (`_in_frustum`: conservative, so the picture is the same as
without it), which keeps scenes of hundreds of objects (`street`) fast.

Conventions (DESIGN §2): OpenCV pinhole camera (x right, y down, z forward), pixel centres
at integer coordinates, `X_w = R_world_camera X_c + t_world_camera`, metres.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import cv2
import numpy as np

from backend.data.rigs import R_BODY_CAMERA_FORWARD as R_BODY_CAMERA_FORWARD  # where it has always been imported from
from backend.data.scenes import Cylinder, Rectangle, Scene, Sphere
from backend.data.textures import texture_pyramid
from backend.geometry.camera import PinholeCamera

NEAR_M = 0.05
BACKGROUND_GREY = 128
NON_PLANAR_ID = -1
_LIGHT_WORLD = np.array([0.35, 0.25, 1.0]) / np.linalg.norm([0.35, 0.25, 1.0])
_FRUSTUM_MARGIN_PX = 2.0
_TIE = np.float32(1.0 + 1e-5)


class View(NamedTuple):
    """One rendered view: `image` (H, W) uint8; `depth` (H, W) float32, metres along the
    camera z axis, inf where nothing is hit; `plane_id` (H, W) int16, the rectangle's plane
    id, -1 on spheres, cylinders and background."""

    image: np.ndarray
    depth: np.ndarray
    plane_id: np.ndarray


def _clip_planes(camera: PinholeCamera) -> np.ndarray:
    """Half-spaces `a·X_c + b >= 0` (5, 4) of the near plane and the four image borders
    (widened by a small margin), camera frame."""
    m = _FRUSTUM_MARGIN_PX
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    w1, h1 = camera.width - 1 + m, camera.height - 1 + m
    return np.array(
        [
            [0.0, 0.0, 1.0, -NEAR_M],
            [fx, 0.0, cx + m, 0.0],
            [-fx, 0.0, w1 - cx, 0.0],
            [0.0, fy, cy + m, 0.0],
            [0.0, -fy, h1 - cy, 0.0],
        ]
    )


def clip_polygon(points: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the convex polygon `points` (N, 3) clipped to the half-spaces
    `a·X + b >= 0` given as rows `(a, b)` of `planes` (P, 4); (M, 3), possibly empty."""
    poly = points
    for plane in planes:
        if len(poly) == 0:
            break
        s = poly @ plane[:3] + plane[3]
        inside = s >= 0
        if inside.all():
            continue
        if not inside.any():
            return poly[:0]
        out = []
        n = len(poly)
        for i in range(n):
            j = (i + 1) % n
            if inside[i]:
                out.append(poly[i])
            if inside[i] != inside[j]:
                a = s[i] / (s[i] - s[j])
                out.append(poly[i] + a * (poly[j] - poly[i]))
        poly = np.array(out)
    return poly


def _composite(view: View, x0: int, y0: int, z: np.ndarray, mask: np.ndarray, shade: np.ndarray, plane_id: int) -> None:
    """z-test the patch (at pixel offset x0, y0) against the view and write where it wins."""
    h, w = z.shape
    zb = view.depth[y0 : y0 + h, x0 : x0 + w]
    sel = mask & (z <= zb * _TIE)
    np.copyto(zb, z, where=sel)
    np.copyto(view.image[y0 : y0 + h, x0 : x0 + w], shade, where=sel)
    view.plane_id[y0 : y0 + h, x0 : x0 + w][sel] = plane_id


def _draw_rectangle(view: View, rect: Rectangle, plane_world: np.ndarray, camera: PinholeCamera, K: np.ndarray, R_camera_world: np.ndarray, t_world_camera: np.ndarray, clip: np.ndarray) -> None:
    corners_camera = (rect.corners - t_world_camera) @ R_camera_world.T
    # quick reject: all corners outside one half-space
    s = corners_camera @ clip[:, :3].T + clip[:, 3]
    if np.any(np.all(s < 0, axis=0)):
        return
    poly_camera = clip_polygon(corners_camera, clip)
    if len(poly_camera) < 3:
        return
    uv = poly_camera[:, :2] / poly_camera[:, 2:3] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    x0 = max(int(np.floor(uv[:, 0].min())), 0)
    y0 = max(int(np.floor(uv[:, 1].min())), 0)
    x1 = min(int(np.ceil(uv[:, 0].max())) + 1, camera.width)
    y1 = min(int(np.ceil(uv[:, 1].max())) + 1, camera.height)
    if x1 <= x0 or y1 <= y0:
        return
    # plane in the camera frame; 1/z affine in (u, v)
    n_camera = R_camera_world @ plane_world[:3]
    d_camera = float(plane_world[3] + plane_world[:3] @ t_world_camera)
    if abs(d_camera) < 1e-9:
        return  # seen edge-on
    a = -n_camera[0] / (camera.fx * d_camera)
    b = -n_camera[1] / (camera.fy * d_camera)
    c = -(n_camera[2] - n_camera[0] * camera.cx / camera.fx - n_camera[1] * camera.cy / camera.fy) / d_camera
    us = np.arange(x0, x1, dtype=np.float32)
    vs = np.arange(y0, y1, dtype=np.float32)
    inv_z = np.float32(a) * us[None, :] + (np.float32(b) * vs + np.float32(c))[:, None]
    np.maximum(inv_z, np.float32(1e-6), out=inv_z)
    z = np.reciprocal(inv_z)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    pts = np.round((uv - [x0, y0]) * 16.0).astype(np.int32)
    cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=4)
    # texture pyramid level: about one texel per pixel at the polygon's typical depth
    rows, cols = rect.texture_shape
    w_m, h_m = rect.size
    sx, sy = w_m / cols, h_m / rows
    zs = poly_camera[:, 2]
    texels_per_px = np.sqrt(zs.min() * zs.max()) / (min(camera.fx, camera.fy) * min(sx, sy))
    pyramid = texture_pyramid(rect.texture.kind, rect.texture.seed, rows, cols)
    level = int(np.clip(np.round(np.log2(max(texels_per_px, 1e-9))), 0, len(pyramid) - 1))
    scale = float(2**level)
    # texel (s, t) of the level -> world p0 + u sx (2^L s + 1/2) + v sy (2^L t + 1/2)
    A_world = np.column_stack([rect.u * sx * scale, rect.v * sy * scale, rect.p0 + 0.5 * (rect.u * sx + rect.v * sy) - t_world_camera])
    H_image_texture = K @ (R_camera_world @ A_world)
    H_bbox_texture = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]]) @ H_image_texture
    H_texture_bbox = np.linalg.inv(H_bbox_texture)
    shade = cv2.warpPerspective(pyramid[level], H_texture_bbox, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    _composite(view, x0, y0, z, mask.view(bool), shade, rect.plane_id)


_BOX_FACES = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))


def _bbox_of_box(lo_world: np.ndarray, hi_world: np.ndarray, camera: PinholeCamera, R_camera_world: np.ndarray, t_world_camera: np.ndarray, clip: np.ndarray) -> tuple[int, int, int, int] | None:
    """Pixel bounding box (x0, y0, x1, y1) of the axis-aligned world box [lo, hi] clipped
    to the near plane and the view frustum (each face clipped, vertices united); None when
    nothing of it is in view."""
    corners = np.array([[x, y, z] for x in (lo_world[0], hi_world[0]) for y in (lo_world[1], hi_world[1]) for z in (lo_world[2], hi_world[2])])
    corners_camera = (corners - t_world_camera) @ R_camera_world.T
    s = corners_camera @ clip[:, :3].T + clip[:, 3]
    if np.any(np.all(s < 0, axis=0)):
        return None
    if np.all(s >= 0):
        points = corners_camera
    else:
        pieces = [clip_polygon(corners_camera[list(face)], clip) for face in _BOX_FACES]
        pieces = [p for p in pieces if len(p)]
        if not pieces:
            return None
        points = np.concatenate(pieces)
    uv = camera.project(points)
    x0, y0 = max(int(np.floor(uv[:, 0].min())), 0), max(int(np.floor(uv[:, 1].min())), 0)
    x1, y1 = min(int(np.ceil(uv[:, 0].max())) + 1, camera.width), min(int(np.ceil(uv[:, 1].max())) + 1, camera.height)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _rays(camera: PinholeCamera, x0: int, y0: int, x1: int, y1: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalized ray coordinates x̂ (1, w) and ŷ (h, 1) of a pixel box (the ray is (x̂, ŷ, 1))."""
    xs = ((np.arange(x0, x1) - camera.cx) / camera.fx)[None, :]
    ys = ((np.arange(y0, y1) - camera.cy) / camera.fy)[:, None]
    return xs, ys


def _checker(angle: np.ndarray, other: np.ndarray, cells: int) -> np.ndarray:
    """0/1 checker of `cells` cells per turn of `angle` (rad) and unit cells of `other`."""
    return (np.floor(angle * (cells / (2 * np.pi))) + np.floor(other)).astype(np.int64) % 2


def _draw_sphere(view: View, sphere: Sphere, camera: PinholeCamera, R_camera_world: np.ndarray, t_world_camera: np.ndarray, clip: np.ndarray) -> None:
    r = sphere.radius
    box = _bbox_of_box(sphere.centre - r, sphere.centre + r, camera, R_camera_world, t_world_camera, clip)
    if box is None:
        return
    x0, y0, x1, y1 = box
    xs, ys = _rays(camera, x0, y0, x1, y1)
    c = R_camera_world @ (sphere.centre - t_world_camera)
    A = xs**2 + ys**2 + 1.0
    B = xs * c[0] + ys * c[1] + c[2]
    disc = B**2 - A * (c @ c - r * r)
    hit = disc > 0
    z = (B - np.sqrt(np.maximum(disc, 0.0))) / A
    hit &= z > NEAR_M
    if not hit.any():
        return
    R_world_camera = R_camera_world.T
    p_world = [R_world_camera[i, 0] * z * xs + R_world_camera[i, 1] * z * ys + R_world_camera[i, 2] * z + t_world_camera[i] for i in range(3)]
    n = [(p_world[i] - sphere.centre[i]) / r for i in range(3)]
    lambert = np.maximum(n[0] * _LIGHT_WORLD[0] + n[1] * _LIGHT_WORLD[1] + n[2] * _LIGHT_WORLD[2], 0.0)
    lat = np.arcsin(np.clip(n[2], -1.0, 1.0))
    pattern = _checker(np.arctan2(n[1], n[0]), lat * (sphere.pattern_cells / (2 * np.pi)), sphere.pattern_cells)
    shade = sphere.shade * (0.3 + 0.7 * lambert) * (0.5 + 0.5 * pattern)
    _composite(view, x0, y0, z.astype(np.float32), hit, np.clip(shade, 0, 255).astype(np.uint8), NON_PLANAR_ID)


def _draw_cylinder(view: View, cyl: Cylinder, camera: PinholeCamera, R_camera_world: np.ndarray, t_world_camera: np.ndarray, clip: np.ndarray) -> None:
    r = cyl.radius
    z0, z1 = cyl.z_range
    cx, cy = cyl.centre_xy
    box = _bbox_of_box(np.array([cx - r, cy - r, z0]), np.array([cx + r, cy + r, z1]), camera, R_camera_world, t_world_camera, clip)
    if box is None:
        return
    x0, y0, x1, y1 = box
    xs, ys = _rays(camera, x0, y0, x1, y1)
    axis = R_camera_world[:, 2]  # world z in the camera frame
    base = R_camera_world @ (np.array([cx, cy, z0]) - t_world_camera)
    q = base - (base @ axis) * axis  # the axis point closest to the camera centre
    ray_axis = xs * axis[0] + ys * axis[1] + axis[2]
    A = xs**2 + ys**2 + 1.0 - ray_axis**2
    B = xs * q[0] + ys * q[1] + q[2]
    disc = B**2 - A * (q @ q - r * r)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_side = (B - np.sqrt(np.maximum(disc, 0.0))) / A
        height = z_side * ray_axis - base @ axis
        z_side = np.where((disc > 0) & (A > 1e-12) & (height >= 0) & (height <= z1 - z0) & (z_side > NEAR_M), z_side, np.inf)
        z_best = z_side
        is_cap = np.zeros(z_side.shape, bool)
        for h_cap in (0.0, z1 - z0):
            z_cap = (h_cap + base @ axis) / ray_axis
            # point on the ray minus the axis point at the cap's height, squared length
            px = z_cap * xs - base[0] - h_cap * axis[0]
            py = z_cap * ys - base[1] - h_cap * axis[1]
            pz = z_cap - base[2] - h_cap * axis[2]
            radial2 = px**2 + py**2 + pz**2
            ok = (radial2 <= r * r) & (z_cap > NEAR_M) & (z_cap < z_best)
            z_best = np.where(ok, z_cap, z_best)
            is_cap |= ok
    hit = np.isfinite(z_best)
    if not hit.any():
        return
    z = np.where(hit, z_best, 1.0)
    R_world_camera = R_camera_world.T
    p_world = [R_world_camera[i, 0] * z * xs + R_world_camera[i, 1] * z * ys + R_world_camera[i, 2] * z + t_world_camera[i] for i in range(3)]
    dx, dy = (p_world[0] - cx) / r, (p_world[1] - cy) / r
    angle = np.arctan2(dy, dx)
    cells = cyl.pattern_cells
    side_lambert = np.maximum(dx * _LIGHT_WORLD[0] + dy * _LIGHT_WORLD[1], 0.0)
    side_pattern = _checker(angle, (p_world[2] - z0) * cells / (2 * np.pi * r), cells)
    cap_pattern = _checker(angle, np.sqrt(dx**2 + dy**2) * 2.0, cells)
    lambert = np.where(is_cap, _LIGHT_WORLD[2], side_lambert)
    pattern = np.where(is_cap, cap_pattern, side_pattern)
    shade = cyl.shade * (0.3 + 0.7 * lambert) * (0.5 + 0.5 * pattern)
    _composite(view, x0, y0, z.astype(np.float32), hit, np.clip(shade, 0, 255).astype(np.uint8), NON_PLANAR_ID)


@functools.lru_cache(maxsize=16)
def _scene_hulls(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World corners of every rectangle (R, 4, 3), and of every sphere's and cylinder's
    axis-aligned bounding box ((S, 8, 3), (C, 8, 3)): what `_in_frustum` tests."""

    def box(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    rects = np.array([r.corners for r in scene.rectangles]).reshape(-1, 4, 3)
    spheres = np.array([box(s.centre - s.radius, s.centre + s.radius) for s in scene.spheres]).reshape(-1, 8, 3)
    cylinders = np.array([box(np.array([*(c.centre_xy - c.radius), c.z_range[0]]), np.array([*(c.centre_xy + c.radius), c.z_range[1]])) for c in scene.cylinders]).reshape(-1, 8, 3)
    return rects, spheres, cylinders


def _in_frustum(corners_world: np.ndarray, R_camera_world: np.ndarray, t_world_camera: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """(M,) False where all corners of a hull (M, K, 3) lie outside one clip half-space by
    more than rounding can explain: nothing of it can be drawn (the drawing functions then
    reject it too); True otherwise."""
    corners_camera = (corners_world - t_world_camera) @ R_camera_world.T
    s = corners_camera @ clip[:, :3].T + clip[:, 3]
    margin = 1e-9 * (np.linalg.norm(corners_camera, axis=2, keepdims=True) * np.linalg.norm(clip[:, :3], axis=1) + np.abs(clip[:, 3]) + 1.0)
    return ~np.any(np.all(s < -margin, axis=1), axis=1)


def render_view(
    scene: Scene,
    camera: PinholeCamera,
    R_world_camera: np.ndarray,
    t_world_camera: np.ndarray,
    *,
    gain: float = 1.0,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
) -> View:
    """Render the view of `camera` at pose `T_world_camera = (R_world_camera, t_world_camera)`.

    Image effects, applied in this order: exposure `gain` (multiplies intensities), Gaussian
    blur of `blur_sigma_px` pixels, additive Gaussian noise of `noise_sigma` grey levels
    drawn from `rng` (required when noise_sigma > 0, so results are reproducible). Depth and
    plane ids are unaffected by them.
    """
    R_world_camera = np.asarray(R_world_camera, dtype=float)
    t_world_camera = np.asarray(t_world_camera, dtype=float).reshape(3)
    R_camera_world = R_world_camera.T
    H, W = camera.height, camera.width
    view = View(
        image=np.full((H, W), BACKGROUND_GREY, np.uint8),
        depth=np.full((H, W), np.inf, np.float32),
        plane_id=np.full((H, W), NON_PLANAR_ID, np.int16),
    )
    K = camera.K
    clip = _clip_planes(camera)
    planes = scene.planes
    rect_hulls, sphere_hulls, cylinder_hulls = _scene_hulls(scene)
    for rect, seen in zip(scene.rectangles, _in_frustum(rect_hulls, R_camera_world, t_world_camera, clip)):
        if seen:
            _draw_rectangle(view, rect, planes[rect.plane_id], camera, K, R_camera_world, t_world_camera, clip)
    for sphere, seen in zip(scene.spheres, _in_frustum(sphere_hulls, R_camera_world, t_world_camera, clip)):
        if seen:
            _draw_sphere(view, sphere, camera, R_camera_world, t_world_camera, clip)
    for cyl, seen in zip(scene.cylinders, _in_frustum(cylinder_hulls, R_camera_world, t_world_camera, clip)):
        if seen:
            _draw_cylinder(view, cyl, camera, R_camera_world, t_world_camera, clip)
    if gain != 1.0 or blur_sigma_px > 0 or noise_sigma > 0:
        image: np.ndarray = view.image.astype(np.float32)  # float32 throughout (OpenCV's stubs type the blur's result as any numeric array)
        if gain != 1.0:
            image *= np.float32(gain)
        if blur_sigma_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
        if noise_sigma > 0:
            if rng is None:
                raise ValueError("noise_sigma > 0 needs an rng (numpy Generator) for reproducible noise")
            image += rng.normal(0.0, noise_sigma, image.shape).astype(np.float32)
        view = view._replace(image=np.clip(np.round(image), 0, 255).astype(np.uint8))
    return view


def look_at(eye_world: np.ndarray, target_world: np.ndarray, *, up_world: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """`R_world_camera` of a camera at `eye_world` whose optical axis (z) points at
    `target_world`, with image y (down) as close to `-up_world` as possible."""
    z = np.asarray(target_world, dtype=float) - np.asarray(eye_world, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up_world)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction parallel to up_world")
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def right_camera_pose(camera: PinholeCamera, R_world_left: np.ndarray, t_world_left: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`T_world_right` of the rectified stereo partner: same rotation, centre `baseline`
    metres along the left camera's +x axis."""
    R = np.asarray(R_world_left, dtype=float)
    return R, np.asarray(t_world_left, dtype=float).reshape(3) + R @ camera.offset_right


def render_stereo(
    scene: Scene,
    camera: PinholeCamera,
    R_world_left: np.ndarray,
    t_world_left: np.ndarray,
    *,
    gain: float = 1.0,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
) -> tuple[View, View]:
    """Left and right views of a rectified stereo pair (`camera.baseline` metres apart
    along the left camera's x axis), same intrinsics and image effects (noise drawn for the
    left image first)."""
    left = render_view(scene, camera, R_world_left, t_world_left, gain=gain, blur_sigma_px=blur_sigma_px, noise_sigma=noise_sigma, rng=rng)
    R_world_right, t_world_right = right_camera_pose(camera, R_world_left, t_world_left)
    right = render_view(scene, camera, R_world_right, t_world_right, gain=gain, blur_sigma_px=blur_sigma_px, noise_sigma=noise_sigma, rng=rng)
    return left, right
