"""Every tab's camera, each the browser's own: framed on the shown map until the user moves
it (then left alone), re-framed when the tab's canvas changes size; with *Follow keyframe*,
kept at its offset to the newest keyframe. A tab whose view cannot be set (a camera it
reported that the debugger cannot use) is skipped with one log line: it never stops a step."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np
import viser

from backend.pipeline.snapshot import Snapshot
from viewer.framing import follow_pose, framing_pose, snapshot_bounds

log = logging.getLogger(__name__)
VIEW_SETTLE_S = 1.5  # a view set by the debugger counts as untouched this long (the browser animates to it)


def has_camera(client: viser.ClientHandle) -> bool:
    """Whether the tab has reported its camera (viser asserts on reading it before)."""
    try:
        client.camera.update_timestamp  # noqa: B018
    except AssertionError:
        return False
    return True


class CameraViews:
    """The views of `server`'s tabs; `shown()`: the snapshot on screen (None: none yet)."""

    def __init__(self, server: viser.ViserServer, *, shown: Callable[[], Snapshot | None]) -> None:
        self.server = server
        self._shown = shown
        # Per client: the view this debugger last set (None: the user has moved it since,
        # so it is no longer re-framed as the map grows).
        self._auto_view: dict[int, tuple[np.ndarray, np.ndarray, float, float] | None] = {}

    def forget(self) -> None:
        """Every view is framed afresh with the next snapshot (Reset)."""
        self._auto_view = {}

    def on_connect(self, client: viser.ClientHandle) -> None:
        """Frame a new tab's view as soon as it reports its camera (its canvas size is
        needed); a tab that connects before the first keyframe is framed with it."""

        def on_camera(cam: viser.CameraHandle) -> None:
            if self._shown() is None:
                return
            last = self._auto_view.get(client.client_id, "never")
            if isinstance(last, str):
                self.frame(client, keep_direction=False)
            elif last is not None and abs(float(cam.aspect) - last[3]) > 0.02 and self._view_unchanged(client, last):
                self.frame(client, keep_direction=False)  # the canvas changed size (panels docked, window resized)

        client.camera.on_update(on_camera)

    def update(self, snapshot: Snapshot, *, follow: bool) -> None:
        """Views that the user has not moved keep framing the map as it grows; with
        `follow`, every view keeps its offset to the newest keyframe."""
        position, look_at = framing_pose(snapshot_bounds(snapshot), fov_y=float(self.server.initial_camera.fov), aspect=1.2)
        self.server.initial_camera.position = position  # also viser's own "reset view"
        self.server.initial_camera.look_at = look_at
        for client_id, client in self.server.get_clients().items():
            try:
                self._update_view(client_id, client, snapshot, follow=follow)
            except Exception as e:
                log.warning("view of client %s not updated: %s: %s", client_id, type(e).__name__, e)

    def _update_view(self, client_id: int, client: viser.ClientHandle, snapshot: Snapshot, *, follow: bool) -> None:
        if not has_camera(client):
            return  # no camera reported yet: framed when it is (on_connect)
        if follow:
            self._follow(client, snapshot)
            return
        last = self._auto_view.get(client_id, "never")
        if isinstance(last, str) or (last is not None and self._view_unchanged(client, last)):
            self.frame(client, keep_direction=False)
        else:
            self._auto_view[client_id] = None

    @staticmethod
    def _view_unchanged(client: viser.ClientHandle, view: tuple[np.ndarray, np.ndarray, float, float]) -> bool:
        """The client's view is the one set last, or the browser may still be animating
        towards it (its camera moves smoothly for about a second)."""
        cam = client.camera
        if time.monotonic() - view[2] < VIEW_SETTLE_S:
            return True
        return bool(np.allclose(cam.position, view[0], atol=1e-3) and np.allclose(cam.look_at, view[1], atol=1e-3))

    def frame(self, client: viser.ClientHandle | None, *, keep_direction: bool) -> tuple[np.ndarray, np.ndarray] | None:
        """Frame the shown map in `client`'s view (along its current direction, or the
        default one); returns the view set. The view then follows the growing map again
        until the user moves it."""
        snapshot = self._shown()
        if client is None or snapshot is None:
            return None
        if not has_camera(client):  # framed once it reports its camera (on_connect)
            return None
        cam = client.camera
        fov, aspect = float(cam.fov), float(cam.aspect)
        kwargs = {}
        if keep_direction:
            direction = np.asarray(cam.position, float) - np.asarray(cam.look_at, float)
            if np.linalg.norm(direction) > 1e-9:
                kwargs["direction"] = direction
        position, look_at = framing_pose(snapshot_bounds(snapshot), fov_y=fov, aspect=aspect, **kwargs)
        with client.atomic():  # position first: viser moves look_at along with it
            cam.position = position
            cam.look_at = look_at
        self._auto_view[client.client_id] = (position, look_at, time.monotonic(), aspect)
        return position, look_at

    @staticmethod
    def _follow(client: viser.ClientHandle, snapshot: Snapshot) -> None:
        cam = client.camera
        position, look_at = follow_pose(cam.position, cam.look_at, snapshot.estimate.t_world_camera[-1])
        with client.atomic():  # position first: viser moves look_at along with it
            cam.position = position
            cam.look_at = look_at
