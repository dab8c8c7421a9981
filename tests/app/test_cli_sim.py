"""`coplanar sim` (DESIGN §7): outputs, bad input (DESIGN §8), and the Hessian structure it draws."""

from __future__ import annotations

import contextlib
import io
import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from app import cli
from backend.eval import montecarlo, sequences
from backend.optim.problem import build_problem
from backend.optim.structure import hessian_structure
from backend.optim.variant import VARIANTS
from tests.paper import PAPER_COUNTS_B as PAPER_COUNTS

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
CONSOLE_SCRIPT = pathlib.Path(sys.executable).parent / "coplanar"


@pytest.fixture(scope="module")
def sim_b(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One in-process `coplanar sim --sequence b --runs 1` with Hessian images."""
    out = tmp_path_factory.mktemp("sim")
    json_path, hess_dir = out / "study.json", out / "hessians"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        rc = cli.main(["sim", "--sequence", "b", "--runs", "1", "--json", str(json_path), "--hessian-dir", str(hess_dir)])
    return {"rc": rc, "json": json_path, "hessians": hess_dir, "stdout": stdout.getvalue(), "stderr": stderr.getvalue()}


def test_sim_exits_zero(sim_b: dict) -> None:
    assert sim_b["rc"] == 0, sim_b["stderr"]
    assert "Traceback" not in sim_b["stderr"]


def test_sim_writes_the_json_contract(sim_b: dict) -> None:
    payload = json.loads(sim_b["json"].read_text())
    assert payload["sequence"] == "b"
    assert payload["runs"] == 1
    assert list(payload["variants"]) == list(VARIANTS)
    for name, entry in payload["variants"].items():
        assert (entry["items"], entry["params"]) == PAPER_COUNTS[name]
        assert isinstance(entry["items"], int) and isinstance(entry["params"], int)
        for key in ("rmse_cm_median", "time_ms_median", "iterations_median"):
            assert isinstance(entry[key], (int, float)) and np.isfinite(entry[key]), (name, key)
        assert entry["rmse_cm_median"] > 0
        assert entry["time_ms_median"] > 0
        assert 1 <= entry["iterations_median"] <= montecarlo.MAX_ITERATIONS
        assert entry["cost_increase_runs"] == 0  # the solver never accepts a cost increase
        assert 0 <= entry["converged_runs"] <= payload["runs"]
        assert entry["linearizations_median"] >= entry["iterations_median"] + 1


def test_sim_json_matches_the_library_study(sim_b: dict) -> None:
    """The CLI reports what run_study computes for the same seed (RMSE is deterministic)."""
    payload = json.loads(sim_b["json"].read_text())
    summary, _ = montecarlo.run_study("b", runs=1, seed=0, variants=["P-w"])
    assert payload["variants"]["P-w"]["rmse_cm_median"] == pytest.approx(summary["P-w"].rmse_cm_median, rel=1e-12)


def test_sim_writes_the_plot_png(sim_b: dict) -> None:
    plot = sim_b["json"].with_suffix(".png")
    assert plot.read_bytes()[:8] == PNG_SIGNATURE
    assert plot.stat().st_size > 1000


def test_sim_writes_one_hessian_png_per_variant(sim_b: dict) -> None:
    files = sorted(p.name for p in sim_b["hessians"].iterdir())
    assert files == sorted(f"hessian_b_{v}.png" for v in VARIANTS)
    for name in files:
        assert (sim_b["hessians"] / name).read_bytes()[:8] == PNG_SIGNATURE


def test_sim_prints_a_table_with_every_variant(sim_b: dict) -> None:
    lines = sim_b["stdout"].splitlines()
    for v in VARIANTS:
        row = [line for line in lines if line.split()[:1] == [v]]
        assert len(row) == 1, v
        items, params = PAPER_COUNTS[v]
        assert row[0].split()[1:3] == [str(items), str(params)]


# ------------------------------------------------------------------ bad input


def _bad_input_cases(tmp: pathlib.Path) -> dict[str, tuple[list[str], list[str], pathlib.Path]]:
    """name -> (extra arguments, words the error must mention, the JSON path that must not appear)."""
    ok_json = tmp / "out.json"
    missing_dir_json = tmp / "no_such_dir" / "out.json"
    return {
        "sequence": (["--sequence", "c", "--json", str(ok_json)], ["--sequence", "c"], ok_json),
        "runs0": (["--sequence", "b", "--runs", "0", "--json", str(ok_json)], ["--runs", "0"], ok_json),
        "runs-3": (["--sequence", "b", "--runs", "-3", "--json", str(ok_json)], ["--runs", "-3"], ok_json),
        "variants": (["--sequence", "b", "--runs", "1", "--variants", "P-x", "--json", str(ok_json)], ["--variants", "P-x"], ok_json),
        "json-missing-dir": (["--sequence", "b", "--runs", "1", "--json", str(missing_dir_json)], ["--json", "no_such_dir"], missing_dir_json),
        "sigma-rel0": (["--sequence", "b", "--runs", "1", "--sigma-rel", "0", "--json", str(ok_json)], ["--sigma-rel", "0"], ok_json),
        "sigma-rel-nan": (["--sequence", "b", "--runs", "1", "--sigma-rel", "nan", "--json", str(ok_json)], ["--sigma-rel", "nan"], ok_json),
    }


def _assert_one_error_line(err: str, words: list[str]) -> None:
    assert "Traceback" not in err
    lines = err.strip("\n").splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error:")
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("case", ["sequence", "runs0", "runs-3", "variants", "json-missing-dir", "sigma-rel0", "sigma-rel-nan"])
def test_bad_input_is_one_error_line_and_exit_2(case: str, tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    args, words, json_path = _bad_input_cases(tmp_path)[case]
    rc = cli.main(["sim", *args])
    out, err = capsys.readouterr()
    assert rc == 2
    _assert_one_error_line(err, words)
    assert not json_path.exists()
    assert not json_path.parent.exists() or json_path.parent == tmp_path
    assert list(tmp_path.iterdir()) == []  # nothing written at all
    assert "P-wo" not in out  # no study ran


def test_json_path_that_is_a_directory(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "results"
    target.mkdir()
    rc = cli.main(["sim", "--sequence", "b", "--runs", "1", "--json", str(target)])
    _, err = capsys.readouterr()
    assert rc == 2
    _assert_one_error_line(err, ["--json", str(target)])
    assert target.is_dir() and list(target.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_json_path_dot(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    try:
        rc = cli.main(["sim", "--sequence", "b", "--runs", "1", "--json", "."])
    except Exception as e:  # a crash is the bug this test documents
        pytest.fail(f"raised {e!r}")
    _, err = capsys.readouterr()
    assert rc == 2
    _assert_one_error_line(err, ["--json"])


def test_unwritable_plot_leaves_no_json(tmp_path: pathlib.Path, capsys: pytest.CaptureFixture[str]) -> None:
    json_path = tmp_path / "out.json"
    rc = cli.main(["sim", "--sequence", "b", "--runs", "1", "--json", str(json_path), "--plot", str(tmp_path / "nodir" / "p.png")])
    _, err = capsys.readouterr()
    assert rc == 2
    _assert_one_error_line(err, ["--plot"])
    assert not json_path.exists()


def test_console_script_reports_bad_input(tmp_path: pathlib.Path) -> None:
    assert CONSOLE_SCRIPT.exists(), CONSOLE_SCRIPT
    json_path = tmp_path / "out.json"
    proc = subprocess.run(
        [str(CONSOLE_SCRIPT), "sim", "--sequence", "b", "--runs", "1", "--variants", "P-wo,P-x", "--json", str(json_path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    _assert_one_error_line(proc.stderr, ["--variants", "P-x"])
    assert not json_path.exists()


# ------------------------------------------------------------------ Hessian structure


def test_w_hessian_is_smaller_and_sparser() -> None:
    world = sequences.make_world("b", seed=0)
    data = montecarlo.make_problem_data(world, np.random.default_rng([0, 0]))
    s = {v: hessian_structure(build_problem(data, v)) for v in VARIANTS}
    for v in VARIANTS:
        assert (s[v].items, s[v].params) == PAPER_COUNTS[v]
        assert s[v].pattern.shape == (s[v].params, s[v].params)
        assert (s[v].pattern != s[v].pattern.T).nnz == 0  # H is symmetric
        assert np.all(s[v].pattern.diagonal())  # every variable is constrained
    for kind in ("P", "PL"):
        w, wo, r = s[f"{kind}-w"], s[f"{kind}-wo"], s[f"{kind}-r"]
        assert w.params < wo.params and w.params < r.params
        assert w.nnz < wo.nnz and w.nnz < r.nnz
    # Lines add variables and nonzeros to -wo/-r; -w has the same variables with or without lines.
    assert s["PL-wo"].nnz > s["P-wo"].nnz and s["PL-r"].nnz > s["P-r"].nnz
    assert s["PL-w"].params == s["P-w"].params
    # Group layout: cameras | points | lines | planes.
    groups = {g.kind: g for g in s["PL-r"].groups}
    assert groups["cameras"].size == 300 and groups["points"].size == 50
    assert groups["lines"].size == 80 and groups["planes"].size == 3
