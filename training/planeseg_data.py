"""Training data for the plane-instance segmenter (training time only; never imported by
the runtime package).

Rendered samples: random room layouts (size, textures, decals on the walls, boxes, a table,
non-planar spheres and cylinders) seen from random poses inside, with random exposure,
blur and noise; grey images like EuRoC's, and the renderer's exact plane-instance ids.
With `photos` > 0, that share of the surfaces and decals wears real photographs
(`real_textures.py`: scikit-image's bundled brick, grass, gravel, ... and pictures)
instead of the procedural textures.
Real samples: frames of the EuRoC MH_01 slice in `../shared/data/` with pseudo-labels from
the geometric (stereo) segmenter, its instances only where they are large (confident);
the rest of such an image is left out of the loss.

A sample is the network input (`INPUT_H`, `INPUT_W`) uint8, labels at the output
resolution (`OUTPUT_H`, `OUTPUT_W`) int16: an instance id >= 0, `NON_PLANAR` (-1) or
`IGNORE` (-2, no loss), and the planes' unit normals in the camera frame at the output
resolution (3, `OUTPUT_H`, `OUTPUT_W`) float16, oriented towards the camera, zero where
unknown (rendered: exact; real: the geometric segmenter's fitted planes).
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
from real_textures import picture_kinds, register_photo_textures, surface_kinds

from backend.data.render import NON_PLANAR_ID, render_view
from backend.data.scenes import Cylinder, Scene, Sphere, Texture, box_rectangles, facing_rectangle
from backend.data.synthetic import CAMERA
from backend.frontend.segmentation_learned import prepare_input

INPUT_W, INPUT_H = 192, 128  # network input (the 752×480 image resized)
OUTPUT_W, OUTPUT_H = 96, 64  # network output (half the input)
NON_PLANAR = -1
IGNORE = -2
WALL_KINDS = ("tiles", "panels", "plaster", "checker", "poster")
PHOTO_SURFACES = surface_kinds()  # texture kinds of real photographs (registered on use)
PHOTO_PICTURES = picture_kinds()
_Z = np.array([0.0, 0.0, 1.0])


@dataclasses.dataclass(frozen=True)
class Sample:
    image: np.ndarray  # (INPUT_H, INPUT_W) uint8
    labels: np.ndarray  # (OUTPUT_H, OUTPUT_W) int16
    normals: np.ndarray  # (3, OUTPUT_H, OUTPUT_W) float16, camera frame, zero where unknown


CLAHE: dict | None = None  # set by train_planeseg.py --clahe (then written into the contract)


def to_input(image: np.ndarray) -> np.ndarray:
    """A full-size grey image as the network's input (uint8, the input size), prepared as
    the runtime prepares it (`prepare_input`: CLAHE when set, then area average)."""
    x = prepare_input(image, width=INPUT_W, height=INPUT_H, clahe=CLAHE)
    return np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)


def to_output_labels(labels: np.ndarray) -> np.ndarray:
    """Full-size labels at the output resolution (nearest: the centre pixel of each cell)."""
    H, W = labels.shape
    ys = ((np.arange(OUTPUT_H) + 0.5) * H / OUTPUT_H).astype(int)
    xs = ((np.arange(OUTPUT_W) + 0.5) * W / OUTPUT_W).astype(int)
    return labels[np.ix_(ys, xs)].astype(np.int16)


def normal_image(labels: np.ndarray, normals_by_id: dict[int, np.ndarray]) -> np.ndarray:
    """(3, h, w) float16 unit normals of output-resolution `labels` from `normals_by_id`
    (camera frame, oriented towards the camera); zero for other labels."""
    out = np.zeros((3, *labels.shape), np.float16)
    for pid, n in normals_by_id.items():
        sel = labels == pid
        out[:, sel] = np.asarray(n, np.float16)[:, None]
    return out


def camera_normals(scene: Scene, R_world_camera: np.ndarray, t_world_camera: np.ndarray) -> dict[int, np.ndarray]:
    """Each plane id's unit normal in the camera frame, turned to face the camera."""
    out: dict[int, np.ndarray] = {}
    for rect in scene.rectangles:
        if rect.plane_id in out:
            continue
        n_camera = R_world_camera.T @ rect.normal
        p_camera = R_world_camera.T @ (rect.p0 - t_world_camera)
        out[rect.plane_id] = -n_camera if n_camera @ p_camera > 0 else n_camera
    return out


def random_room(rng: np.random.Generator, name: str, *, leaning: bool = False, photos: float = 0.0) -> Scene:
    """A random box-shaped room with decals on the walls and patches on the floor, boxes,
    maybe a table, and non-planar clutter;
    three in ten are open (no ceiling, one to three walls missing). With `leaning`, half
    the rooms also get one to three panels leaning against a wall at 55–80° from the
    floor (like the padded mats of EuRoC's Vicon room), each its own plane. With `photos`
    (a probability, 0–1), each surface and decal wears a real photograph with that
    probability (`real_textures.register_photo_textures` must have run); at 0 the random
    draws, and so the layouts, are those of the procedural rooms."""
    X, Y, H = rng.uniform(1.8, 4.5), rng.uniform(1.8, 4.5), rng.uniform(2.3, 3.6)
    seed = int(rng.integers(1 << 30))

    def kind() -> str:
        if photos > 0 and rng.random() < photos:
            return str(rng.choice(PHOTO_SURFACES))
        return str(rng.choice(WALL_KINDS))

    def decal(kinds: tuple[str, ...]) -> str:
        if photos > 0 and rng.random() < photos:
            return str(rng.choice(PHOTO_PICTURES + PHOTO_SURFACES))
        return str(rng.choice(kinds))

    tex = lambda k: Texture(kind(), seed + k, float(rng.uniform(0.004, 0.012)))  # noqa: E731
    rects = [
        facing_rectangle(np.array([0, 0, 0.0]), _Z, (2 * X, 2 * Y), tex(0), 0),
        facing_rectangle(np.array([0, 0, H]), -_Z, (2 * X, 2 * Y), tex(1), 1),
        facing_rectangle(np.array([X, 0, H / 2]), np.array([-1.0, 0, 0]), (2 * Y, H), tex(2), 2),
        facing_rectangle(np.array([-X, 0, H / 2]), np.array([1.0, 0, 0]), (2 * Y, H), tex(3), 3),
        facing_rectangle(np.array([0, Y, H / 2]), np.array([0, -1.0, 0]), (2 * X, H), tex(4), 4),
        facing_rectangle(np.array([0, -Y, H / 2]), np.array([0, 1.0, 0]), (2 * X, H), tex(5), 5),
    ]
    if rng.random() < 0.3:  # an open scene: no ceiling, some walls missing, the empty background (non-planar) shows
        missing = set(rng.choice([2, 3, 4, 5], size=int(rng.integers(1, 4)), replace=False).tolist()) | {1}
        rects = [r for r in rects if r.plane_id not in missing]
    present = {r.plane_id for r in rects}
    walls = [
        (2, np.array([X, 0, 0]), np.array([-1.0, 0, 0]), Y),
        (3, np.array([-X, 0, 0]), np.array([1.0, 0, 0]), Y),
        (4, np.array([0, Y, 0]), np.array([0, -1.0, 0]), X),
        (5, np.array([0, -Y, 0]), np.array([0, 1.0, 0]), X),
    ]
    walls = [w for w in walls if w[0] in present] or walls[:0]
    for k in range(int(rng.integers(0, 7)) if walls else 0):  # decals share their wall's plane id
        pid, base, n, half = walls[int(rng.integers(len(walls)))]
        along = np.cross(_Z, n)
        w, h = rng.uniform(0.4, 1.4), rng.uniform(0.4, 2.0)
        c = base + along * rng.uniform(-half + w, half - w) + _Z * rng.uniform(h / 2 + 0.1, H - h / 2 - 0.1) - n * 0.0
        rects.append(facing_rectangle(c, n, (w, h), Texture(decal(("poster", "door")), seed + 100 + k), pid))
    for k in range(int(rng.integers(0, 9))):  # patches on the floor (mats, markers, carpet patterns) share its plane id
        w, h = rng.uniform(0.15, 1.2, 2)
        c = np.array([rng.uniform(-X + w, X - w), rng.uniform(-Y + h, Y - h), 0.0])
        rects.append(facing_rectangle(c, _Z, (w, h), Texture(decal(("poster", "checker", "tiles", "panels")), seed + 300 + k, float(rng.uniform(0.003, 0.01))), 0))
    next_id = 6
    if rng.random() < 0.5:  # a table top
        c = np.array([rng.uniform(-X + 1, X - 1), rng.uniform(-Y + 1, Y - 1), rng.uniform(0.6, 0.9)])
        rects.append(facing_rectangle(c, _Z, (rng.uniform(0.8, 1.6), rng.uniform(0.5, 1.0)), tex(6), next_id))
        next_id += 1
    for b in range(int(rng.integers(0, 4))):
        s = rng.uniform(0.3, 1.0, 3)
        cxy = (rng.uniform(-X + s[0], X - s[0]), rng.uniform(-Y + s[1], Y - s[1]))
        rects += box_rectangles(cxy, tuple(s), kind=kind(), seed=seed + 200 + b, first_plane_id=next_id)
        next_id += 5
    if leaning and walls and rng.random() < 0.5:
        for k in range(int(rng.integers(1, 4))):
            _, base, n, half = walls[int(rng.integers(len(walls)))]
            tilt = np.radians(rng.uniform(55, 80))  # from the floor
            length, w = rng.uniform(0.8, min(2.2, H - 0.1)), rng.uniform(0.8, min(2.4, 2 * half - 0.2))
            along = np.cross(_Z, n)
            foot = base + along * rng.uniform(-half + w / 2, half - w / 2)
            centre = foot + n * (0.5 * length * np.cos(tilt)) + _Z * (0.5 * length * np.sin(tilt))
            normal = np.sin(tilt) * n + np.cos(tilt) * _Z
            rects.append(facing_rectangle(centre, normal, (w, length), tex(400 + k), next_id))
            next_id += 1
    spheres = tuple(
        Sphere(
            np.array([rng.uniform(-X + 0.5, X - 0.5), rng.uniform(-Y + 0.5, Y - 0.5), rng.uniform(0.2, 1.5)]),
            float(rng.uniform(0.15, 0.45)),
            shade=float(rng.uniform(60, 220)),
            pattern_cells=int(rng.integers(4, 14)),
        )
        for _ in range(int(rng.integers(0, 3)))
    )
    cylinders = tuple(
        Cylinder(
            np.array([rng.uniform(-X + 0.5, X - 0.5), rng.uniform(-Y + 0.5, Y - 0.5)]),
            float(rng.uniform(0.05, 0.35)),
            (0.0, float(rng.uniform(0.5, 2.2))),
            shade=float(rng.uniform(60, 220)),
            pattern_cells=int(rng.integers(4, 14)),
        )
        for _ in range(int(rng.integers(0, 4)))
    )
    return Scene(name=name, rectangles=tuple(rects), spheres=spheres, cylinders=cylinders, camera_region=(np.array([0.0, 0.0, 1.4]), np.array([X - 0.6, Y - 0.6, 0.5])))


def random_pose(rng: np.random.Generator, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """`R_world_camera, t_world_camera` inside the scene's camera region: any heading,
    pitch from 35° down to 20° up, roll within ±10°."""
    centre, half = scene.camera_region
    t = centre + rng.uniform(-1, 1, 3) * half
    yaw, pitch, roll = rng.uniform(-np.pi, np.pi), np.radians(rng.uniform(-35, 20)), np.radians(rng.uniform(-10, 10))
    f = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    r = np.cross(f, _Z)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    c, s = np.cos(roll), np.sin(roll)
    r, d = c * r + s * d, -s * r + c * d
    return np.stack([r, d, f], axis=1), t


def rendered_samples(seed: int, *, layouts: int, views_per_layout: int, leaning: bool = False, photos: float = 0.0) -> list[Sample]:
    """Samples of `layouts` random rooms drawn from `seed` (disjoint seeds: disjoint layouts);
    `leaning`, `photos`: see `random_room` (`photos` > 0 registers the photographs)."""
    if photos > 0:
        register_photo_textures()
    rng = np.random.default_rng([seed, 0x5E6])
    out = []
    for k in range(layouts):
        scene = random_room(rng, f"random-{seed}-{k}", leaning=leaning, photos=photos)
        for _ in range(views_per_layout):
            R, t = random_pose(rng, scene)
            view = render_view(scene, CAMERA, R, t, gain=float(rng.uniform(0.55, 1.45)), blur_sigma_px=float(rng.uniform(0, 1.5)), noise_sigma=float(rng.uniform(0, 6)), rng=rng)
            labels = to_output_labels(np.where(view.plane_id == NON_PLANAR_ID, NON_PLANAR, view.plane_id).astype(np.int16))
            out.append(Sample(to_input(view.image), labels, normal_image(labels, camera_normals(scene, R, t))))
    return out


def real_samples(folder: pathlib.Path, *, every: int = 2, min_share: float = 0.03) -> list[Sample]:
    """Pseudo-labelled frames of a real EuRoC folder: the geometric segmenter's instances
    covering at least `min_share` of the image; everything else is IGNORE."""
    from backend.data.euroc import EurocDataset
    from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

    data = EurocDataset(folder)
    seg = GeometricPlaneSegmenter()
    out = []
    for i in range(0, len(data), every):
        left, right = data.rectified_pair(i)
        out.append(pseudo_labelled(left, seg.segment(left, right, data.camera), min_share=min_share))
    return out


def pseudo_labelled(left: np.ndarray, masks, *, min_share: float = 0.03) -> Sample:
    """A real image with the geometric segmenter's `masks` (`PlaneMasks` with fitted planes)
    as labels: its instances covering at least `min_share` of the image, with their normals
    turned towards the camera; everything else is IGNORE."""
    from backend.frontend.segmentation import NO_PLANE

    labels = np.full(masks.labels.shape, IGNORE, np.int16)
    normals: dict[int, np.ndarray] = {}
    for q in range(masks.count):
        sel = masks.labels == q
        if sel.mean() >= min_share:
            labels[sel] = q
            n = masks.normals_camera[q]
            normals[q] = n if masks.offsets_camera[q] > 0 else -n  # n·X + d = 0 with d > 0: n faces the camera
    labels[masks.labels == NO_PLANE] = IGNORE
    small = to_output_labels(labels)
    return Sample(to_input(left), small, normal_image(small, normals))


def v101_pair_samples(indices: list[int]) -> list[Sample]:
    """Pseudo-labelled left images of the V1_01 test pairs `indices` (scripts/segmentation_gallery.py).
    For the held-out check only (train on some pairs, evaluate on the others): a model
    trained with them is never shipped, since the pairs are the real test set."""
    import sys

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "scripts"))
    from segmentation_gallery import real_pairs

    from backend.frontend.segmentation_geometric import GeometricPlaneSegmenter

    seg = GeometricPlaneSegmenter()
    return [pseudo_labelled(left, seg.segment(left, right, camera)) for i, left, right, camera, _ in real_pairs() if i in indices]
