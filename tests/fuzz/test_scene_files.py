"""Fuzz: scene JSON files through `coplanar render --scene FILE` (issue 16).

The `room` scene's JSON with one to three values replaced by any JSON value (NaN and
infinities included), keys deleted or added, the text truncated or nested deeply. Rendering
must exit 0 (a complete `mav0` folder) or 2 (one `error:` line naming the file, no `mav0`).
"""

from __future__ import annotations

import contextlib
import copy
import json
import shutil

import pytest
from hypothesis import given
from hypothesis import strategies as st

from backend.data.scenes import builtin_scene, scene_to_dict
from tests.fuzz._support import check_outcome, fuzz_settings, run_cli

BASE = scene_to_dict(builtin_scene("room"))
numbers = st.floats(allow_nan=True, allow_infinity=True) | st.integers(min_value=-(10**20), max_value=10**20) | st.sampled_from((0, -1, 1e6, 1e-9, 5e4))
json_values = st.recursive(
    st.none() | st.booleans() | numbers | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=3),
    max_leaves=8,
)
edit = st.tuples(st.lists(st.integers(0, 1000), min_size=1, max_size=5), st.sampled_from(("replace", "delete", "add", "scale")), json_values, numbers)


def _apply(data: object, path: list[int], op: str, value: object, number: object) -> object:
    """Walk `path` (each step picks a key or index by modulo), then change what is there."""
    if not isinstance(data, (dict, list)) or not data:
        return value if op == "replace" else data
    parent, key = None, None
    node = data
    for step in path:
        if not isinstance(node, (dict, list)) or not node:
            break
        keys = list(node.keys()) if isinstance(node, dict) else list(range(len(node)))
        parent, key = node, keys[step % len(keys)]
        node = node[key]
    if parent is None:
        return data
    if op == "replace":
        parent[key] = value
    elif op == "delete":
        del parent[key]
    elif op == "add":
        if isinstance(parent, dict):
            parent[f"extra{path[0]}"] = value
        else:
            parent.append(value)
    elif op == "scale" and isinstance(node, (int, float)) and not isinstance(node, bool) and isinstance(number, (int, float)):
        with contextlib.suppress(OverflowError):
            parent[key] = node * number
    return data


@fuzz_settings(ci_examples=100)
@given(edits=st.lists(edit, min_size=1, max_size=3), text_cut=st.none() | st.integers(0, 20_000), nesting=st.sampled_from((0, 0, 0, 50, 5000)))
def test_a_corrupted_scene_file_renders_or_is_refused_in_one_line(
    tmp_path_factory: pytest.TempPathFactory, capfd: pytest.CaptureFixture[str], edits: list[tuple], text_cut: int | None, nesting: int
) -> None:
    data = copy.deepcopy(BASE)
    for path, op, value, number in edits:
        data = _apply(data, path, op, value, number)
    text = json.dumps(data)
    if nesting:
        text = text.replace('"spheres":', '"spheres": ' + "[" * nesting + "]" * nesting + ', "x":', 1)
    if text_cut is not None:
        text = text[: text_cut % (len(text) + 1)]
    work = tmp_path_factory.mktemp("scene")
    scene, out = work / "scene.json", work / "out"
    scene.write_text(text)
    rc, stderr = run_cli(["render", "--scene", str(scene), "--duration", "0.05", "--out", str(out)], capfd)
    check_outcome(rc, stderr, folders=[work])
    if rc == 2:
        assert str(scene) in stderr, stderr
        assert not (out / "mav0").exists()
    else:
        assert (out / "mav0" / "cam0" / "data.csv").is_file() and (out / "mav0" / "imu0" / "data.csv").is_file()
    shutil.rmtree(work, ignore_errors=True)
