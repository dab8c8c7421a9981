"""Draw a snapshot into a viser scene: keyframe frustums, trajectories, points, segments,
planes and the RANSAC consensus of the last detection. World frame, metres, z up.

Every layer is one scene node (frustums are one set of line segments), so a step costs a
handful of messages whatever the number of keyframes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import viser

from backend.common.palette import plane_color
from backend.geometry.camera import PinholeCamera
from backend.pipeline.snapshot import INLIER, OUTLIER, Snapshot
from viewer.displacement import Displacement, displacement, displacement_colors
from viewer.framing import marker_size_m, snapshot_bounds

FRUSTUM_DEPTH_M = 0.25
INFINITE_PLANE_SIZE_M = 30.0
GRID_HALF_M = 6.0
COLOR_GRID = (205, 205, 205)
COLOR_KEYFRAME = (150, 150, 150)
COLOR_WINDOW = (255, 160, 0)
COLOR_CURRENT = (220, 0, 0)
COLOR_ESTIMATE = (30, 90, 220)
COLOR_GROUND_TRUTH = (20, 20, 20)
COLOR_INLIER = (0, 200, 0)
COLOR_OUTLIER = (255, 0, 0)
# The A/B run's trajectory, newest camera and label: aquamarine, far from every plane colour
# (backend/common/palette.py; the nearest, teal, is 60 CIELAB units away), from the
# cameras' grey, orange and red and from the RANSAC green (46 units): tests/viewer/test_scene_colours.py.
COLOR_B = (0, 255, 190)
B_FRUSTUM_DEPTH_M = 1.6 * FRUSTUM_DEPTH_M  # B's newest camera drawn larger than A's
B_THICKNESS = 4.0  # px, A's frustums 1.5
COLOR_DISPLACEMENT_LINK = (90, 90, 90)  # from a landmark to where the other snapshot has it
PLANE_OPACITY = 0.45
PLANE_OPACITY_UNUSED = 0.15  # -wo variants: planes shown for reference only
COLOR_FADED = (215, 215, 215)  # P variants: lines blended towards this, shown for reference only
LINE_FADE = 0.35  # the share of a line's own colour kept under P variants


@dataclasses.dataclass
class Layers:
    """Which layers are visible."""

    points: bool = True
    lines: bool = True
    planes: bool = True
    infinite_planes: bool = False
    inliers: bool = True
    ground_truth: bool = True
    cameras: bool = True
    ab: bool = True


# Scene node name -> the layer that controls its visibility.
NODE_LAYER = {
    "/map/points": "points",
    "/map/lines": "lines",
    "/map/planes": "planes",
    "/map/infinite_planes": "infinite_planes",
    "/map/inliers": "inliers",
    "/map/outliers": "inliers",
    "/map/inlier_lines": "inliers",
    "/map/outlier_lines": "inliers",
    "/trajectory/ground_truth": "ground_truth",
    "/cameras": "cameras",
    "/ab": "ab",
    "/map/displacement": "points",
}


SHADER_KEEPER = "/world/shader_keeper"  # scene nodes that only keep shaders compiled in the browser (SceneView._keep_point_shaders)


def frustum_segments(R_world_camera: np.ndarray, t_world_camera: np.ndarray, camera: PinholeCamera, *, depth: float = FRUSTUM_DEPTH_M) -> np.ndarray:
    """Wireframe (K * 8, 2, 3) of K camera frustums: four edges from the centre to the image
    corners at `depth` metres, and the image rectangle."""
    u = np.array([0.0, camera.width, camera.width, 0.0])
    v = np.array([0.0, 0.0, camera.height, camera.height])
    corners_c = depth * np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(4)], axis=1)  # (4, 3)
    corners_w = np.einsum("kij,cj->kci", R_world_camera, corners_c) + t_world_camera[:, None, :]  # (K, 4, 3)
    centre = np.repeat(t_world_camera[:, None, :], 4, axis=1)
    rays = np.stack([centre, corners_w], axis=2)
    rect = np.stack([corners_w, np.roll(corners_w, -1, axis=1)], axis=2)
    return np.concatenate([rays, rect], axis=1).reshape(-1, 2, 3)


def grid_segments(*, half: float, cell: float) -> np.ndarray:
    """Lines of a square grid on z = 0 from -half to +half metres, `cell` apart."""
    r = np.arange(-half, half + 0.5 * cell, cell)
    lo, hi, zero = np.full_like(r, -half), np.full_like(r, half), np.zeros_like(r)
    along_x = np.stack([np.stack([lo, r, zero], axis=1), np.stack([hi, r, zero], axis=1)], axis=1)
    along_y = np.stack([np.stack([r, lo, zero], axis=1), np.stack([r, hi, zero], axis=1)], axis=1)
    return np.concatenate([along_x, along_y])


def polyline_segments(p: np.ndarray) -> np.ndarray:
    """Consecutive points (N, 3) as segments (N - 1, 2, 3)."""
    return np.stack([p[:-1], p[1:]], axis=1) if len(p) >= 2 else np.zeros((0, 2, 3))


def plane_quad(n: np.ndarray, d: float, centre: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A square (4 vertices, 2 faces) of side `size` on plane (n, d), centred at the
    projection of `centre`."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = np.cross(n, a)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(n, b1)
    c = centre - (n @ centre + d) * n
    h = 0.5 * size
    verts = np.stack([c - h * b1 - h * b2, c + h * b1 - h * b2, c + h * b1 + h * b2, c - h * b1 + h * b2])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


class SceneView:
    """Owns the scene nodes of the map; :meth:`draw` replaces them with a snapshot's."""

    def __init__(self, server: viser.ViserServer, *, layers: Layers | None = None) -> None:
        self._server = server
        self.layers = layers or Layers()
        self._handles: dict[str, viser.SceneNodeHandle] = {}
        self.point_scale = 1.0  # the user's factor on the extent-based marker size
        self._point_size = 0.02
        self.displacement: Displacement | None = None  # of the shown map to the one chosen (None: off)
        server.scene.set_up_direction("+z")
        server.initial_camera.position = (-3.2, -5.2, 4.6)
        server.initial_camera.look_at = (0.0, 0.0, 0.0)
        # Software WebGL (headless, remote desktops) pays per pixel: a grid of lines costs
        # far less than viser's shader grid, shadows are off, and so is the default HDRI
        # environment map (it stalls software rendering for seconds).
        server.scene.configure_environment_map(hdri=None)
        server.scene.configure_default_lights(cast_shadow=False)
        server.scene.add_line_segments("/world/grid", grid_segments(half=GRID_HALF_M, cell=1.0).astype(np.float32), COLOR_GRID, thickness=1.0, thickness_units="screen")
        server.scene.add_frame("/world/axes", axes_length=0.5, axes_radius=0.015)
        self._keep_point_shaders(server)

    @staticmethod
    def _keep_point_shaders(server: viser.ViserServer) -> None:
        """Two one-point clouds at the origin (inside the axes, never changed) that keep the
        browser's point shaders compiled. viser's client (1.1.1) builds a new material
        whenever a cloud's colours change and disposes the old one first; three.js then
        frees the shader program when no other material uses it and compiles it again for
        the new one. The map's points change colours at every step (a colour per point), so
        every step compiled the shader again: about 100 ms of the page's time on a room
        step in software WebGL (docs/results/debugger.md). One cloud holds the variant with
        a colour per point, one the single-colour variant (RANSAC inliers and outliers)."""
        origin = np.zeros((2, 3), np.float32)
        tiny = 1e-6  # m: under a pixel (drawn as one, inside the axes' origin)
        server.scene.add_point_cloud(f"{SHADER_KEEPER}/per_point", origin, np.array([[128, 128, 128], [129, 128, 128]], np.uint8), point_size=tiny, point_shape="circle", precision="float32")
        server.scene.add_point_cloud(f"{SHADER_KEEPER}/one_colour", origin[:1], (128, 128, 128), point_size=tiny, point_shape="circle", precision="float32")

    def _visible(self, name: str) -> bool:
        layer = next((v for k, v in NODE_LAYER.items() if name.startswith(k)), None)
        return True if layer is None else bool(getattr(self.layers, layer))

    def set_layer(self, layer: str, visible: bool) -> None:
        """Show or hide a layer (a field of :class:`Layers`)."""
        setattr(self.layers, layer, visible)
        for name, handle in self._handles.items():
            handle.visible = self._visible(name)

    def clear(self) -> None:
        """Remove everything a snapshot drew (the grid and axes stay)."""
        for name in list(self._handles):
            self._keep(name, None)

    def set_point_scale(self, scale: float) -> None:
        """Scale the map's markers (points and RANSAC markers) by `scale`."""
        self.point_scale = float(scale)
        self._apply_point_size()

    def _apply_point_size(self) -> None:
        for name, handle in self._handles.items():
            if isinstance(handle, viser.PointCloudHandle):
                handle.point_size = self._size_of(name)

    def _size_of(self, name: str) -> float:
        return self._point_size * self.point_scale * (1.6 if name in ("/map/inliers", "/map/outliers") else 1.0)

    def _keep(self, name: str, handle: viser.SceneNodeHandle | None) -> None:
        old = self._handles.pop(name, None)
        if handle is None:
            if old is not None:
                old.remove()
            return
        self._handles[name] = handle

    def _segments(self, name: str, segments: np.ndarray, colors: np.ndarray | tuple[int, int, int], *, thickness: float) -> None:
        """Line segments (N, 2, 3) with one colour or one per segment (N, 3). An existing
        node is updated in place (cheaper for the client than a new node)."""
        if len(segments) == 0:
            self._keep(name, None)
            return
        cols = np.broadcast_to(np.asarray(colors, dtype=np.uint8).reshape(-1, 1, 3), (len(segments), 2, 3))
        handle = self._handles.get(name)
        if isinstance(handle, viser.LineSegmentsHandle):
            handle.points = segments.astype(np.float32)
            handle.colors = np.ascontiguousarray(cols)
            if handle.thickness != thickness:
                handle.thickness = thickness
            return
        handle = self._server.scene.add_line_segments(name, segments.astype(np.float32), np.ascontiguousarray(cols), thickness=thickness, thickness_units="screen", visible=self._visible(name))
        self._keep(name, handle)

    def _points(self, name: str, p: np.ndarray, colors: np.ndarray | tuple[int, int, int]) -> None:
        """Points (N, 3) with one colour or one per point (N, 3), sized for the map's
        extent (:func:`viewer.framing.marker_size_m`); updated in place."""
        if len(p) == 0:
            self._keep(name, None)
            return
        cols = np.ascontiguousarray(np.broadcast_to(np.asarray(colors, dtype=np.uint8).reshape(-1, 3), (len(p), 3)))
        size = self._size_of(name)
        handle = self._handles.get(name)
        if isinstance(handle, viser.PointCloudHandle):
            handle.points = p.astype(np.float32)
            handle.colors = cols
            if handle.point_size != size:
                handle.point_size = size
            return
        handle = self._server.scene.add_point_cloud(name, p.astype(np.float32), cols, point_size=size, point_shape="circle", precision="float32", visible=self._visible(name))
        self._keep(name, handle)

    def _mesh(self, name: str, vertices: np.ndarray, faces: np.ndarray, color: tuple[int, int, int], *, opacity: float) -> None:
        """A translucent, double-sided, unshadowed mesh; updated in place."""
        handle = self._handles.get(name)
        if isinstance(handle, viser.MeshHandle):
            handle.vertices = vertices.astype(np.float32)
            handle.faces = faces.astype(np.uint32)
            handle.color = color
            if handle.opacity != opacity:
                handle.opacity = opacity
            return
        handle = self._server.scene.add_mesh_simple(
            name,
            vertices.astype(np.float32),
            faces,
            color=color,
            opacity=opacity,
            material="toon3",
            side="double",
            cast_shadow=False,
            receive_shadow=False,
            visible=self._visible(name),
        )
        self._keep(name, handle)

    def draw(self, snapshot: Snapshot, *, other: Snapshot | None = None, compare: Snapshot | None = None) -> None:
        """Replace the drawn map with `snapshot`'s (call inside `server.atomic()`); `other`
        (the A/B run's snapshot) adds its trajectory, newest camera and label in aquamarine;
        `compare` (another snapshot of the same keyframe) colours the points and lines by
        how far each landmark lies from itself there (`self.displacement`)."""
        self._point_size = marker_size_m(snapshot_bounds(snapshot))
        est = snapshot.estimate
        R, t = est.R_world_camera, est.t_world_camera
        # Cameras: all keyframes grey, the window orange, the newest red.
        frusta = frustum_segments(R, t, snapshot.camera)
        kind = np.zeros(len(t), int)
        kind[snapshot.window] = 1
        kind[-1] = 2  # the newest keyframe is the last
        palette = np.array([COLOR_KEYFRAME, COLOR_WINDOW, COLOR_CURRENT], dtype=np.uint8)
        self._segments("/cameras/frustums", frusta, np.repeat(palette[kind], 8, axis=0), thickness=1.5)
        self._segments("/trajectory/estimate", polyline_segments(t), COLOR_ESTIMATE, thickness=2.0)
        gt = snapshot.ground_truth
        self._segments("/trajectory/ground_truth", polyline_segments(gt.t_world_camera) if gt is not None else np.zeros((0, 2, 3)), COLOR_GROUND_TRUTH, thickness=1.5)

        pts, lns = snapshot.points, snapshot.lines
        finite = np.all(np.isfinite(pts.p_world), axis=1)
        seg_ok = np.all(np.isfinite(lns.segment_world.reshape(-1, 6)), axis=1)
        self.displacement = displacement(snapshot, compare) if compare is not None else None
        point_colors, line_colors = self._map_colors(snapshot, finite=finite, seg_ok=seg_ok)
        self._points("/map/points", pts.p_world[finite], point_colors)
        self._segments("/map/lines", lns.segment_world[seg_ok], line_colors, thickness=3.0 if snapshot.variant.with_lines else 1.0)
        self._draw_links(snapshot, finite=finite)
        # RANSAC consensus of the last detection: inliers green, outliers red (drawn larger).
        for state, name, color in ((INLIER, "inliers", COLOR_INLIER), (OUTLIER, "outliers", COLOR_OUTLIER)):
            self._points(f"/map/{name}", pts.p_world[finite & (pts.detection == state)], color)
            self._segments(f"/map/{name[:-1]}_lines", lns.segment_world[seg_ok & (lns.detection == state)], color, thickness=6.0)

        # Planes: the hull of the inliers (a triangle fan) and an optional large quad;
        # faint under -wo variants, whose optimizer does not use them.
        opacity = PLANE_OPACITY_UNUSED if not snapshot.variant.uses_planes else PLANE_OPACITY
        names = set()
        for plane in snapshot.planes:
            r, g, b = (int(c) for c in plane_color(plane.id))
            color = (r, g, b)
            hull = plane.hull_world
            if len(hull) >= 3:
                name = f"/map/planes/{plane.id}"
                faces = np.stack([np.zeros(len(hull) - 2, int), np.arange(1, len(hull) - 1), np.arange(2, len(hull))], axis=1)
                self._mesh(name, hull, faces, color, opacity=opacity)
                names.add(name)
                centre = hull.mean(axis=0)
            else:
                centre = -plane.d * plane.n
            name = f"/map/infinite_planes/{plane.id}"
            verts, faces = plane_quad(plane.n, plane.d, centre, INFINITE_PLANE_SIZE_M)
            self._mesh(name, verts, faces, color, opacity=0.12)
            names.add(name)
        for name in [n for n in self._handles if n.startswith(("/map/planes/", "/map/infinite_planes/")) and n not in names]:
            self._keep(name, None)
        self._draw_other(other)

    def _map_colors(self, snapshot: Snapshot, *, finite: np.ndarray, seg_ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Colours (N, 3) of the finite points and lines: by displacement when it is on
        (viridis up to its scale), else by plane, lines faded under P variants (whose
        optimizer does not use them)."""
        d = self.displacement
        if d is not None:
            return displacement_colors(d.point_m[finite], scale_m=d.scale_m), displacement_colors(d.line_m[seg_ok], scale_m=d.scale_m)
        line_colors = plane_color(snapshot.lines.plane[seg_ok])
        if not snapshot.variant.with_lines:
            line_colors = (LINE_FADE * line_colors.astype(float) + (1.0 - LINE_FADE) * np.array(COLOR_FADED, dtype=float)).astype(np.uint8)
        return plane_color(snapshot.points.plane[finite]), line_colors

    def _draw_links(self, snapshot: Snapshot, *, finite: np.ndarray) -> None:
        """With the displacement on: a thin segment from each matched point to where the
        other snapshot has it (world frame, m); none otherwise."""
        d = self.displacement
        links = np.zeros((0, 2, 3))
        if d is not None:
            p_world = np.asarray(snapshot.points.p_world, float)
            matched = finite & np.isfinite(d.point_m) & (d.point_m > 0.0)
            links = np.stack([p_world[matched], d.p_world_other[matched]], axis=1)
        self._segments("/map/displacement", links, COLOR_DISPLACEMENT_LINK, thickness=1.0)

    def _draw_other(self, other: Snapshot | None) -> None:
        """The A/B run's trajectory, its newest camera (larger and thicker than A's) and a
        label "B: <variant>" at that camera; nothing without an A/B run."""
        if other is None:
            self._segments("/ab/trajectory", np.zeros((0, 2, 3)), COLOR_B, thickness=3.0)
            self._segments("/ab/camera", np.zeros((0, 2, 3)), COLOR_B, thickness=B_THICKNESS)
            self._label_b(None, "")
            return
        t_world_camera = other.estimate.t_world_camera
        self._segments("/ab/trajectory", polyline_segments(t_world_camera), COLOR_B, thickness=3.0)
        R_world_camera = other.estimate.R_world_camera
        frustum = frustum_segments(R_world_camera[-1:], t_world_camera[-1:], other.camera, depth=B_FRUSTUM_DEPTH_M)
        self._segments("/ab/camera", frustum, COLOR_B, thickness=B_THICKNESS)
        self._label_b(t_world_camera[-1], f"B: {other.variant}")

    def _label_b(self, p_world: np.ndarray | None, text: str) -> None:
        """The A/B run's label at `p_world` (B's newest camera centre, m); removed with None."""
        if p_world is None:
            self._keep("/ab/label", None)
            return
        handle = self._handles.get("/ab/label")
        if isinstance(handle, viser.LabelHandle):
            handle.position = np.asarray(p_world, float)
            if handle.text != text:
                handle.text = text
            return
        handle = self._server.scene.add_label("/ab/label", text, position=np.asarray(p_world, float), anchor="bottom-left", visible=self._visible("/ab/label"))
        self._keep("/ab/label", handle)
