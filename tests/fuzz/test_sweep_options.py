"""Fuzz: the matrix options of `sweep` (and a TOML file's values), listed with `--dry-run` so
that nothing runs: any value is a matrix or one `error:` line naming the option, exit 2,
never a traceback, and no file written."""

from __future__ import annotations

import os

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz._support import check_outcome, fuzz_settings, remove, run_cli, walk
from tests.fuzz.test_options import values

BASE = ["sweep", "--scenes", "room", "--duration", "0.3", "--variants", "P-wo", "--serial", "--dry-run", "--out", "out"]
AXES = ("--scenes", "--datasets", "--variants", "--modes", "--segmenters", "--seeds", "--speeds", "--strides", "--duration", "--frames", "--out")
lists = st.lists(values, min_size=1, max_size=3).map(",".join)


@fuzz_settings(ci_examples=100)
@given(data=st.data())
def test_any_axis_value_is_a_matrix_or_one_line(tmp_path_factory: pytest.TempPathFactory, capfd: pytest.CaptureFixture[str], data: st.DataObject) -> None:
    chosen = data.draw(st.dictionaries(st.sampled_from(AXES), values | lists, min_size=1, max_size=3), label="options")
    argv = list(BASE)
    for option, value in chosen.items():
        if option in argv:
            argv[argv.index(option) + 1] = value
        else:
            argv += [option, value]
    work = tmp_path_factory.mktemp("sweep-options")
    cwd = os.getcwd()
    os.chdir(work)
    try:
        rc, stderr = run_cli(argv, capfd)
        os.chdir(cwd)
        check_outcome(rc, stderr, folders=[work])
        assert not [p for p in walk(work) if p.is_file()], sorted(walk(work))  # a dry run writes nothing
    finally:
        os.chdir(cwd)
        remove(work)


toml_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(10**20), max_value=10**20) | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=3),
    max_leaves=6,
)


@fuzz_settings(ci_examples=60)
@given(data=st.data())
def test_any_toml_value_is_a_matrix_or_one_line(tmp_path_factory: pytest.TempPathFactory, capfd: pytest.CaptureFixture[str], data: st.DataObject) -> None:
    import json

    keys = data.draw(st.dictionaries(st.sampled_from([a.lstrip("-") for a in AXES if a != "--out"] + ["colour"]), toml_values, min_size=1, max_size=3), label="toml")
    work = tmp_path_factory.mktemp("sweep-toml")
    config = work / "sweep.toml"
    # JSON's scalars and arrays are TOML's too (null is not: it stands for a bad line)
    config.write_text("".join(f"{k} = {json.dumps(v, ensure_ascii=False)}\n" for k, v in keys.items()), encoding="utf-8")
    try:
        rc, stderr = run_cli(["sweep", "--config", str(config), "--duration", "0.3", "--dry-run", "--out", str(work / "out")], capfd)
        check_outcome(rc, stderr, folders=[work])
        assert not (work / "out").exists()
    finally:
        remove(work)
