"""The Sweep tab: a `coplanar sweep`'s results beside the usual views (`serve --sweep DIR`):
its Table II-shaped summary (`table.md`), its plots (ATE per variant across runs, time
per stage) and how many runs finished or failed (`results.json`). Reload reads the folder
again (a sweep still running adds runs). Without `--sweep` the tab says how to open one."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import viser
from PIL import Image

from viewer.settings import ViewerSettings
from viewer.tabs.base import Shown, TabActions

PLOTS: tuple[tuple[str, str], ...] = (("ate_by_variant.png", "ATE per variant"), ("time_by_stage.png", "Time per stage"))


def sweep_summary(folder: pathlib.Path) -> str:
    """Markdown: the runs' status counts (results.json) and the table (table.md)."""
    lines = [f"**Sweep** `{folder}`"]
    try:
        rows = json.loads((folder / "results.json").read_text())
        runs = rows.get("runs", rows) if isinstance(rows, dict) else rows
        status = [str(r.get("status", "?")) for r in runs if isinstance(r, dict)]
        counts = ", ".join(f"{status.count(s)} {s}" for s in sorted(set(status)))
        lines.append(f"{len(status)} runs: {counts}" if status else "no runs yet")
    except (OSError, ValueError) as e:
        lines.append(f"*results.json: {getattr(e, 'strerror', None) or e}*")
    try:
        table = (folder / "table.md").read_text()
        lines.append(table.split("\n", 1)[1] if table.startswith("# ") else table)  # its title: the tab says what it is
    except OSError:
        lines.append("*no table.md yet*")
    return "\n\n".join(lines)


def _png(path: pathlib.Path) -> np.ndarray | None:
    try:
        with Image.open(path) as image:
            return np.asarray(image.convert("RGB"))
    except (OSError, ValueError):
        return None


class SweepTab:
    title = "Sweep"
    icon = viser.Icon.TABLE

    def __init__(self, actions: TabActions, settings: ViewerSettings) -> None:
        self.folder = settings.sweep

    def build(self, gui: viser.GuiApi) -> None:
        self.markdown = gui.add_markdown("")
        self.images = {name: gui.add_image(np.zeros((1, 1, 3), np.uint8), label=label, format="png", visible=False) for name, label in PLOTS}
        self.reload = gui.add_button("Reload", icon=viser.Icon.REFRESH, hint="read the sweep's folder again", visible=self.folder is not None)
        self.reload.on_click(lambda _: self.read())
        self.read()

    def read(self) -> None:
        """Show what the sweep's folder holds now."""
        if self.folder is None:
            self.markdown.content = "No sweep opened: `coplanar serve --sweep DIR` shows the results of `coplanar sweep --out DIR` here."
            return
        self.markdown.content = sweep_summary(self.folder)
        for name, handle in self.images.items():
            picture = _png(self.folder / name)
            if picture is not None:
                handle.image = picture
            handle.visible = picture is not None

    def show(self, shown: Shown) -> None:
        """A sweep's results do not follow the keyframe shown."""

    def clear(self) -> None:
        """Reset leaves the sweep's results as they are."""
