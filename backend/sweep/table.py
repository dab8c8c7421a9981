"""A sweep's `table.md`: the paper's Table II shape from the results rows (backend.sweep.results).

One table per mode and segmenter: a row per sequence (input, with its speed, stride and frame
limit where not the default), a column per variant, the ATE after SE(3) alignment (cm; the
mean over the seeds that finished, `x/n` when only x of n did, `failed` when none did) and a
mean row (the mean of each column over the sequences). VIO gets the ATE from its first
initialization on first, then over all tracked frames. Under it the same shape for the lost
frames (mean over seeds), then the failed runs with their reasons.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from backend.optim.variant import VARIANTS
from backend.sweep.results import OK

Row = Mapping[str, Any]


def table_markdown(rows: Sequence[Row]) -> str:
    """table.md's text for `rows` (in the sweep's order)."""
    lines = ["# Sweep results", ""]
    groups = _groups(rows)
    for (mode, segmenter), group in groups.items():
        if len(groups) > 1:
            lines += [f"## {mode}, {segmenter} segmenter", ""]
        lines += _accuracy(group) + [""] + _lost(group) + [""]
    failed = [r for r in rows if r["status"] != OK]
    if failed:
        lines += ["## Failed runs", ""] + [f"- `{r['run_id']}`: {r['error']}" for r in failed] + [""]
    return "\n".join(lines)


def _groups(rows: Sequence[Row]) -> dict[tuple[str, str], list[Row]]:
    groups: dict[tuple[str, str], list[Row]] = {}
    for row in rows:
        groups.setdefault((row["mode"], row["segmenter"]), []).append(row)
    return groups


def _layout(rows: Sequence[Row]) -> tuple[list[str], list[str], dict[tuple[str, str], list[Row]]]:
    """The sequences (first seen first), the variants (the paper's order) and each cell's runs."""
    cells: dict[tuple[str, str], list[Row]] = {}
    for row in rows:
        cells.setdefault((row["sequence"], row["variant"]), []).append(row)
    sequences = list(dict.fromkeys(s for s, _ in cells))
    present = {v for _, v in cells}
    return sequences, [v for v in VARIANTS if v in present], cells


def _cell(runs: list[Row], key: str, digits: int) -> tuple[str, float | None]:
    """A cell's text and value: the mean of `key` over the runs that finished with a value."""
    if not runs:
        return "–", None
    values = [float(r[key]) for r in runs if r["status"] == OK and r[key] is not None]
    if not values:
        return ("failed" if any(r["status"] != OK for r in runs) else "n/a"), None
    mean = statistics.fmean(values)
    text = f"{mean:.{digits}f}"
    return (text if len(values) == len(runs) else f"{text} ({len(values)}/{len(runs)})"), mean


def _grid(rows: Sequence[Row], key: str, digits: int, mean_label: str) -> list[str]:
    sequences, variants, cells = _layout(rows)
    lines = ["| sequence | " + " | ".join(variants) + " |", "|---|" + "---:|" * len(variants)]
    columns: dict[str, list[float]] = {v: [] for v in variants}
    for sequence in sequences:
        texts = []
        for v in variants:
            text, value = _cell(cells.get((sequence, v), []), key, digits)
            texts.append(text)
            if value is not None:
                columns[v].append(value)
        lines.append(f"| {sequence} | " + " | ".join(texts) + " |")
    means = [f"{statistics.fmean(columns[v]):.{digits}f}" + ("" if len(columns[v]) == len(sequences) else f" ({len(columns[v])}/{len(sequences)})") if columns[v] else "–" for v in variants]
    lines.append(f"| **{mean_label}** | " + " | ".join(means) + " |")
    return lines


def _accuracy(rows: Sequence[Row]) -> list[str]:
    """The ATE grid; VIO's from its first initialization on first (the frames before it have
    no metric scale), then over all tracked frames."""
    seeds = sorted({r["seed"] for r in rows})
    over = f", mean over {len(seeds)} seeds" if len(seeds) > 1 else ""
    lines = []
    if any(r["mode"] == "vio" for r in rows):
        lines += [f"ATE after SE(3) alignment, cm (tracked frames from the first VIO initialization on{over}):", ""] + _grid(rows, "vio_ate_after_init_cm", 2, "mean") + [""]
    return lines + [f"ATE after SE(3) alignment, cm (all tracked frames{over}):", ""] + _grid(rows, "ate_rmse_cm", 2, "mean")


def _lost(rows: Sequence[Row]) -> list[str]:
    return ["Lost frames (frames tracking lost, mean over seeds):", ""] + _grid(rows, "lost_frames", 1 if len({r["seed"] for r in rows}) > 1 else 0, "mean")
