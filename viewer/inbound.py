"""Which client messages reach viser and the debugger: an allow-list of the message types the
debugger's page sends, each checked field by field before viser decodes it.

viser dispatches every message type it knows to whatever handler is registered for it and
applies a GUI update to any property of a control (`update_cb`, `removed`, `sync_cb`, ...),
casting the value with the control's current type. The browser's own client only ever
sends, for this debugger:

- `GuiUpdateMessage` with `updates == {"value": v}` for an input control;
- `CommandTriggerMessage` for a keyboard shortcut;
- `ViewerCameraMessage` for its view;
- `ShareUrlRequest` / `ShareUrlDisconnect` when the share button is shown (`--share`);
- `FileTransferStartUpload` / `FileTransferPart` for upload controls (the debugger has none
  today; the rules hold for any that are added).

Everything else is refused. A value is refused unless it has the control's type, is finite
and in the control's range or options, and the control is enabled and visible; the
verdict then names the control so that the tab can be told (viewer/guard.py).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import viser
from viser import _messages
from viser.infra._messages import wire_field_names

MAX_TEXT_CHARS = 10_000
MAX_NAME_CHARS = 255
MAX_IMAGE_PIXELS_PER_SIDE = 100_000
MAX_COORDINATE = 1e9
MAX_UPLOADS_PER_CLIENT = 4

# Control kinds whose values the browser sends, by viser handle class.
BUTTONS = (viser.GuiButtonHandle,)
CHECKBOXES = (viser.GuiCheckboxHandle,)
NUMBERS = (viser.GuiSliderHandle, viser.GuiNumberHandle)
CHOICES = (viser.GuiDropdownHandle, viser.GuiButtonGroupHandle)
TEXTS = (viser.GuiTextHandle,)
UPLOADS = (viser.GuiUploadButtonHandle,)

# The message types admitted, with the fields each carries on the wire (all of them, always).
FIELDS: dict[str, frozenset[str]] = {
    name: frozenset(wire_field_names(getattr(_messages, name)))
    for name in (
        "GuiUpdateMessage",
        "CommandTriggerMessage",
        "ViewerCameraMessage",
        "ShareUrlRequest",
        "ShareUrlDisconnect",
        "FileTransferStartUpload",
        "FileTransferPart",
    )
}


@dataclasses.dataclass(frozen=True)
class Verdict:
    """What becomes of one client frame. `kind`: its message type (or what it was instead
    of a message). `reason`: why it was refused, one line. `control`: the control a refused
    value was meant for, so the sender can be told and its widget set back."""

    accepted: bool
    kind: str
    reason: str = ""
    control: viser.GuiInputHandle[Any] | viser.GuiButtonHandle | None = None


def _accept(kind: str) -> Verdict:
    return Verdict(True, kind)


def _refuse(kind: str, reason: str, control: Any = None) -> Verdict:
    return Verdict(False, kind, reason, control)


def is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite_vector(value: object, length: int) -> bool:
    return isinstance(value, (list, tuple)) and len(value) == length and all(is_number(v) and math.isfinite(v) and abs(v) <= MAX_COORDINATE for v in value)


def _short_text(value: object, limit: int = MAX_NAME_CHARS) -> bool:
    return isinstance(value, str) and len(value) <= limit and "\x00" not in value


def _fmt(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def control_label(handle: Any) -> str:
    """The control's label (not every viser control has one)."""
    return str(getattr(handle, "label", None) or type(handle).__name__.removeprefix("Gui").removesuffix("Handle").lower())


def check_value(handle: Any, value: object) -> str | None:
    """Why `value` cannot be `handle`'s value (one line naming the control), or None."""
    label = control_label(handle)
    if isinstance(handle, BUTTONS):
        return None if value is True else f"{label} is a button: a click sends true, not {_fmt(value)}"
    if isinstance(handle, CHECKBOXES):
        return None if isinstance(value, bool) else f"{label} is a checkbox: true or false, not {_fmt(value)}"
    if isinstance(handle, NUMBERS):
        low, high = handle.min, handle.max
        span = f" from {low:g} to {high:g}" if low is not None and high is not None else ""
        if not is_number(value) or not math.isfinite(value):  # type: ignore[arg-type]
            return f"{label} takes a finite number{span}, not {_fmt(value)}"
        if (low is not None and value < low) or (high is not None and value > high):  # type: ignore[operator]
            return f"{label} takes a number{span}, not {_fmt(value)}"
        return None
    if isinstance(handle, CHOICES):
        if isinstance(value, str) and value in tuple(handle.options):
            return None
        return f"{label} takes one of {', '.join(map(str, handle.options))}; not {_fmt(value)}"
    if isinstance(handle, TEXTS):
        return None if _short_text(value, MAX_TEXT_CHARS) else f"{label} takes text of at most {MAX_TEXT_CHARS} characters"
    return f"{label} ({type(handle).__name__}) takes no value from a browser"


def check_camera(fields: dict[str, Any]) -> str | None:
    """Why a reported view is unusable (None: finite, a unit rotation, a real frustum)."""
    wxyz = fields["wxyz"]
    if not _finite_vector(wxyz, 4) or abs(math.sqrt(sum(v * v for v in wxyz)) - 1.0) > 1e-2:
        return "camera orientation is not a finite unit quaternion"
    for name in ("position", "look_at", "up_direction"):
        if not _finite_vector(fields[name], 3):
            return f"camera {name} is not 3 finite numbers"
    if math.sqrt(sum(v * v for v in fields["up_direction"])) < 1e-9:
        return "camera up direction is zero"
    fov, near, far = fields["fov"], fields["near"], fields["far"]
    if not (is_number(fov) and 0.0 < fov < math.pi):
        return f"camera field of view {_fmt(fov)} is not in (0, pi)"
    if not (is_number(near) and is_number(far) and 0.0 < near < far and math.isfinite(far)):
        return "camera near and far planes are not 0 < near < far < inf"
    for name in ("image_height", "image_width"):
        size = fields[name]
        if not (isinstance(size, int) and not isinstance(size, bool) and 0 < size <= MAX_IMAGE_PIXELS_PER_SIDE):
            return f"camera {name} {_fmt(size)} is not a pixel count"
    return None


@dataclasses.dataclass
class _Upload:
    control: str
    remaining_bytes: int
    part_count: int


class InboundFilter:
    """Checks client frames (module docstring). `find_control(client_id, uuid)`: the input
    control with that uuid in the server's or that client's GUI (None: none);
    `is_command(uuid)`: a registered keyboard command; `share`: admit share requests;
    `max_upload_bytes`: the largest upload admitted."""

    def __init__(
        self,
        *,
        find_control: Callable[[int, str], Any],
        is_command: Callable[[str], bool],
        share: bool,
        max_upload_bytes: int,
    ) -> None:
        self._find_control = find_control
        self._is_command = is_command
        self._share = share
        self._max_upload_bytes = max_upload_bytes
        self._uploads: dict[tuple[int, str], _Upload] = {}
        self._uploads_lock = threading.Lock()  # checks run on the server's loop, forget() on a disconnect callback's thread

    def check(self, client_id: int, frame: bytes | str) -> Verdict:
        if not isinstance(frame, bytes):
            return _refuse("text frame", "a text frame (viser's messages are binary msgpack)")
        try:
            mapping = msgspec.msgpack.decode(frame)
        except (msgspec.DecodeError, ValueError, TypeError, RecursionError):
            return _refuse("undecodable", "not msgpack")
        if not isinstance(mapping, dict) or not isinstance(mapping.get("type"), str):
            return _refuse("not a message", "msgpack without a message type")
        kind: str = mapping["type"]
        if kind not in FIELDS:
            return _refuse(kind[:60], "not a message the debugger's page sends")
        fields = {k: v for k, v in mapping.items() if k != "type"}
        if set(fields) != FIELDS[kind]:
            return _refuse(kind, f"fields {sorted(map(str, fields))} instead of {sorted(FIELDS[kind])}")
        with self._uploads_lock:
            verdict = getattr(self, f"_check_{kind}")(client_id, fields)
        if verdict.accepted:
            try:  # what viser will do with it; a frame it cannot decode never reaches it
                _messages.Message.deserialize(frame)
            except Exception as e:
                return _refuse(kind, f"viser cannot decode it: {type(e).__name__}")
        return verdict

    def forget(self, client_id: int) -> None:
        """Drop a disconnected client's upload book-keeping."""
        with self._uploads_lock:
            for key in [k for k in self._uploads if k[0] == client_id]:
                del self._uploads[key]

    # ---------------------------------------------------------------- per type

    def _check_GuiUpdateMessage(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        kind = "GuiUpdateMessage"
        uuid, updates = fields["uuid"], fields["updates"]
        if not _short_text(uuid) or not isinstance(updates, dict):
            return _refuse(kind, "malformed uuid or updates")
        if set(updates) != {"value"}:
            return _refuse(kind, f"writes {sorted(map(str, updates))}: a browser writes only a control's value")
        handle = self._find_control(client_id, uuid)
        if handle is None:
            return _refuse(kind, "no such control")
        label = control_label(handle)
        if isinstance(handle, UPLOADS):
            return _refuse(kind, f"{label} takes files by upload only", handle)
        disabled, visible = bool(getattr(handle, "disabled", False)), bool(getattr(handle, "visible", True))
        if disabled or not visible:
            return _refuse(kind, f"{label} is {'disabled' if disabled else 'hidden'} now", handle)
        why = check_value(handle, updates["value"])
        return _accept(kind) if why is None else _refuse(kind, why, handle)

    def _check_CommandTriggerMessage(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        uuid = fields["uuid"]
        if _short_text(uuid) and self._is_command(uuid):
            return _accept("CommandTriggerMessage")
        return _refuse("CommandTriggerMessage", "no such command")

    def _check_ViewerCameraMessage(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        why = check_camera(fields)
        return _accept("ViewerCameraMessage") if why is None else _refuse("ViewerCameraMessage", why)

    def _check_ShareUrlRequest(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        return _accept("ShareUrlRequest") if self._share else _refuse("ShareUrlRequest", "sharing is off (serve --share turns it on)")

    def _check_ShareUrlDisconnect(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        return _accept("ShareUrlDisconnect") if self._share else _refuse("ShareUrlDisconnect", "sharing is off (serve --share turns it on)")

    def _check_FileTransferStartUpload(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        kind = "FileTransferStartUpload"
        target, transfer = fields["source_component_uuid"], fields["transfer_uuid"]
        size, parts = fields["size_bytes"], fields["part_count"]
        if not all(_short_text(fields[k]) for k in ("source_component_uuid", "transfer_uuid", "filename", "mime_type")):
            return _refuse(kind, "malformed names")
        handle = self._find_control(client_id, target)
        if not isinstance(handle, UPLOADS):
            return _refuse(kind, f"{control_label(handle) if handle is not None else 'the target'} is not an upload control", handle)
        if handle.disabled or not handle.visible:
            return _refuse(kind, f"{handle.label} is disabled or hidden now", handle)
        if not (isinstance(size, int) and isinstance(parts, int)) or isinstance(size, bool) or isinstance(parts, bool):
            return _refuse(kind, "malformed size")
        if not 0 <= size <= self._max_upload_bytes:
            return _refuse(kind, f"{handle.label}: files up to {self._max_upload_bytes / 2**20:g} MiB", handle)
        if not (0 <= parts <= max(size, 1)) or (parts == 0) != (size == 0):
            return _refuse(kind, "part count does not fit the size")
        if (client_id, transfer) in self._uploads or sum(k[0] == client_id for k in self._uploads) >= MAX_UPLOADS_PER_CLIENT:
            return _refuse(kind, f"a repeated transfer or more than {MAX_UPLOADS_PER_CLIENT} at once")
        if size > 0:
            self._uploads[(client_id, transfer)] = _Upload(control=target, remaining_bytes=size, part_count=parts)
        return _accept(kind)

    def _check_FileTransferPart(self, client_id: int, fields: dict[str, Any]) -> Verdict:
        kind = "FileTransferPart"
        upload = self._uploads.get((client_id, fields["transfer_uuid"])) if isinstance(fields["transfer_uuid"], str) else None
        if upload is None or fields["source_component_uuid"] != upload.control:
            return _refuse(kind, "no upload of this client's under that transfer")
        content, index = fields["content"], fields["part_index"]
        if not isinstance(content, bytes) or not (isinstance(index, int) and not isinstance(index, bool) and 0 <= index < upload.part_count):
            return _refuse(kind, "malformed part")
        if len(content) > upload.remaining_bytes:
            return _refuse(kind, "more bytes than the upload declared")
        upload.remaining_bytes -= len(content)
        if upload.remaining_bytes == 0:
            del self._uploads[(client_id, fields["transfer_uuid"])]
        return _accept(kind)
