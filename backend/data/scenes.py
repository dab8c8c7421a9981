"""Synthetic scenes: textured planar rectangles plus non-planar spheres and vertical
cylinders, in the world frame (metres, z up), with the rig that sees them, how its body
moves and the camera's exposure.

A rectangle is `X(a, b) = p0 + a u + b v` for `a ∈ [0, w]`, `b ∈ [0, h]` (u, v unit and
orthogonal); its texture's column index runs along u and its row index along v. Its plane
is `n = u × v`, `d = -n·p0` (DESIGN §2: `n·X + d = 0`). Every rectangle carries a plane id
(≥ 0); coplanar rectangles may share one (a poster on a wall shares the wall's id and, drawn
after it, covers it). Spheres and cylinders have no plane (id -1 in the renderer's masks).

A scene also carries its `rig` (camera, baseline, rates: `backend.data.rigs`; EuRoC-like by
default), its `motion` (`backend.data.body_motion`: a random path in `camera_region` by
default, or a drive around a road loop; optionally shaken or slow to start) and an
`exposure` schedule (`backend.data.exposure`; none by default).

Built-in scenes (`builtin_scene`): the standard indoor ones `room` (default), `corridor`,
`boxes`, and the stress scenes that test robustness on what real data brings (`STRESS_SCENES`):
`street` (a KITTI-like drive around a city block, `backend.data.street`), and `room` made
harder: `shake` (hand-held shake), `slow-start` (3 s nearly still), `low-texture` (faint
walls) and `exposure` (auto-exposure steps and ramps). User scenes are JSON files
(`load_scene`, `scene_to_json`); see `scene_to_dict` for the layout.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from typing import Any

import numpy as np

from backend.data.body_motion import Motion, motion_from_dict, motion_to_dict
from backend.data.exposure import ExposureSchedule, GainChange, exposure_from_dict, exposure_to_dict
from backend.data.json_fields import integer, number, objects, vector
from backend.data.motion import Shake, SlowStart
from backend.data.rigs import EUROC_RIG, rig_from_dict, rig_to_dict
from backend.data.scene_model import MAX_COORDINATE_M as MAX_COORDINATE_M
from backend.data.scene_model import MAX_EXTENT_M as MAX_EXTENT_M
from backend.data.scene_model import Z_UP
from backend.data.scene_model import Cylinder as Cylinder
from backend.data.scene_model import Rectangle as Rectangle
from backend.data.scene_model import Scene as Scene
from backend.data.scene_model import Sphere as Sphere
from backend.data.scene_model import Texture as Texture
from backend.data.scene_model import box_rectangles as box_rectangles
from backend.data.scene_model import facing_rectangle as facing_rectangle
from backend.data.textures import DEFAULT_TEXEL_M

STANDARD_SCENES = ("room", "corridor", "boxes")  # what a sweep runs by default
STRESS_SCENES = ("street", "shake", "slow-start", "low-texture", "exposure")
SCENE_NAMES = (*STANDARD_SCENES, *STRESS_SCENES)
DEFAULT_SCENE = "room"


class SceneFileError(ValueError):
    """A malformed scene file; the message is one line naming the file and the problem."""

    def __init__(self, path: str | os.PathLike[str], reason: str) -> None:
        self.path = os.fspath(path)
        self.reason = " ".join(str(reason).split())
        super().__init__(f"{self.path}: {self.reason}")


def _room() -> Scene:
    """6 × 5 × 3 m room (x ∈ [-3, 3], y ∈ [-2.5, 2.5], z ∈ [0, 3])."""
    X, Y, H = 3.0, 2.5, 3.0
    rects = [
        facing_rectangle(np.array([0, 0, 0.0]), Z_UP, (2 * X, 2 * Y), Texture("tiles", 1), 0),
        facing_rectangle(np.array([0, 0, H]), -Z_UP, (2 * X, 2 * Y), Texture("tiles", 2, 0.01), 1),
        facing_rectangle(np.array([X, 0, H / 2]), np.array([-1.0, 0, 0]), (2 * Y, H), Texture("plaster", 3), 2),
        facing_rectangle(np.array([-X, 0, H / 2]), np.array([1.0, 0, 0]), (2 * Y, H), Texture("panels", 4), 3),
        facing_rectangle(np.array([0, Y, H / 2]), np.array([0, -1.0, 0]), (2 * X, H), Texture("plaster", 5), 4),
        facing_rectangle(np.array([0, -Y, H / 2]), np.array([0, 1.0, 0]), (2 * X, H), Texture("tiles", 6), 5),
    ]
    # decals: posters and doors on the walls, sharing the wall's plane
    decals = [
        ((X, -1.0, 1.6), (-1, 0, 0), (0.8, 1.1), "poster", 2),
        ((X, 0.6, 1.5), (-1, 0, 0), (1.2, 0.8), "poster", 2),
        ((X, 1.8, 1.05), (-1, 0, 0), (0.9, 2.1), "door", 2),
        ((-X, 0.5, 1.6), (1, 0, 0), (1.0, 0.7), "poster", 3),
        ((-1.5, Y, 1.05), (0, -1, 0), (0.9, 2.1), "door", 4),
        ((0.5, Y, 1.6), (0, -1, 0), (1.0, 1.0), "poster", 4),
        ((1.9, Y, 1.5), (0, -1, 0), (0.6, 0.9), "poster", 4),
        ((-0.8, -Y, 1.7), (0, 1, 0), (1.4, 0.9), "poster", 5),
        ((1.2, -Y, 1.4), (0, 1, 0), (0.7, 1.0), "poster", 5),
    ]
    for k, (c, n, s, kind, pid) in enumerate(decals):
        rects.append(facing_rectangle(np.array(c, float), np.array(n, float), s, Texture(kind, 100 + k), pid))
    rects.append(facing_rectangle(np.array([-2.0, 1.6, 0.75]), Z_UP, (1.2, 0.7), Texture("panels", 7), 6))
    rects += box_rectangles((2.2, -1.7), (0.6, 0.6, 0.6), kind="poster", seed=8, first_plane_id=7)
    legs = [Cylinder(np.array([-2.0 + sx * 0.55, 1.6 + sy * 0.3]), 0.03, (0.0, 0.75), shade=60.0, pattern_cells=4) for sx in (-1, 1) for sy in (-1, 1)]
    return Scene(
        name="room",
        rectangles=tuple(rects),
        spheres=(Sphere(np.array([2.2, 1.7, 0.35]), 0.35, shade=190.0, pattern_cells=10),),
        cylinders=(Cylinder(np.array([-2.3, -1.8]), 0.25, (0.0, 1.1), shade=160.0, pattern_cells=12), *legs),
        camera_region=(np.array([0.0, 0.0, 1.4]), np.array([1.5, 1.5, 0.3])),
    )


def _corridor() -> Scene:
    """A 16 m long, 2 m wide, 2.5 m high corridor along x (x ∈ [0, 16], y ∈ [-1, 1])."""
    L, Y, H = 16.0, 1.0, 2.5
    rects = [
        facing_rectangle(np.array([L / 2, 0, 0.0]), Z_UP, (L, 2 * Y), Texture("checker", 11), 0),
        facing_rectangle(np.array([L / 2, 0, H]), -Z_UP, (L, 2 * Y), Texture("tiles", 12, 0.01), 1),
        facing_rectangle(np.array([L / 2, Y, H / 2]), np.array([0, -1.0, 0]), (L, H), Texture("panels", 13), 2),
        facing_rectangle(np.array([L / 2, -Y, H / 2]), np.array([0, 1.0, 0]), (L, H), Texture("plaster", 14), 3),
        facing_rectangle(np.array([0.0, 0, H / 2]), np.array([1.0, 0, 0]), (2 * Y, H), Texture("poster", 15), 4),
        facing_rectangle(np.array([L, 0, H / 2]), np.array([-1.0, 0, 0]), (2 * Y, H), Texture("tiles", 16), 5),
    ]
    k = 0
    for x in np.arange(1.5, L - 1.0, 2.5):
        side = 1 if k % 2 == 0 else -1
        rects.append(facing_rectangle(np.array([x, side * Y, 1.0]), np.array([0, -side, 0.0]), (0.9, 2.0), Texture("door", 200 + k), 2 if side > 0 else 3))
        rects.append(facing_rectangle(np.array([x + 1.2, -side * Y, 1.5]), np.array([0, side, 0.0]), (0.7, 0.9), Texture("poster", 300 + k), 3 if side > 0 else 2))
        k += 1
    rects += box_rectangles((5.5, -0.7), (0.4, 0.4, 0.5), kind="panels", seed=17, first_plane_id=6)
    return Scene(
        name="corridor",
        rectangles=tuple(rects),
        spheres=(Sphere(np.array([11.0, 0.7, 0.25]), 0.25, shade=200.0, pattern_cells=8),),
        cylinders=(Cylinder(np.array([8.0, 0.75]), 0.15, (0.0, 0.6), shade=120.0, pattern_cells=10),),
        camera_region=(np.array([L / 2, 0.0, 1.4]), np.array([L / 2 - 2.0, 0.4, 0.2])),
    )


def _boxes() -> Scene:
    """A 16 × 16 m hall (open floor, low walls 2 m high at x, y = ±8, no ceiling) with boxes
    of several sizes around a free centre."""
    rects = [facing_rectangle(np.array([0, 0, 0.0]), Z_UP, (16.0, 16.0), Texture("checker", 21, 0.008), 0)]
    for k, (c, n, kind) in enumerate([((8.0, 0, 1.0), (-1, 0, 0), "tiles"), ((-8.0, 0, 1.0), (1, 0, 0), "panels"), ((0, 8.0, 1.0), (0, -1, 0), "panels"), ((0, -8.0, 1.0), (0, 1, 0), "tiles")]):
        rects.append(facing_rectangle(np.array(c), np.array(n, float), (16.0, 2.0), Texture(kind, 22 + k), 36 + k))
    layout: list[tuple[tuple[float, float], tuple[float, float, float], str]] = [
        ((3.5, 0.5), (0.8, 1.2, 1.0), "tiles"),
        ((-3.4, 2.6), (1.5, 1.0, 1.6), "poster"),
        ((0.5, -3.6), (1.0, 1.0, 0.5), "panels"),
        ((-3.2, -2.8), (0.6, 0.6, 2.2), "tiles"),
        ((3.3, 3.4), (1.2, 0.8, 0.8), "poster"),
        ((-0.5, 4.0), (2.0, 0.8, 1.2), "panels"),
        ((4.5, -3.0), (0.5, 0.5, 0.5), "poster"),
    ]
    pid = 1
    for k, (centre, size, kind) in enumerate(layout):
        rects += box_rectangles(centre, size, kind=kind, seed=30 + k, first_plane_id=pid)
        pid += 5
    return Scene(
        name="boxes",
        rectangles=tuple(rects),
        spheres=(Sphere(np.array([-4.0, 0.0, 0.5]), 0.5, shade=180.0, pattern_cells=12),),
        cylinders=(
            Cylinder(np.array([2.8, -2.2]), 0.3, (0.0, 1.8), shade=170.0),
            Cylinder(np.array([-2.0, -4.0]), 0.2, (0.0, 1.0), shade=110.0),
            Cylinder(np.array([3.0, 5.0]), 0.4, (0.0, 0.7), shade=200.0),
        ),
        camera_region=(np.array([0.0, 0.0, 1.4]), np.array([1.8, 1.8, 0.3])),
    )


def _street() -> Scene:
    from backend.data.street import street_scene  # it builds on this module

    return street_scene()


def _shake() -> Scene:
    """`room` carried by hand: its path plus a shake of up to 8 mm and 1.5° at 2–6 Hz."""
    return dataclasses.replace(_room(), name="shake", motion=Motion(shake=Shake(amplitude_m=0.008, amplitude_deg=1.5, band_hz=(2.0, 6.0))))


def _slow_start() -> Scene:
    """`room` whose first 3 s creep at a hundredth of the usual pace (millimetres per
    second), rising to it over the next 2 s."""
    return dataclasses.replace(_room(), name="slow-start", motion=Motion(slow_start=SlowStart(still_s=3.0, ramp_s=2.0, creep=0.01)))


def _low_texture() -> Scene:
    """`room` with faint walls, floor and ceiling (`faint`: near-uniform paint, a few marks
    14–22 grey levels off it) and only one of its nine decals, a door; the table, the box,
    the ball and the bin keep their texture."""
    room = _room()
    surfaces = tuple(dataclasses.replace(r, texture=Texture("faint", 400 + k, 0.01)) for k, r in enumerate(room.rectangles[:6]))
    door = room.rectangles[6 + 2]  # on the +x wall
    return dataclasses.replace(room, name="low-texture", rectangles=(*surfaces, door, *room.rectangles[15:]))


# auto-exposure: steps and ramps of the gain between 0.55 and 1.5, repeating every 16 s
AUTO_EXPOSURE = ExposureSchedule(
    period_s=16.0,
    changes=(
        GainChange(at_s=1.5, gain=1.45),
        GainChange(at_s=3.5, gain=0.6, ramp_s=1.0),
        GainChange(at_s=6.0, gain=1.0),
        GainChange(at_s=8.0, gain=1.5, ramp_s=2.0),
        GainChange(at_s=11.0, gain=0.55),
        GainChange(at_s=13.0, gain=1.0, ramp_s=1.5),
    ),
)


def _exposure() -> Scene:
    """`room` under auto-exposure: `AUTO_EXPOSURE`'s gain steps and ramps of ±40–50 %."""
    return dataclasses.replace(_room(), name="exposure", exposure=AUTO_EXPOSURE)


_BUILDERS = {
    "room": _room,
    "corridor": _corridor,
    "boxes": _boxes,
    "street": _street,
    "shake": _shake,
    "slow-start": _slow_start,
    "low-texture": _low_texture,
    "exposure": _exposure,
}


def builtin_scene(name: str = DEFAULT_SCENE) -> Scene:
    """One of the built-in scenes `SCENE_NAMES`."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown scene {name!r} (built-in: {', '.join(SCENE_NAMES)})")
    return _BUILDERS[name]()


# ----------------------------------------------------------------------------- JSON


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """The JSON-able form of a scene:

    {"name": str,
     "rectangles": [{"p0": [x, y, z], "u": [..], "v": [..], "size": [w, h], "plane_id": int,
                     "texture": {"kind": str, "seed": int, "texel_m": float}}, ...],
     "spheres": [{"centre": [x, y, z], "radius": r, "shade": 0..255, "pattern_cells": int}],
     "cylinders": [{"centre_xy": [x, y], "radius": r, "z_range": [z0, z1], "shade": .., "pattern_cells": ..}],
     "camera_region": {"centre": [..], "half_extent": [..]} or null,
     "rig": {"camera": {"fx", "fy", "cx", "cy", "width", "height", "baseline"}, "T_body_cam0": 4x4,
             "camera_rate_hz", "imu_rate_hz"},                                   (rigs.rig_to_dict)
     "motion": {"road": null | {...}, "shake": null | {...}, "slow_start": null | {...}},
                                                                           (body_motion.motion_to_dict)
     "exposure": null | {"period_s", "changes": [{"at_s", "gain", "ramp_s"}, ...]}}
                                                                           (exposure.exposure_to_dict)
    World frame, metres, pixels, seconds. `spheres`, `cylinders`, `camera_region`, a
    texture's `texel_m`, `rig` (the EuRoC-like rig), `motion` (a random path in the camera
    region) and `exposure` (none) may be left out."""
    return {
        "name": scene.name,
        "rectangles": [
            {
                "p0": r.p0.tolist(),
                "u": r.u.tolist(),
                "v": r.v.tolist(),
                "size": list(r.size),
                "plane_id": r.plane_id,
                "texture": {"kind": r.texture.kind, "seed": r.texture.seed, "texel_m": r.texture.texel_m},
            }
            for r in scene.rectangles
        ],
        "spheres": [{"centre": s.centre.tolist(), "radius": s.radius, "shade": s.shade, "pattern_cells": s.pattern_cells} for s in scene.spheres],
        "cylinders": [{"centre_xy": c.centre_xy.tolist(), "radius": c.radius, "z_range": list(c.z_range), "shade": c.shade, "pattern_cells": c.pattern_cells} for c in scene.cylinders],
        "camera_region": None if scene.camera_region is None else {"centre": scene.camera_region[0].tolist(), "half_extent": scene.camera_region[1].tolist()},
        "rig": rig_to_dict(scene.rig),
        "motion": motion_to_dict(scene.motion),
        "exposure": None if scene.exposure is None else exposure_to_dict(scene.exposure),
    }


def scene_to_json(scene: Scene) -> str:
    """The scene as JSON text (see `scene_to_dict`)."""
    return json.dumps(scene_to_dict(scene), indent=1)


def scene_from_dict(data: Any) -> Scene:
    """A scene from its JSON-able form (`scene_to_dict`); ValueError with a short reason
    (naming the entry, e.g. `rectangles[2].u: expected 3 numbers`) when malformed."""
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object at the top level")
    rects = []
    for i, r in enumerate(objects(data, "rectangles")):
        where = f"rectangles[{i}]"
        size = vector(r, "size", 2, where)
        tex = r.get("texture")
        if not isinstance(tex, dict):
            raise ValueError(f"{where}.texture: expected an object with kind and seed")
        kind = tex.get("kind")
        if not isinstance(kind, str):
            raise ValueError(f"{where}.texture.kind: expected a string")
        seed = integer(tex, "seed", f"{where}.texture")
        if seed < 0:
            raise ValueError(f"{where}.texture.seed: must be >= 0")
        texture = Texture(kind, seed, number(tex, "texel_m", f"{where}.texture", DEFAULT_TEXEL_M))
        rects.append(
            Rectangle(
                p0=vector(r, "p0", 3, where),
                u=vector(r, "u", 3, where),
                v=vector(r, "v", 3, where),
                size=(float(size[0]), float(size[1])),
                texture=texture,
                plane_id=integer(r, "plane_id", where),
            )
        )
    if not rects:
        raise ValueError("rectangles: expected at least one rectangle")
    spheres = []
    for i, s in enumerate(objects(data, "spheres")):
        where = f"spheres[{i}]"
        spheres.append(Sphere(vector(s, "centre", 3, where), number(s, "radius", where), number(s, "shade", where, 170.0), integer(s, "pattern_cells", where, 8)))
    cylinders = []
    for i, c in enumerate(objects(data, "cylinders")):
        where = f"cylinders[{i}]"
        z = vector(c, "z_range", 2, where)
        cylinders.append(Cylinder(vector(c, "centre_xy", 2, where), number(c, "radius", where), (float(z[0]), float(z[1])), number(c, "shade", where, 150.0), integer(c, "pattern_cells", where, 12)))
    region = data.get("camera_region")
    camera_region = None
    if region is not None:
        if not isinstance(region, dict):
            raise ValueError("camera_region: expected an object with centre and half_extent")
        camera_region = (vector(region, "centre", 3, "camera_region"), vector(region, "half_extent", 3, "camera_region"))
    name = data.get("name", "scene")
    if not isinstance(name, str):
        raise ValueError("name: expected a string")
    rig = EUROC_RIG if data.get("rig") is None else rig_from_dict(data["rig"])
    motion = Motion() if data.get("motion") is None else motion_from_dict(data["motion"])
    exposure = None if data.get("exposure") is None else exposure_from_dict(data["exposure"])
    return Scene(name=name, rectangles=tuple(rects), spheres=tuple(spheres), cylinders=tuple(cylinders), camera_region=camera_region, rig=rig, motion=motion, exposure=exposure)


def load_scene(path: str | os.PathLike[str]) -> Scene:
    """A scene from a JSON file; SceneFileError (one line naming the file) when it cannot
    be read or is malformed."""
    from backend.data.errors import DatasetError, read_text

    path = pathlib.Path(path)
    try:
        text = read_text(path)  # a regular file only: a FIFO would block
    except DatasetError as error:
        raise SceneFileError(path, error.reason) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise SceneFileError(path, f"invalid JSON at line {error.lineno} column {error.colno}: {error.msg}") from None
    except RecursionError:
        raise SceneFileError(path, "invalid scene: JSON nested too deeply") from None
    try:
        return scene_from_dict(data)
    except ValueError as error:
        raise SceneFileError(path, str(error)) from None
