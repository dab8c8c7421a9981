"""The Plots tab's figure (viewer/plots.py): a plane event only where the planes changed,
both costs visible on a log axis without an offset text, legends above the data, a unit
on every axis. The figure is caught as `plots_png` saves it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from backend.pipeline.sim_engine import SimEngine, SimSettings
from backend.pipeline.snapshot import PlaneLandmark, Snapshot
from viewer import plots

UNITS = ("(cm)", "(ms)", "(count)", "(unitless", "(m/s)", "(mrad/s)", "(index)")


def drawn_figure(monkeypatch: pytest.MonkeyPatch, series: list[Snapshot], *, current: int | None):
    """The matplotlib figure `plots.plots_png` draws for `series`."""
    from matplotlib.figure import Figure

    caught = []
    save = Figure.savefig

    def catch(self, *args, **kwargs):
        caught.append(self)
        return save(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", catch)
    plots.plots_png(series, current=current)
    monkeypatch.setattr(Figure, "savefig", save)
    return caught[-1]


def _plane_ticks(figure) -> np.ndarray:
    """The keyframes with a tick on the events strip's plane row (y = 2)."""
    strip = next(ax for ax in figure.axes if "lost" in [t.get_text() for t in ax.get_yticklabels()])
    offsets = [c.get_offsets() for c in strip.collections if len(c.get_offsets())]
    points = np.concatenate(offsets) if offsets else np.zeros((0, 2))
    return np.unique(points[points[:, 1] == 2][:, 0])


def check_plots(figure, series: list[Snapshot]) -> None:
    """What the issue asks of the plots of `series` (one snapshot per keyframe)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    counts = np.array([len(s.planes) for s in series])
    ids = [{p.id for p in s.planes} for s in series]
    changed = [s.keyframe for i, s in enumerate(series) if (ids[i] != ids[i - 1] if i else s.keyframe == 0 and ids[i])]
    np.testing.assert_array_equal(_plane_ticks(figure), changed)
    assert len(changed) < len(series) or np.all(np.diff(counts) != 0)
    cost = next(ax for ax in figure.axes if ax.get_ylabel().startswith("cost"))
    assert cost.get_yscale() == "log"
    styles = {line.get_label(): line.get_linestyle() for line in cost.get_lines()}
    assert len(set(styles.values())) == 2, styles  # before and after drawn differently
    renderer = canvas.get_renderer()
    for ax in figure.axes:
        assert ax.yaxis.get_offset_text().get_text() == "", ax.get_ylabel()
        if ax.get_ylabel():
            assert any(unit in ax.get_ylabel() for unit in UNITS), ax.get_ylabel()
        legend = ax.get_legend()
        if legend is not None:
            assert legend.get_window_extent(renderer).y0 >= ax.get_window_extent(renderer).y1 - 1, ax.get_ylabel()
    labels = [t.get_text() for ax in figure.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert any("plane created" in label for label in labels), labels


@pytest.fixture(scope="module")
def series() -> list[Snapshot]:
    engine = SimEngine(SimSettings(window=4, max_iterations=2))
    return [engine.step() for _ in range(8)]


def _with_planes(snapshot: Snapshot, ids: list[int], *, template: PlaneLandmark, cost: float) -> Snapshot:
    planes = tuple(dataclasses.replace(template, id=i) for i in ids)
    report = dataclasses.replace(snapshot.report, initial_cost=2 * cost, final_cost=cost)
    return dataclasses.replace(snapshot, planes=planes, report=report)


def test_plane_events_only_where_the_planes_changed(series, monkeypatch) -> None:
    """Planes 0, 1 at keyframe 0; 2 created at 3; 1 merged away at 5; the same ids elsewhere.
    Costs from 10 to 1e7 (VIO's range): a log axis, no '1e7' offset text."""
    plan = [[0, 1], [0, 1], [0, 1], [0, 1, 2], [0, 1, 2], [0, 2], [0, 2], [0, 2]]
    costs = np.geomspace(10, 1e7, len(plan))
    template = next(p for s in series for p in s.planes)
    made = [_with_planes(s, ids, template=template, cost=float(c)) for s, ids, c in zip(series, plan, costs)]
    check_plots(drawn_figure(monkeypatch, made, current=4), made)
    created, removed = plots.plane_events(made)
    np.testing.assert_array_equal(np.flatnonzero(created), [0, 3])
    np.testing.assert_array_equal(np.flatnonzero(removed), [5])


def test_cost_ticks_are_plain_numbers() -> None:
    assert [plots.compact_number(t) for t in plots.cost_ticks(300, 6000)] == ["500", "1,000", "2,000", "5,000"]
    assert [plots.compact_number(t) for t in plots.cost_ticks(10, 1.2e7)] == ["10", "1,000", "1e5", "1e7"]
    assert len(plots.cost_ticks(3000, 5000)) >= 2


def test_the_tabs_image_is_the_saved_png_drawn_once(series) -> None:
    """The Plots tab's image (drawn straight into Agg's buffer) has the pixels of the PNG
    `plots_png` saves, with and without a shown keyframe."""
    import io

    from PIL import Image

    for current in (None, series[3].keyframe):
        image = plots.plots_image(series, current=current)
        saved = np.asarray(Image.open(io.BytesIO(plots.plots_png(series, current=current))).convert("RGB"))
        assert image.dtype == np.uint8 and image.shape == saved.shape == (plots.HEIGHT_PX, plots.WIDTH_PX, 3)
        np.testing.assert_array_equal(image, saved)


def test_the_kept_figure_draws_what_a_new_one_would(series) -> None:
    """The Plots tab keeps its figure and replaces the data as keyframes come and the shown
    one moves: every image is a new figure's (up to the layout's rounding: a pixel or so by
    one grey level), and the figure is built again only when its panels change."""
    canvas = plots.PlotCanvas()
    for n in range(2, len(series) + 1):
        for shown in (series[n - 1].keyframe, series[0].keyframe):
            image = canvas.image(series[:n], current=shown)
            new = plots.plots_image(series[:n], current=shown)
            differs = np.any(image != new, axis=2)
            assert np.count_nonzero(differs) <= 10, (n, shown, np.count_nonzero(differs))
            assert np.abs(image.astype(int) - new).max(initial=0) <= 3
    assert canvas.built < len(series) - 1  # reused at least once
    without_shown = canvas.image(series, current=None)  # no vertical line: a new figure
    np.testing.assert_array_equal(without_shown, plots.plots_image(series, current=None))
