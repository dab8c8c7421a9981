"""A sweep's results (backend/sweep/results.py, table.py, plots.py) from rows: the CSV and JSON
files, the Table II shape with its mean row, lost frames and failures, and the plots."""

from __future__ import annotations

import csv
import json
import pathlib

from backend.optim.variant import Variant
from backend.sweep.matrix import RunSpec
from backend.sweep.plots import write_plots
from backend.sweep.results import COLUMNS, failed_row, ok_row, results_csv, results_json, without_times
from backend.sweep.table import table_markdown


def _spec(scene: str, variant: str, seed: int = 0) -> RunSpec:
    return RunSpec(scene, None, Variant.parse(variant), "stereo", "geometric", seed, duration_s=30.0)


def _metrics(ate: float, lost: int) -> dict:
    timing = {"point_dm": 10.0, "tracking": 5.0, "line_dm": None, "plane_seg": 30.0, "plane_fit": 8.0, "optimization": 40.0, "total_per_frame": 25.0}
    return {"ate_rmse_cm": ate, "lost_frames": lost, "keyframes": 20, "frames": 600, "reinitializations": 0, "timing_ms": timing}


def _rows() -> list[dict]:
    return [
        ok_row(_spec("room", "P-wo"), _metrics(2.0, 0), wall_s=10.0),
        ok_row(_spec("room", "PL-w"), _metrics(1.0, 2), wall_s=12.0),
        ok_row(_spec("room", "PL-w", seed=1), _metrics(3.0, 4), wall_s=12.0),
        ok_row(_spec("corridor", "P-wo"), _metrics(4.0, 1), wall_s=10.0),
        failed_row(_spec("corridor", "PL-w"), "DatasetError: bad\nsecond line"),
    ]


def test_table_has_the_paper_shape_with_a_mean_row_lost_frames_and_failures() -> None:
    text = table_markdown(_rows())
    lines = text.splitlines()
    header = lines.index("| sequence | P-wo | PL-w |")
    assert lines[header + 2] == "| room | 2.00 | 2.00 |"  # PL-w: the mean over seeds 0 and 1
    assert lines[header + 3] == "| corridor | 4.00 | failed |"
    assert lines[header + 4] == "| **mean** | 3.00 | 2.00 (1/2) |"
    lost = lines.index("| sequence | P-wo | PL-w |", header + 1)
    assert lines[lost + 2] == "| room | 0.0 | 3.0 |"
    assert "- `corridor_PL-w_stereo_geometric_seed0_30s`: DatasetError: bad second line" in lines


def test_csv_and_json_hold_every_column_and_one_row_per_run() -> None:
    rows = _rows()
    parsed = json.loads(results_json(rows))
    assert [list(r) for r in parsed] == [list(COLUMNS)] * len(rows)
    assert parsed[1]["ate_rmse_cm"] == 1.0 and parsed[1]["time_optimization_ms"] == 40.0 and parsed[1]["status"] == "ok"
    assert parsed[4]["status"] == "failed" and parsed[4]["error"] == "DatasetError: bad second line" and parsed[4]["ate_rmse_cm"] is None
    table = list(csv.DictReader(results_csv(rows).splitlines()))
    assert len(table) == len(rows) and table[0]["run_id"] == "room_P-wo_stereo_geometric_seed0_30s" and table[4]["ate_rmse_cm"] == ""
    assert "wall_s" not in without_times(rows[0]) and "time_point_dm_ms" not in without_times(rows[0]) and "ate_rmse_cm" in without_times(rows[0])


def test_plots_are_written(tmp_path: pathlib.Path) -> None:
    paths = write_plots(tmp_path, _rows())
    assert [p.name for p in paths] == ["ate_by_variant.png", "time_by_stage.png"]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in paths)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ate_by_variant.png", "time_by_stage.png"]  # no temporary file left
    write_plots(tmp_path / ".." / tmp_path.name, [failed_row(_spec("room", "P-wo"), "x")])  # nothing finished: empty plots, no error


def test_vio_leads_with_the_ate_from_its_initialization() -> None:
    spec = RunSpec("room", None, Variant.PL_W, "vio", "learned", 0, duration_s=30.0)
    text = table_markdown([ok_row(spec, {**_metrics(9.0, 10), "vio": {"initialized": True, "ate_after_init_cm": 1.5}}, wall_s=30.0)])
    assert text.index("| room | 1.50 |") < text.index("| room | 9.00 |") and "from the first VIO initialization on" in text
