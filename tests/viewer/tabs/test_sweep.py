"""The Sweep tab (viewer/tabs/sweep.py): `serve --sweep DIR` shows a sweep's table, plots and
run counts beside the usual views; Reload reads a growing sweep again; Reset and steps leave
it alone; without a sweep the tab says how to open one."""

from __future__ import annotations

import json
import pathlib
import socket

import numpy as np
from PIL import Image

from backend.pipeline.sim_engine import SimEngine, SimSettings
from viewer.app import Debugger, ViewerSettings
from viewer.commands import Command
from viewer.tabs import SweepTab


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _sweep(folder: pathlib.Path, statuses: list[str]) -> None:
    folder.mkdir(exist_ok=True)
    (folder / "results.json").write_text(json.dumps([{"scene": "room", "variant": "PL-w", "status": s} for s in statuses]))
    (folder / "table.md").write_text("| sequence | P-wo | PL-w |\n|---|---|---|\n| room | 1.20 | 0.90 |\n")
    Image.fromarray(np.full((40, 60, 3), 200, np.uint8)).save(folder / "ate_by_variant.png")


def _debugger(settings: ViewerSettings) -> Debugger:
    d = Debugger(SimEngine(SimSettings(window=4, max_iterations=2)), port=_free_port(), settings=settings)
    d.server.scene.configure_environment_map(hdri=None)
    return d


def test_a_sweep_is_shown_reloaded_and_kept_through_steps_and_reset(tmp_path: pathlib.Path) -> None:
    folder = tmp_path / "sweep"
    _sweep(folder, ["ok", "failed"])
    d = _debugger(ViewerSettings(compare=False, plots=False, sweep=folder))
    try:
        tab = d._tab(SweepTab)
        text = tab.markdown.content
        assert "2 runs: 1 failed, 1 ok" in text and "| room | 1.20 | 0.90 |" in text
        assert tab.images["ate_by_variant.png"].visible and not tab.images["time_by_stage.png"].visible
        _sweep(folder, ["ok", "ok", "ok"])  # the sweep goes on
        tab.read()
        assert "3 runs: 3 ok" in tab.markdown.content
        d.submit(Command.STEP)
        d.wait_idle()
        d.submit(Command.RESET)
        d.wait_idle()
        assert "3 runs: 3 ok" in tab.markdown.content
    finally:
        d.stop()


def test_without_a_sweep_the_tab_says_how_to_open_one() -> None:
    d = _debugger(ViewerSettings(compare=False, plots=False))
    try:
        tab = d._tab(SweepTab)
        assert "coplanar serve --sweep DIR" in tab.markdown.content and not tab.reload.visible
    finally:
        d.stop()
