"""The debugger's dense layer: the shown keyframe's map checked against a TSDF mesh of the
keyframes' depth fused at their estimated poses (`backend.eval.dense`), built in a thread of
its own so that stepping never waits for it (the newest request wins), and drawn as one
mesh node. Depth maps are kept per frame, so a later keyframe fuses only the new ones'
depth from scratch (the volume itself is rebuilt: every pose may have moved)."""

from __future__ import annotations

import threading
import time

import numpy as np
import viser

from backend.data.source import RenderedTruth
from backend.pipeline.snapshot import Snapshot

NODE = "/dense/mesh"
MESH_COLOR = (200, 200, 190)


class DenseLayer:
    """Builds and shows the dense mesh of the requested snapshot (`request`); `note` (a GUI
    markdown handle) says what is drawn or why nothing is."""

    def __init__(self, server: viser.ViserServer, source, note) -> None:
        self.server = server
        self.source = source
        self.note = note
        self.enabled = False
        self.built = 0  # meshes drawn (for tests)
        self._depth: dict[int, np.ndarray] = {}
        self._request: Snapshot | None = None
        self._event = threading.Event()
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="coplanar-dense", daemon=True)
        self._thread.start()

    def request(self, snapshot: Snapshot | None) -> None:
        """Build the mesh of `snapshot` (when the layer is on)."""
        if not self.enabled or snapshot is None:
            return
        self._request = snapshot
        self._event.set()

    def set_enabled(self, on: bool, snapshot: Snapshot | None) -> None:
        self.enabled = bool(on)
        if on:
            self.note.content = "*dense mesh: building …*" if snapshot is not None else "*dense mesh: step first*"
            self.request(snapshot)
        else:
            self.server.scene.remove_by_name(NODE)
            self.note.content = ""

    def clear(self) -> None:
        """Forget the drawn mesh (reset): nothing is shown until the next request."""
        self._request = None
        self.server.scene.remove_by_name(NODE)
        self.note.content = "*dense mesh: step first*" if self.enabled else ""

    def stop(self) -> None:
        self._stopped.set()
        self._event.set()
        self._thread.join(timeout=10.0)

    def _loop(self) -> None:
        while not self._stopped.is_set():
            if not self._event.wait(timeout=0.5):
                continue
            self._event.clear()
            snapshot, self._request = self._request, None
            if snapshot is None or not self.enabled:
                continue
            try:
                self._build(snapshot)
            except Exception as error:
                self.note.content = f"*dense mesh: {' '.join(str(error).split())}*"

    def _build(self, snapshot: Snapshot) -> None:
        from backend.eval.dense import distance_to_planes, fuse_keyframes, keyframe_frames, map_bounds

        t0 = time.perf_counter()
        frames = keyframe_frames(self.source, snapshot.estimate.timestamp_ns)
        t = np.asarray(snapshot.estimate.t_world_camera)
        fusion = fuse_keyframes(self.source, frames, np.asarray(snapshot.estimate.R_world_camera), t, map_bounds(snapshot.points.p_world, t), depth_cache=self._depth)
        mesh = fusion.mesh()
        vertices = np.asarray(mesh.vertices, dtype=np.float32)
        faces = np.asarray(mesh.triangles, dtype=np.uint32)
        if not self.enabled:
            return
        if len(faces) == 0:
            self.server.scene.remove_by_name(NODE)
            self.note.content = f"*dense mesh of keyframe {snapshot.keyframe}: empty (no depth in range)*"
            return
        self.server.scene.add_mesh_simple(
            NODE, vertices=vertices, faces=faces, color=MESH_COLOR, material="toon3", side="double", cast_shadow=False, receive_shadow=False
        )  # as the plane patches: lit without the environment map
        text = f"*dense mesh of keyframe {snapshot.keyframe} ({fusion.keyframes} keyframes at their estimated poses, {fusion.voxel_m * 100:.0f} cm voxels): {len(faces)} triangles"
        if isinstance(self.source, RenderedTruth):
            d = 100.0 * distance_to_planes(vertices, self.source.plane_table)
            text += f"; median distance to the true planes {np.median(d):.2f} cm"
        self.note.content = text + f"; built in {time.perf_counter() - t0:.1f} s*"
        self.built += 1
