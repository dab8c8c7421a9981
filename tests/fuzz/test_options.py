"""Fuzz: option values of `run`, `render` and `sim` (issue 16).

Each case starts from a small valid command and replaces one to three option values by
drawn ones: any text (NUL bytes, huge paths and unicode included), numbers out of range,
NaN and infinities, negative and huge integers. The command must exit 0 or 2 with one
`error:` line naming what is wrong, never a traceback, and leave complete files or none.
Values that are valid but would make the command long (a duration beyond 0.3 s, more than
one Monte-Carlo run) are skipped: their validity is not in question.
"""

from __future__ import annotations

import math
import os

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from tests.fuzz._support import check_outcome, fuzz_settings, remove, run_cli, walk

RUN_FILES = ("trajectory.txt", "keyframes.txt", "groundtruth.txt", "metrics.json", "map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")
numbers = (
    st.floats(allow_nan=True, allow_infinity=True).map(repr)
    | st.integers(min_value=-(10**30), max_value=10**30).map(str)
    | st.sampled_from(("nan", "inf", "-inf", "1e400", "-0", "0", "1", "0.5", "2", "1e-300", "0x10", "1_000", " 3", "٣"))
)
paths = st.text(min_size=1, max_size=40) | st.sampled_from(("", "/", "/proc/nope/x", "/dev/null", "a" * 300, "x/" * 2000, "nul\x00byte", "."))
values = numbers | st.text(max_size=20) | paths

COMMANDS = {
    "run": (
        ["run", "--scene", "room", "--duration", "0.3", "--variant", "P-wo"],
        "--out",
        ("--scene", "--duration", "--stride", "--speed", "--seed", "--window", "--mode", "--segmenter", "--segmenter-model", "--variant", "--out", "--frames", "--keyframes", "--trajectory-frame"),
    ),
    "run-mc": (["run", "--scene", "mc-b", "--variant", "P-wo", "--keyframes", "5"], "--out", ("--seed", "--mislabel", "--window", "--keyframes", "--variant", "--out", "--trajectory-frame")),
    "render": (["render", "--scene", "room", "--duration", "0.05"], "--out", ("--scene", "--duration", "--seed", "--image-noise", "--blur", "--exposure", "--out")),
    "sim": (
        ["sim", "--sequence", "b", "--runs", "1", "--variants", "P-wo"],
        "--json",
        ("--sequence", "--runs", "--seed", "--variants", "--solver", "--sigma-rel", "--json", "--plot", "--hessian-dir"),
    ),
}


def _long(option: str, value: str) -> bool:
    """A valid value that would make the case slow (not what is being tested)."""
    try:
        x = float(value)
    except ValueError:
        return False
    if not math.isfinite(x):
        return False
    return (option == "--duration" and x > 0.3) or (option == "--runs" and x > 1) or (option in ("--keyframes", "--frames") and x > 8) or (option == "--window" and x > 50)


@fuzz_settings(ci_examples=150)
@given(command=st.sampled_from(sorted(COMMANDS)), data=st.data())
def test_any_option_value_runs_or_is_refused_in_one_line(tmp_path_factory: pytest.TempPathFactory, capfd: pytest.CaptureFixture[str], command: str, data: st.DataObject) -> None:
    base, out_option, options = COMMANDS[command]
    chosen = data.draw(st.dictionaries(st.sampled_from(options), values, min_size=1, max_size=3), label="options")
    for option, value in chosen.items():
        assume(not _long(option, value))
    argv = list(base)
    overrides = {out_option: "out.json" if out_option == "--json" else "out", **chosen}
    for option, value in overrides.items():
        if option in argv:
            argv[argv.index(option) + 1] = value
        else:
            argv += [option, value]
    work = tmp_path_factory.mktemp("options")
    cwd = os.getcwd()
    os.chdir(work)  # relative paths among the drawn values land here
    try:
        rc, stderr = run_cli(argv, capfd)
        os.chdir(cwd)
        written = []
        if rc == 0 and command.startswith("run") and "\x00" not in overrides["--out"]:
            written = [work / overrides["--out"] / name for name in RUN_FILES]
        check_outcome(rc, stderr, written=written, folders=[work])
        if rc == 2:  # nothing written: no file anywhere under the case's folder
            assert not [p for p in walk(work) if p.is_file()], sorted(walk(work))
    finally:
        os.chdir(cwd)
        remove(work)  # folders thousands deep among them, which pytest's own clean-up cannot remove
