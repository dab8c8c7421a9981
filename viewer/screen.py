"""What the debugger's panels show, as plain values: to compare two sessions screen for
screen (a replay against the live run it recorded: tests and benchmarks/bench_replay.py)."""

from __future__ import annotations

import hashlib
from typing import Any

import viser


def _value(handle: object) -> str | None:
    """A panel element's content: a markdown's text, an image's digest (the bytes sent to
    the page), an input's value; None for anything else (buttons, folders)."""
    if isinstance(handle, viser.GuiMarkdownHandle):
        return handle.content if handle.visible else "(hidden)"
    if isinstance(handle, viser.GuiImageHandle):
        if not handle.visible:
            return "(hidden)"
        data = getattr(handle, "_data", None)
        return f"image {hashlib.sha1(data).hexdigest()[:12]}" if isinstance(data, bytes) else None
    if isinstance(handle, viser.GuiTextHandle | viser.GuiDropdownHandle):
        return str(handle.value)
    return None


def screen_contents(debugger: Any, *, source: str | None = None) -> dict[str, str]:
    """Every tab's markdown and image and the Shown / Variant fields and status line of
    `debugger`, by "tab.attribute"; `source` (the engine's name) is replaced by "SOURCE"
    wherever it appears, so that a replay and its live run compare equal. The plots are drawn on their own
    thread: wait for them first (`debugger.wait_plots()`)."""
    out: dict[str, str] = {}
    for tab in debugger.tabs:
        for name, handle in vars(tab).items():
            value = _value(handle)
            if value is not None:
                out[f"{type(tab).__name__}.{name}"] = value
    out["status"] = debugger.status.content
    out["shown"] = str(debugger.keyframe_label.value)
    out["variant"] = str(debugger.variant.value)
    out["layer_note"] = debugger.layer_note.content
    if source is not None:
        out = {key: value.replace(source, "SOURCE") for key, value in out.items()}
    return out
