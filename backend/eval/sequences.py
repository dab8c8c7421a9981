"""The paper's Monte-Carlo worlds (§IV-B), exactly as DESIGN §4 defines them.

World frame z up; cameras OpenCV (x right, y down, z forward). A world is the ground truth:
poses `T_world_camera`, points and line segments (endpoints) in metres, each on a wall plane.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from backend.geometry.camera import PinholeCamera

SEQUENCES: tuple[str, ...] = ("a", "b")
CAMERA = PinholeCamera(fx=460.0, fy=460.0, cx=376.0, cy=240.0, width=752, height=480)
MIN_DEPTH_M = 0.1


@dataclasses.dataclass(frozen=True)
class World:
    """Ground truth of one sequence. Planes `n·X + d = 0`; `*_plane` index the wall."""

    name: str
    camera: PinholeCamera
    R_world_camera: np.ndarray  # (N, 3, 3)
    t_world_camera: np.ndarray  # (N, 3)
    points: np.ndarray  # (P, 3)
    point_plane: np.ndarray  # (P,)
    segments: np.ndarray  # (L, 2, 3) endpoints
    segment_plane: np.ndarray  # (L,)
    plane_n: np.ndarray  # (Q, 3)
    plane_d: np.ndarray  # (Q,)


def _look_frame(forward: np.ndarray) -> np.ndarray:
    """Rotation `R_world_camera` with optical axis `forward` (horizontal), image y = world -z."""
    z = forward / np.linalg.norm(forward)
    y = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


def _wall_features(rng: np.random.Generator, *, origin: np.ndarray, u: np.ndarray, half_u: float, half_z: float, n_points: int, n_segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and segments on the vertical wall through `origin` spanned by horizontal `u`
    (unit) and world z, within ±half_u horizontally and ±half_z vertically."""
    z = np.array([0.0, 0.0, 1.0])
    a = rng.uniform(-half_u, half_u, n_points)
    b = rng.uniform(-half_z, half_z, n_points)
    points = origin + a[:, None] * u + b[:, None] * z
    length = rng.uniform(0.5, 2.0, n_segments)
    # Half near vertical, half near horizontal: within ±10° of the axis.
    base = np.where(np.arange(n_segments) < n_segments // 2, np.pi / 2, 0.0)
    angle = base + np.deg2rad(rng.uniform(-10.0, 10.0, n_segments))
    da = 0.5 * length * np.cos(angle)
    db = 0.5 * length * np.sin(angle)
    # Centres uniform where both endpoints stay inside the wall's extent.
    centre_a = rng.uniform(-1.0, 1.0, n_segments) * (half_u - np.abs(da))
    centre_b = rng.uniform(-1.0, 1.0, n_segments) * (half_z - np.abs(db))
    centre = origin + centre_a[:, None] * u + centre_b[:, None] * z
    half = da[:, None] * u + db[:, None] * z
    segments = np.stack([centre - half, centre + half], axis=1)
    return points, segments


def make_world(name: str, *, seed: int = 0) -> World:
    """Sequence `a` (four walls, 150 poses on a circle) or `b` (one wall, 50 poses).

    Landmark placement is random with `seed`; poses are deterministic.
    """
    rng = np.random.default_rng([0xC0, seed, ord(name[:1] or "?")])
    if name == "a":
        walls = [  # (normal n, d) with n·X + d = 0, origin on the wall, horizontal axis u
            (np.array([1.0, 0.0, 0.0]), -4.0, np.array([4.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
            (np.array([-1.0, 0.0, 0.0]), -4.0, np.array([-4.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
            (np.array([0.0, 1.0, 0.0]), -4.0, np.array([0.0, 4.0, 0.0]), np.array([1.0, 0.0, 0.0])),
            (np.array([0.0, -1.0, 0.0]), -4.0, np.array([0.0, -4.0, 0.0]), np.array([1.0, 0.0, 0.0])),
        ]
        features = [_wall_features(rng, origin=o, u=u, half_u=3.0, half_z=1.5, n_points=50, n_segments=25) for _, _, o, u in walls]
        theta = 2.0 * np.pi * np.arange(150) / 150.0
        t = np.stack([1.5 * np.cos(theta), 1.5 * np.sin(theta), 0.3 * np.sin(10.0 * theta)], axis=1)
        R = np.stack([_look_frame(np.array([np.cos(th), np.sin(th), 0.0])) for th in theta])
    elif name == "b":
        walls = [(np.array([1.0, 0.0, 0.0]), -4.0, np.array([4.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))]
        features = [_wall_features(rng, origin=walls[0][2], u=walls[0][3], half_u=2.0, half_z=1.5, n_points=50, n_segments=20)]
        n = np.arange(50)
        t = np.stack([np.zeros(50), -1.0 + 2.0 * n / 49.0, 0.3 * np.sin(4.0 * np.pi * n / 49.0)], axis=1)
        yaw = np.deg2rad(10.0) * np.sin(2.0 * np.pi * n / 49.0)
        R = np.stack([_look_frame(np.array([np.cos(y), np.sin(y), 0.0])) for y in yaw])
    else:
        raise ValueError(f"unknown sequence {name!r}; expected one of {', '.join(SEQUENCES)}")
    points = np.concatenate([f[0] for f in features])
    segments = np.concatenate([f[1] for f in features])
    point_plane = np.concatenate([np.full(len(f[0]), i) for i, f in enumerate(features)])
    segment_plane = np.concatenate([np.full(len(f[1]), i) for i, f in enumerate(features)])
    return World(
        name=name,
        camera=CAMERA,
        R_world_camera=R,
        t_world_camera=t,
        points=points,
        point_plane=point_plane,
        segments=segments,
        segment_plane=segment_plane,
        plane_n=np.stack([w[0] for w in walls]),
        plane_d=np.array([w[1] for w in walls]),
    )


def visible(world: World, p_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (P, 3) into every pose: pixels (N, P, 2) and a mask (N, P) of
    those in the image at depth > 0.1 m."""
    p_cam = np.einsum("nji,npj->npi", world.R_world_camera, p_world[None, :, :] - world.t_world_camera[:, None, :])
    depth = p_cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = world.camera.project(p_cam)
    ok = (depth > MIN_DEPTH_M) & world.camera.in_image(uv)
    return uv, ok
