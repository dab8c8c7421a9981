"""The `street` scene: a KITTI-like drive around a city block.

The car's loop (`street_loop`, a `backend.data.road.RoadLoop`: straights of 160 m and
100 m joined by rounded corners of 56 m of arc, driven counter-clockwise at 8.5–14 m/s)
runs round a block centred on the world origin; the road is the plane z = 0 and the rig is
KITTI-like (`backend.data.rigs.KITTI_RIG`: 1241×376 px, f ≈ 718 px, baseline 0.54 m, 10 Hz)
with its left camera 1.65 m above the road. Along each straight, in the straight's own
frame (x along the driving direction from its start, y to the left, the car's path at
y = 0 in the right lane; metres):

- the street, 19 m across (y ∈ [-7.75, 11.25]): sidewalks, curbs, parking lanes and two
  lanes with a dashed centre line (`road` texture), on the ground plane (plane 0) with the
  junction squares where the loop turns (`asphalt`) and a paved ground under everything;
- building fronts on both sides (`facade`: rows of windows), 10–24 m wide and 9–24 m
  high, set back 0–3 m behind the sidewalk, with the side walls their set-backs expose and
  end walls where a row stops: the outer rows leave a cross street at each corner, the
  inner rows leave the inside of each turn open (a small square with trees);
- parked cars (boxes of 4.2–4.8 × 1.8 × 1.45 m) in both parking lanes and trees (a trunk
  cylinder and a crown sphere) along the sidewalks.

Seen from the car, nearly all of it lies 6–80 m away: the road from 6 m (the image's
bottom row), the façades from 8 m across the street to the end of the straight.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from backend.data.body_motion import Motion
from backend.data.rigs import KITTI_RIG
from backend.data.road import RoadLoop
from backend.data.scene_model import Cylinder, Rectangle, Scene, Sphere, Texture, box_rectangles, facing_rectangle

CAMERA_HEIGHT_M = 1.65  # the left camera above the road, as KITTI's
STRAIGHTS_M = (160.0, 100.0)
CORNER_M = 56.0
SPEED_MPS = (8.5, 14.0)  # in the corners, on the straights
STREET_RIGHT_M, STREET_LEFT_M = -7.75, 11.25  # the street's edges (building lines) across the car's path
SIDEWALK_M = 3.5
PARKING_Y_M = (-3.0, 6.5)  # the parking lanes' middles
TREE_Y_M = (-6.5, 9.8)  # the sidewalks' tree lines
INNER_MARGIN_M = 8.0  # the inner rows stop this far before a corner
CAR_MODELS = ((4.2, "panels"), (4.4, "poster"), (4.5, "tiles"), (4.6, "panels"), (4.8, "poster"), (4.3, "door"))
CAR_WIDTH_M, CAR_HEIGHT_M = 1.8, 1.45


def street_loop() -> RoadLoop:
    """The car's loop, centred on the origin, the body at the KITTI rig's height."""
    probe = RoadLoop(straights_m=STRAIGHTS_M, corner_m=CORNER_M, speed_mps=SPEED_MPS)
    d = probe.corner_offset_m
    body_height = CAMERA_HEIGHT_M - float(KITTI_RIG.T_body_cam0[2, 3])
    return dataclasses.replace(probe, origin=(-STRAIGHTS_M[0] / 2.0, -STRAIGHTS_M[1] / 2.0 - d), height_m=body_height)


@dataclasses.dataclass(frozen=True, eq=False)
class _Straight:
    """A straight's frame: world `start` (2,), `heading` (rad), `length` (m)."""

    start: np.ndarray
    heading: float
    length: float

    @property
    def along(self) -> np.ndarray:
        """World direction (3,) of driving."""
        return np.array([math.cos(self.heading), math.sin(self.heading), 0.0])

    @property
    def left(self) -> np.ndarray:
        """World direction (3,) to the driver's left."""
        return np.array([-math.sin(self.heading), math.cos(self.heading), 0.0])

    def world(self, x: float, y: float, z: float = 0.0) -> np.ndarray:
        """The world point (3,) at x along, y left, z up (m)."""
        return np.array([self.start[0], self.start[1], 0.0]) + x * self.along + y * self.left + np.array([0.0, 0.0, z])


class _Ids:
    """Plane ids handed out in order (0 is the ground)."""

    def __init__(self) -> None:
        self.next = 1

    def take(self, n: int = 1) -> int:
        first = self.next
        self.next += n
        return first


def _ground(straights: list[_Straight], d: float) -> list[Rectangle]:
    """The ground plane (plane 0) where it can be seen: the street strips in pieces of at
    most 40 m, the junction squares where the loop turns, with the cross street beyond each
    (30 m of it), and the paved square inside each turn."""
    rects = []
    width = STREET_LEFT_M - STREET_RIGHT_M
    cross = 30.0
    for k, st in enumerate(straights):
        pieces = math.ceil(st.length / 40.0)
        step = st.length / pieces
        for i in range(pieces):
            rects.append(Rectangle(st.world(i * step, STREET_RIGHT_M), st.along, st.left, (step, width), Texture("road", 510 + 10 * k + i, 0.025), 0))
        side = d - STREET_RIGHT_M
        rects.append(Rectangle(st.world(st.length, STREET_RIGHT_M - cross), st.along, st.left, (side + cross, side + cross), Texture("asphalt", 560 + k, 0.04), 0))
        square = (INNER_MARGIN_M + d - STREET_LEFT_M, d + INNER_MARGIN_M - STREET_LEFT_M)
        rects.append(Rectangle(st.world(st.length - INNER_MARGIN_M, STREET_LEFT_M), st.along, st.left, square, Texture("tiles", 570 + k, 0.03), 0))
    return rects


def _row(st: _Straight, x0: float, x1: float, *, side: int, rng: np.random.Generator, ids: _Ids, seed: int, end_walls: bool) -> list[Rectangle]:
    """Building fronts between x0 and x1 on the left (`side` 1) or right (-1) of the street,
    with the side walls their set-backs expose to a car driving along (walls that only a
    car driving the other way would see are left out) and, with `end_walls`, a wall at each
    end of the row (12 m deep)."""
    line = STREET_LEFT_M if side > 0 else STREET_RIGHT_M
    facing = -side * st.left  # towards the street
    buildings: list[tuple[float, float, float, float]] = []  # x, width, set-back, height
    x = x0
    while x < x1 - 1e-6:
        w = float(rng.uniform(10.0, 24.0))
        if x1 - (x + w) < 6.0:
            w = x1 - x
        buildings.append((x, w, float(rng.choice([0.0, 0.0, 0.0, 1.5, 3.0])), float(rng.uniform(9.0, 24.0))))
        x += w
    rects = []
    for i, (x, w, back, h) in enumerate(buildings):
        y = line + side * back
        rects.append(facing_rectangle(st.world(x + w / 2, y, h / 2), facing, (w, h), Texture("facade", seed + i, 0.03), ids.take()))
    for (xa, wa, ba, _), (_, _, bb, hb) in zip(buildings, buildings[1:]):
        if bb < ba:  # the next front stands nearer: its side faces the oncoming car
            rects.append(facing_rectangle(st.world(xa + wa, line + side * (ba + bb) / 2, hb / 2), -st.along, (ba - bb, hb), Texture("plaster", seed + 50, 0.03), ids.take()))
    if end_walls:
        depth = 12.0
        (xf, _, bf, hf), (xl, wl, bl, hl) = buildings[0], buildings[-1]
        rects.append(facing_rectangle(st.world(xf, line + side * (bf + depth / 2), hf / 2), -st.along, (depth, hf), Texture("plaster", seed + 60, 0.03), ids.take()))
        rects.append(facing_rectangle(st.world(xl + wl, line + side * (bl + depth / 2), hl / 2), st.along, (depth, hl), Texture("plaster", seed + 61, 0.03), ids.take()))
    return rects


def _cars(st: _Straight, *, rng: np.random.Generator, ids: _Ids) -> list[Rectangle]:
    """Parked cars in both parking lanes, about one per 30 m of lane; their faces towards
    the curb and towards the driving direction (which a car driving along never sees) left
    out."""
    rects = []
    for y in PARKING_Y_M:
        curb = st.left if y > 0 else -st.left
        x = 6.0 + float(rng.uniform(0.0, 12.0))
        while x + 5.0 < st.length - 6.0:
            model = int(rng.integers(len(CAR_MODELS)))
            length, kind = CAR_MODELS[model]
            centre = st.world(x + length / 2, y)
            along_x = abs(st.along[0]) > 0.5
            size = (length, CAR_WIDTH_M, CAR_HEIGHT_M) if along_x else (CAR_WIDTH_M, length, CAR_HEIGHT_M)
            faces = box_rectangles((float(centre[0]), float(centre[1])), size, kind=kind, seed=70 + model, first_plane_id=ids.take(5))
            rects += [f for f in faces if float(f.normal @ curb) < 0.5 and float(f.normal @ st.along) < 0.5]
            x += length + float(rng.uniform(1.5, 4.0)) + (float(rng.uniform(15.0, 45.0)) if rng.random() < 0.8 else 0.0)
    return rects


def _trees(st: _Straight, *, rng: np.random.Generator) -> tuple[list[Cylinder], list[Sphere]]:
    """Trees (a trunk and a crown) along both sidewalks, 50–80 m apart (ray-casting their
    round shapes costs more than a façade)."""
    trunks, crowns = [], []
    for y in TREE_Y_M:
        x = 8.0 + float(rng.uniform(0.0, 15.0))
        while x < st.length - 8.0:
            p = st.world(x, y)
            trunks.append(Cylinder(p[:2].copy(), 0.2, (0.0, 3.2), shade=float(rng.uniform(70, 110)), pattern_cells=6))
            crowns.append(Sphere(st.world(x, y, float(rng.uniform(4.3, 4.9))), float(rng.uniform(1.2, 1.6)), shade=float(rng.uniform(110, 170)), pattern_cells=14))
            x += float(rng.uniform(50.0, 80.0))
    return trunks, crowns


def _square_trees(loop: RoadLoop, straights: list[_Straight], d: float) -> tuple[list[Cylinder], list[Sphere]]:
    """Two trees on the open square inside each turn, at least 6 m from the car's path."""
    s = np.linspace(0.0, loop.length_m, int(loop.length_m) * 2)
    path = loop.point(s)
    trunks, crowns = [], []
    for st in straights:
        for x, y in ((st.length - 2.0, d + 6.0), (st.length + d - 16.0, STREET_LEFT_M + 3.0), (st.length - 4.0, STREET_LEFT_M + 5.0)):
            p = st.world(x, y)
            if np.min(np.linalg.norm(path - p[:2], axis=1)) < 6.0:
                continue
            trunks.append(Cylinder(p[:2].copy(), 0.25, (0.0, 3.5), shade=90.0, pattern_cells=6))
            crowns.append(Sphere(st.world(x, y, 5.2), 2.2, shade=150.0, pattern_cells=16))
    return trunks, crowns


def street_scene() -> Scene:
    """The `street` scene (module docstring): its geometry is fixed; the drive's start and
    the suspension's bounce come from the sequence's seed."""
    loop = street_loop()
    d = loop.corner_offset_m
    straights = [_Straight(start, heading, length) for start, heading, length in loop.straights()]
    rng = np.random.default_rng(2026)
    ids = _Ids()
    rects = _ground(straights, d)
    trunks: list[Cylinder] = []
    crowns: list[Sphere] = []
    for k, st in enumerate(straights):
        rects += _row(st, -d, st.length + d, side=-1, rng=rng, ids=ids, seed=1000 + 200 * k, end_walls=False)  # their ends face away from the car
        rects += _row(st, INNER_MARGIN_M, st.length - INNER_MARGIN_M, side=1, rng=rng, ids=ids, seed=1100 + 200 * k, end_walls=True)
        rects += _cars(st, rng=rng, ids=ids)
        t, c = _trees(st, rng=rng)
        trunks += t
        crowns += c
    t, c = _square_trees(loop, straights, d)
    first = straights[0]
    region = (first.world(first.length / 2, 0.0, CAMERA_HEIGHT_M), np.array([first.length / 2 - 10.0, 1.0, 0.1]))
    return Scene(
        name="street",
        rectangles=tuple(rects),
        spheres=tuple(crowns + c),
        cylinders=tuple(trunks + t),
        camera_region=region,
        rig=KITTI_RIG,
        motion=Motion(road=loop),
    )
