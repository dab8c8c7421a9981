"""A sweep's results: one row per run (its parameters, the figures of its metrics.json, its
wall time and status), and the rows as `results.csv` and `results.json`.

Figures (from `backend.headless` / `backend.eval.run_metrics`): `ate_rmse_cm` (ATE after SE(3)
alignment over the tracked frames, cm), `ate_sim3_rmse_cm`, `rpe_cm_per_m` (relative pose
error per metre travelled, cm), `rmse_cm` (unaligned), frame and keyframe counts, lost frames
and re-initializations, and the VIO start (`vio_initialized`, `vio_init_time_s` seconds after
the first frame, `vio_ate_after_init_cm`, `vio_scale_error_pct`, and `vio_excitation_onset_s`,
`vio_init_after_excitation_s`: when the true motion first accelerated enough and the start's
time after that, `backend.eval.excitation`). Times: `time_*_ms` the DESIGN §7 stage means
(milliseconds; point D&M and tracking per frame, the others per keyframe where they ran,
total per frame) and `wall_s` (seconds, the whole run). `status`: `ok` or `failed` with
`error`, one line.
"""

from __future__ import annotations

import csv
import io
import json
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

from backend.sweep.matrix import RunSpec

OK = "ok"
FAILED = "failed"
PARAMETERS = (
    "run_id",
    "input",
    "sequence",
    "input_kind",
    "input_path",
    "variant",
    "mode",
    "segmenter",
    "seed",
    "duration_s",
    "speed",
    "stride",
    "window",
    "frames_limit",
    "keyframes_limit",
    "dense",
    "trajectory_frame",
    "calib",
    "topics",
    "segmenter_model",
)
FIGURES = (
    "ate_rmse_cm",
    "ate_sim3_rmse_cm",
    "rpe_cm_per_m",
    "rmse_cm",
    "keyframe_ate_rmse_cm",
    "frames",
    "frames_tracked",
    "frames_evaluated",
    "lost_frames",
    "reinitializations",
    "keyframes",
    "planes",
    "points",
    "lines",
)
PLANE_FIGURES = {"planes_seen": "seen", "planes_recovered": "recovered"}  # rendered scenes (metrics.json's plane_recovery)
VIO_FIGURES = {
    "vio_initialized": "initialized",
    "vio_init_time_s": "init_time_s",
    "vio_ate_after_init_cm": "ate_after_init_cm",
    "vio_scale_error_pct": "scale_error_pct",
    "vio_excitation_onset_s": "excitation_onset_s",
    "vio_init_after_excitation_s": "init_after_excitation_s",
}
STAGES = ("point_dm", "tracking", "line_dm", "plane_seg", "plane_fit", "optimization", "total_per_frame")
TIMES = (*(f"time_{stage}_ms" for stage in STAGES), "wall_s")
COLUMNS = (*PARAMETERS, "status", "error", *FIGURES, *PLANE_FIGURES, *VIO_FIGURES, *TIMES)


def ok_row(spec: RunSpec, metrics: Mapping[str, Any], *, wall_s: float) -> dict[str, Any]:
    """The row of a finished run: `metrics` as its metrics.json holds them (JSON values)."""
    row = _blank(spec, OK)
    row.update({key: metrics.get(key) for key in FIGURES})
    planes = metrics.get("plane_recovery") or {}
    row.update({key: planes.get(name) for key, name in PLANE_FIGURES.items()})
    vio = metrics.get("vio") or {}
    row.update({key: vio.get(name) for key, name in VIO_FIGURES.items()})
    timing = metrics.get("timing_ms") or {}
    row.update({f"time_{stage}_ms": timing.get(stage) for stage in STAGES})
    row["wall_s"] = wall_s
    return row


def failed_row(spec: RunSpec, reason: str, *, wall_s: float | None = None) -> dict[str, Any]:
    """The row of a run that failed: `reason` one line, no figures."""
    row = _blank(spec, FAILED)
    row["error"] = " ".join(reason.split()) or "failed"
    row["wall_s"] = wall_s
    return row


def _blank(spec: RunSpec, status: str) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(spec.parameters())
    row["status"] = status
    return row


def without_times(row: Mapping[str, Any]) -> dict[str, Any]:
    """`row` without the time columns: what two sweeps of the same matrix agree on."""
    return {k: v for k, v in row.items() if k not in TIMES}


def results_json(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows as results.json: a JSON list, one object per run with every column (null:
    no value)."""
    return json.dumps([{k: row.get(k) for k in COLUMNS} for row in rows], indent=2, allow_nan=False) + "\n"


def results_csv(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows as results.csv: a header of COLUMNS, one line per run (empty: no value)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    return buffer.getvalue()


def write_results(out: pathlib.Path, rows: Sequence[Mapping[str, Any]]) -> list[pathlib.Path]:
    """results.csv and results.json in `out`, each complete or not at all; their paths."""
    from backend.common.atomic import write_text_atomic

    written = []
    for name, text in (("results.csv", results_csv(rows)), ("results.json", results_json(rows))):
        write_text_atomic(out / name, text)
        written.append(out / name)
    return written
