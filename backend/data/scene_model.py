"""The scene model: textured rectangles (planes with exact ids), spheres and cylinders, and
what a scene carries besides its geometry (its rig, its motion, its exposure schedule), with
the checks a scene must pass and two builders of rectangles. World frame z up, metres.
`backend.data.scenes` builds the built-in scenes from these and reads and writes scene files.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from backend.data.body_motion import Motion
from backend.data.exposure import ExposureSchedule
from backend.data.rigs import EUROC_RIG, Rig
from backend.data.textures import DEFAULT_TEXEL_M, known_kinds, texture_shape

_MAX_PLANE_ID = 32766  # plane masks are int16
MAX_COORDINATE_M = 1e5  # scene coordinates (m): beyond, float32 rendering loses the centimetre
MAX_EXTENT_M = 1e4  # sizes and radii (m)


@dataclasses.dataclass(frozen=True)
class Texture:
    """A procedural texture (`backend.data.textures`): kind, seed and texel size (metres)."""

    kind: str
    seed: int
    texel_m: float = DEFAULT_TEXEL_M


@dataclasses.dataclass(frozen=True, eq=False)
class Rectangle:
    """A textured planar rectangle in the world frame: corner `p0` (3,), unit orthogonal
    axes `u`, `v` (3,), extents `size = (w, h)` metres along u and v, and its plane id."""

    p0: np.ndarray
    u: np.ndarray
    v: np.ndarray
    size: tuple[float, float]
    texture: Texture
    plane_id: int

    @property
    def normal(self) -> np.ndarray:
        """Unit normal `u × v` (3,), world frame."""
        return np.cross(self.u, self.v)

    @property
    def plane(self) -> np.ndarray:
        """`(n, d)` as (4,): `n·X + d = 0` for world points X on the rectangle."""
        n = self.normal
        return np.concatenate([n, [-float(n @ self.p0)]])

    @functools.cached_property
    def texture_shape(self) -> tuple[int, int]:
        """(rows, cols) of its texture image."""
        return texture_shape(self.size[0], self.size[1], texel_m=self.texture.texel_m)

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """World corners (4, 3) in the order p0, p0 + w u, p0 + w u + h v, p0 + h v."""
        w, h = self.size
        corners = np.stack([self.p0, self.p0 + w * self.u, self.p0 + w * self.u + h * self.v, self.p0 + h * self.v])
        corners.setflags(write=False)
        return corners


@dataclasses.dataclass(frozen=True, eq=False)
class Sphere:
    """A sphere (world centre (3,), radius in metres) with base grey `shade` (0..255) and a
    checker of `pattern_cells` cells around its equator."""

    centre: np.ndarray
    radius: float
    shade: float = 170.0
    pattern_cells: int = 8


@dataclasses.dataclass(frozen=True, eq=False)
class Cylinder:
    """A vertical cylinder with caps: axis through world `centre_xy` (2,), radius and
    `z_range = (z0, z1)` metres; grey `shade` and `pattern_cells` checker cells around it."""

    centre_xy: np.ndarray
    radius: float
    z_range: tuple[float, float]
    shade: float = 150.0
    pattern_cells: int = 12


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """Rectangles (drawn in order: later ones win ties, so decals follow their wall),
    spheres and cylinders; `camera_region` is (centre (3,), half_extent (3,)) metres, a box
    of free space where cameras may move (None when unknown), where a random path moves.
    `rig`: the cameras and rates that see it; `motion`: how the body moves; `exposure`: a
    gain schedule of the images (None: constant)."""

    name: str
    rectangles: tuple[Rectangle, ...]
    spheres: tuple[Sphere, ...] = ()
    cylinders: tuple[Cylinder, ...] = ()
    camera_region: tuple[np.ndarray, np.ndarray] | None = None
    rig: Rig = EUROC_RIG
    motion: Motion = Motion()
    exposure: ExposureSchedule | None = None

    def __post_init__(self) -> None:
        _validate(self)

    @functools.cached_property
    def planes(self) -> dict[int, np.ndarray]:
        """Plane table: id -> `(n, d)` (4,), world frame, `n·X + d = 0` (the first
        rectangle's with that id)."""
        table: dict[int, np.ndarray] = {}
        for rect in self.rectangles:
            table.setdefault(rect.plane_id, rect.plane)
        return table


def _validate(scene: Scene) -> None:
    """Raises ValueError with a short reason when the scene is not well formed."""
    planes: dict[int, tuple[int, np.ndarray]] = {}
    for i, rect in enumerate(scene.rectangles):
        where = f"rectangles[{i}]"
        for name in ("p0", "u", "v"):
            value = getattr(rect, name)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise ValueError(f"{where}.{name}: expected 3 finite numbers")
        if abs(np.linalg.norm(rect.u) - 1.0) > 1e-6 or abs(np.linalg.norm(rect.v) - 1.0) > 1e-6:
            raise ValueError(f"{where}: u and v must be unit vectors")
        if abs(float(rect.u @ rect.v)) > 1e-6:
            raise ValueError(f"{where}: u and v must be orthogonal")
        if not (len(rect.size) == 2 and all(math.isfinite(s) and s > 0 for s in rect.size)):
            raise ValueError(f"{where}.size: expected two positive extents (metres)")
        if rect.texture.kind not in known_kinds():
            raise ValueError(f"{where}.texture.kind: unknown {rect.texture.kind!r} (known: {', '.join(known_kinds())})")
        if not (rect.texture.texel_m > 0 and math.isfinite(rect.texture.texel_m)):
            raise ValueError(f"{where}.texture.texel_m: must be positive")
        if not 0 <= rect.plane_id <= _MAX_PLANE_ID:
            raise ValueError(f"{where}.plane_id: must be in 0..{_MAX_PLANE_ID}")
        plane = rect.plane
        if rect.plane_id in planes:
            first, other = planes[rect.plane_id]
            if other[:3] @ plane[:3] < 1.0 - 1e-9 or abs(other[3] - plane[3]) > 1e-6:
                raise ValueError(f"{where}: plane_id {rect.plane_id} is shared with rectangles[{first}] but the two are not coplanar (same side)")
        else:
            planes[rect.plane_id] = (i, plane)
        if np.max(np.abs(rect.p0)) > MAX_COORDINATE_M or max(rect.size) > MAX_EXTENT_M:
            raise ValueError(f"{where}: coordinates within ±{MAX_COORDINATE_M:g} m and sizes up to {MAX_EXTENT_M:g} m")
    for i, sphere in enumerate(scene.spheres):
        if sphere.centre.shape != (3,) or not np.all(np.abs(sphere.centre) <= MAX_COORDINATE_M) or not 0 < sphere.radius <= MAX_EXTENT_M:
            raise ValueError(f"spheres[{i}]: expected a finite centre (3 numbers, within ±{MAX_COORDINATE_M:g} m) and a radius in (0, {MAX_EXTENT_M:g}] m")
    for i, cyl in enumerate(scene.cylinders):
        if cyl.centre_xy.shape != (2,) or not np.all(np.abs(cyl.centre_xy) <= MAX_COORDINATE_M) or not 0 < cyl.radius <= MAX_EXTENT_M:
            raise ValueError(f"cylinders[{i}]: expected a finite centre_xy (2 numbers, within ±{MAX_COORDINATE_M:g} m) and a radius in (0, {MAX_EXTENT_M:g}] m")
        if not (len(cyl.z_range) == 2 and np.all(np.abs(cyl.z_range) <= MAX_COORDINATE_M) and cyl.z_range[0] < cyl.z_range[1]):
            raise ValueError(f"cylinders[{i}].z_range: expected finite [z0, z1] with z0 < z1")
    if scene.camera_region is not None:
        centre, half = (np.asarray(v, dtype=float) for v in scene.camera_region)
        if centre.shape != (3,) or not np.all(np.abs(centre) <= MAX_COORDINATE_M):
            raise ValueError(f"camera_region.centre: expected 3 finite numbers within ±{MAX_COORDINATE_M:g} m")
        if half.shape != (3,) or not np.all((half >= 0) & (half <= MAX_EXTENT_M)):
            raise ValueError(f"camera_region.half_extent: expected 3 numbers in [0, {MAX_EXTENT_M:g}] m")


# ----------------------------------------------------------------------------- builders

Z_UP = np.array([0.0, 0.0, 1.0])


def facing_rectangle(centre: np.ndarray, normal: np.ndarray, size: tuple[float, float], texture: Texture, plane_id: int) -> Rectangle:
    """A rectangle centred at world `centre` whose normal `u × v` is `normal` (it faces
    that way). For non-horizontal normals u is horizontal and v points up; for horizontal
    surfaces u is world x."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    if abs(n[2]) < 0.9:
        u = np.cross(Z_UP, n)
        u /= np.linalg.norm(u)
    else:
        u = np.array([1.0, 0.0, 0.0])
        u -= (u @ n) * n
        u /= np.linalg.norm(u)
    v = np.cross(n, u)
    w, h = size
    p0 = np.asarray(centre, dtype=float) - 0.5 * w * u - 0.5 * h * v
    return Rectangle(p0=p0, u=u, v=v, size=(float(w), float(h)), texture=texture, plane_id=plane_id)


def box_rectangles(centre_xy: tuple[float, float], size: tuple[float, float, float], *, z0: float = 0.0, kind: str, seed: int, first_plane_id: int) -> list[Rectangle]:
    """The five faces (four sides facing out, top facing up) of an axis-aligned box
    standing at height z0; plane ids first_plane_id .. first_plane_id + 4."""
    cx, cy = centre_xy
    sx, sy, sz = size
    zc = z0 + 0.5 * sz
    faces = [
        ((cx + sx / 2, cy, zc), (1, 0, 0), (sy, sz)),
        ((cx - sx / 2, cy, zc), (-1, 0, 0), (sy, sz)),
        ((cx, cy + sy / 2, zc), (0, 1, 0), (sx, sz)),
        ((cx, cy - sy / 2, zc), (0, -1, 0), (sx, sz)),
        ((cx, cy, z0 + sz), (0, 0, 1), (sx, sy)),
    ]
    return [facing_rectangle(np.array(c, float), np.array(n, float), s, Texture(kind, seed * 10 + k), first_plane_id + k) for k, (c, n, s) in enumerate(faces)]
