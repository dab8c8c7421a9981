"""Fuzz: corrupted EuRoC folders through `coplanar run --dataset` (issue 16).

A small rendered sequence (7 stereo pairs with IMU, ground truth, depth and plane ids) is
copied and broken in one to three ways drawn by hypothesis: CSV rows truncated, non-numeric,
NaN/inf, unsorted, duplicated, deleted or with the wrong number of columns; YAML keys
missing, extra, repeated or with bad values, files truncated or not YAML; images of zero
bytes, text, truncated, of the wrong size or depth, in colour, JPEG under a .png name, or
absent; folders and files removed; and as a careless user breaks a folder without breaking
its syntax (issue 29): an image that is a FIFO or a folder, an image named by an absolute
path or one climbing out with `..`, cam0 and cam1 swapped, cam1 one frame late, `T_BS` in
millimetres, a tiny focal length, a principal point off the image, a huge k1, ground truth
an hour off or in millimetres, the IMU in g or in deg/s. The run (stereo or VIO) must exit
0 or 2 with one `error:` line, never a traceback or a hang, and leave complete files or none.
"""

from __future__ import annotations

import os
import pathlib
import shutil

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz._support import check_outcome, fuzz_settings, run_cli

CSV_FILES = ("mav0/cam0/data.csv", "mav0/cam1/data.csv", "mav0/imu0/data.csv", "mav0/state_groundtruth_estimate0/data.csv", "mav0/planes.csv")
YAML_FILES = ("mav0/cam0/sensor.yaml", "mav0/cam1/sensor.yaml", "mav0/imu0/sensor.yaml")
IMAGE_DIRS = ("mav0/cam0/data", "mav0/cam1/data", "mav0/depth0/data", "mav0/planes0/data")
REMOVABLE = (
    "mav0/imu0",
    "mav0/cam1",
    "mav0/state_groundtruth_estimate0",
    "mav0/cam0/data.csv",
    "mav0/cam1/sensor.yaml",
    "mav0/imu0/sensor.yaml",
    "mav0/planes.csv",
    "mav0/depth0",
    "mav0/cam0/data",
    "mav0",
)
RUN_FILES = ("trajectory.txt", "keyframes.txt", "groundtruth.txt", "metrics.json", "map.ply", "points.ply", "lines.ply", "planes.ply", "cameras.ply")
BAD_TOKENS = ("", " ", "nan", "NaN", "inf", "-inf", "1e400", "-1", "0", "-0", "abc", "1,2", "0x1F", "１２", "\t", "9" * 30, "1.5.3", "[1, 2]", "null", "-9e18")

token = st.sampled_from(BAD_TOKENS) | st.text(max_size=12)
csv_mutation = st.tuples(
    st.just("csv"),
    st.sampled_from(CSV_FILES),
    st.sampled_from(("field", "truncate", "delete", "duplicate", "swap", "garbage", "empty", "header", "extra_column", "fewer_columns")),
    st.integers(0, 10_000),
    st.integers(0, 20),
    token,
)
yaml_mutation = st.tuples(
    st.just("yaml"),
    st.sampled_from(YAML_FILES),
    st.sampled_from(("delete_line", "extra_key", "value", "array_value", "truncate", "garbage", "empty", "repeat_key")),
    st.integers(0, 10_000),
    st.integers(0, 20),
    token,
)
image_mutation = st.tuples(
    st.just("image"),
    st.sampled_from(IMAGE_DIRS),
    st.sampled_from(("zero", "text", "truncate", "resize", "colour", "depth16", "jpeg", "delete", "tiny", "fifo", "folder")),
    st.integers(0, 10_000),
    st.integers(0, 20),
    st.just(""),
)
remove_mutation = st.tuples(st.just("remove"), st.sampled_from(REMOVABLE), st.just(""), st.just(0), st.just(0), st.just(""))
#: Whole-folder mistakes that keep every file well formed (issue 29's careless user).
CARELESS = ("outside_absolute", "outside_climbing", "swap_cameras", "cam1_late", "tbs_mm", "focal_tiny", "pp_outside", "k1_huge", "truth_hour", "truth_mm", "imu_g", "imu_deg")
careless_mutation = st.tuples(st.just("careless"), st.sampled_from(CARELESS), st.just(""), st.integers(0, 10_000), st.just(0), st.just(""))
mutations = st.lists(csv_mutation | yaml_mutation | image_mutation | remove_mutation | careless_mutation, min_size=1, max_size=3)


def _mutate_csv(path: pathlib.Path, op: str, i: int, j: int, text: str) -> None:
    lines = path.read_text().splitlines()
    n = max(len(lines), 1)
    k = i % n
    if op == "empty":
        lines = []
    elif op == "header" and lines:
        lines = lines[1:]
    elif op == "garbage":
        lines.insert(k, text)
    elif not lines:
        return
    elif op == "field":
        fields = lines[k].split(",")
        fields[j % len(fields)] = text
        lines[k] = ",".join(fields)
    elif op == "truncate":
        lines[k] = lines[k][: j % (len(lines[k]) + 1)]
        lines = lines[: k + 1] if i % 2 else lines  # a cut-off file, or one short row
    elif op == "delete":
        del lines[k]
    elif op == "duplicate":
        lines.insert(k, lines[k])
    elif op == "swap" and k + 1 < len(lines):
        lines[k], lines[k + 1] = lines[k + 1], lines[k]
    elif op == "extra_column":
        lines[k] += "," + (text or "1")
    elif op == "fewer_columns":
        lines[k] = ",".join(lines[k].split(",")[: -1 - j % 3])
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


def _mutate_yaml(path: pathlib.Path, op: str, i: int, j: int, text: str) -> None:
    content = path.read_text()
    lines = content.splitlines()
    keyed = [n for n, line in enumerate(lines) if ":" in line and not line.lstrip().startswith(("#", "%"))]
    if op == "empty":
        path.write_text("")
        return
    if op == "garbage":
        path.write_text(text + "\n: [\n" + content[: i % (len(content) + 1)])
        return
    if op == "truncate":
        path.write_text(content[: i % (len(content) + 1)])
        return
    if not keyed:
        return
    k = keyed[i % len(keyed)]
    key = lines[k].split(":", 1)[0]
    if op == "delete_line":
        del lines[k]
    elif op == "extra_key":
        lines.insert(k, f"unexpected_{j}: {text}")
    elif op == "repeat_key":
        lines.insert(k + 1, f"{key}: {text}")
    elif op == "value":
        lines[k] = f"{key}: {text}"
    elif op == "array_value":  # a number inside a bracketed list (intrinsics, resolution, T_BS data)
        arrays = [n for n, line in enumerate(lines) if "[" in line or line.strip().endswith(",") or line.strip().endswith("]")]
        if arrays:
            a = arrays[i % len(arrays)]
            head, sep, rest = lines[a].partition("[")
            body = rest if sep else lines[a]
            items = body.split(",")
            items[j % len(items)] = (" " + text) if not items[j % len(items)].strip().endswith("]") else f" {text}]"
            lines[a] = head + sep + ",".join(items)
    path.write_text("\n".join(lines) + "\n")


def _mutate_image(folder: pathlib.Path, op: str, i: int, j: int) -> None:
    images = sorted(p for p in folder.glob("*.png") if p.is_file())  # not one an earlier mutation made a FIFO or a folder
    if not images:
        return
    path = images[i % len(images)]
    data = path.read_bytes()
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None and op in ("resize", "tiny", "colour", "depth16", "jpeg"):
        return  # already broken by an earlier mutation
    if op == "zero":
        path.write_bytes(b"")
    elif op == "text":
        path.write_text("this is not an image\n")
    elif op == "truncate":
        path.write_bytes(data[: max(8, len(data) * (j + 1) // 22)])
    elif op == "delete":
        path.unlink()
    elif op == "resize":
        cv2.imwrite(str(path), cv2.resize(image, (image.shape[1] // 2 + j, image.shape[0])))
    elif op == "tiny":
        cv2.imwrite(str(path), image[:1, :1])
    elif op == "colour":
        grey = image if image.ndim == 2 else image[..., 0]
        cv2.imwrite(str(path), np.dstack([grey.astype(np.uint8)] * 3))
    elif op == "depth16":
        cv2.imwrite(str(path), image.astype(np.uint16) * 257)
    elif op == "jpeg":
        ok, encoded = cv2.imencode(".jpg", image.astype(np.uint8))
        path.write_bytes(encoded.tobytes())
    elif op == "fifo":
        path.unlink()
        os.mkfifo(path)
    elif op == "folder":
        path.unlink()
        path.mkdir()


def _rows(path: pathlib.Path) -> tuple[list[str], list[int]]:
    """A CSV's lines and the indices of its data rows."""
    lines = path.read_text().splitlines()
    return lines, [k for k, line in enumerate(lines) if line and not line.startswith("#")]


def _scale_columns(path: pathlib.Path, columns: tuple[int, ...], factor: float) -> None:
    lines, rows = _rows(path)
    for k in rows:
        fields = lines[k].split(",")
        for c in columns:
            fields[c] = repr(float(fields[c]) * factor)
        lines[k] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


def _edit_yaml_list(path: pathlib.Path, key: str, edit) -> None:
    """Replace the numbers of `key: [...]` (one line) by `edit(numbers)`."""
    lines = path.read_text().splitlines()
    k = next(k for k, line in enumerate(lines) if line.startswith(f"{key}:"))
    numbers = [float(x) for x in lines[k].split("[")[1].split("]")[0].split(",")]
    lines[k] = f"{key}: [{', '.join(repr(x) for x in edit(numbers))}]"
    path.write_text("\n".join(lines) + "\n")


def _careless(root: pathlib.Path, op: str, i: int) -> None:
    """A folder broken without breaking a file's syntax (module docstring)."""
    mav0 = root / "mav0"
    cam0, cam1 = mav0 / "cam0" / "data.csv", mav0 / "cam1" / "data.csv"
    if not (cam0.is_file() and cam1.is_file()):
        return
    lines, rows = _rows(cam0)
    if op in ("outside_absolute", "outside_climbing") and rows:
        k = rows[i % len(rows)]
        stamp, name = lines[k].split(",")[:2]
        lines[k] = f"{stamp},{(mav0 / 'cam0' / 'data' / name).resolve() if op == 'outside_absolute' else '../data/' + name}"
        cam0.write_text("\n".join(lines) + "\n")
    elif op == "swap_cameras":
        (mav0 / "cam0" / "data").rename(mav0 / "data.tmp")
        (mav0 / "cam1" / "data").rename(mav0 / "cam0" / "data")
        (mav0 / "data.tmp").rename(mav0 / "cam1" / "data")
    elif op == "cam1_late":
        lines, rows = _rows(cam1)
        names = [lines[k].split(",")[1] for k in rows]
        for n, k in enumerate(rows):
            lines[k] = f"{lines[k].split(',')[0]},{names[min(n + 1, len(names) - 1)]}"
        cam1.write_text("\n".join(lines) + "\n")
    elif op == "tbs_mm":
        text = (mav0 / "cam1" / "sensor.yaml").read_text()
        head, rest = text.split("data:", 1)
        values = [float(x) for x in rest.split("[")[1].split("]")[0].split(",")]
        for c in (3, 7, 11):
            values[c] *= 1000.0
        (mav0 / "cam1" / "sensor.yaml").write_text(head + "data: [" + ", ".join(repr(v) for v in values) + "]" + rest.split("]", 1)[1])
    elif op in ("focal_tiny", "pp_outside", "k1_huge"):
        yaml = mav0 / "cam0" / "sensor.yaml"
        if op == "focal_tiny":
            _edit_yaml_list(yaml, "intrinsics", lambda v: [10.0, 10.0, v[2], v[3]])
        elif op == "pp_outside":
            _edit_yaml_list(yaml, "intrinsics", lambda v: [v[0], v[1], 5000.0, v[3]])
        else:
            _edit_yaml_list(yaml, "distortion_coefficients", lambda v: [1e4, *v[1:]])
    elif op in ("truth_hour", "truth_mm") and (mav0 / "state_groundtruth_estimate0" / "data.csv").is_file():
        truth = mav0 / "state_groundtruth_estimate0" / "data.csv"
        if op == "truth_mm":
            _scale_columns(truth, (1, 2, 3), 1000.0)
        else:
            lines, rows = _rows(truth)
            for k in rows:
                stamp, rest = lines[k].split(",", 1)
                lines[k] = f"{int(stamp) + 3600 * 10**9},{rest}"
            truth.write_text("\n".join(lines) + "\n")
    elif op in ("imu_g", "imu_deg") and (mav0 / "imu0" / "data.csv").is_file():
        _scale_columns(mav0 / "imu0" / "data.csv", (4, 5, 6) if op == "imu_g" else (1, 2, 3), 1 / 9.81 if op == "imu_g" else 180 / np.pi)


def _apply(root: pathlib.Path, mutation: tuple) -> None:
    kind, name, op, i, j, text = mutation
    target = root / name
    if kind != "careless" and not target.exists():
        return
    if kind == "careless":
        _careless(root, name, i)
    elif kind == "csv":
        _mutate_csv(target, op, i, j, text)
    elif kind == "yaml":
        _mutate_yaml(target, op, i, j, text)
    elif kind == "image":
        _mutate_image(target, op, i, j)
    else:
        shutil.rmtree(target) if target.is_dir() else target.unlink()


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """`room` rendered for 0.3 s: 7 stereo pairs, 200 Hz IMU, ground truth, depth and plane ids."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, render_sequence

    root = tmp_path_factory.mktemp("fuzz") / "room"
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=0.3, seed=0))
    return root


@fuzz_settings(ci_examples=150)
@given(broken=mutations, mode=st.sampled_from(("stereo", "vio")), variant=st.sampled_from(("P-wo", "PL-w")), segmenter=st.sampled_from((None, "learned")))
def test_a_corrupted_euroc_folder_is_run_or_refused_in_one_line(
    sequence: pathlib.Path, tmp_path_factory: pytest.TempPathFactory, capfd: pytest.CaptureFixture[str], broken: list[tuple], mode: str, variant: str, segmenter: str | None
) -> None:
    work = tmp_path_factory.mktemp("case")
    root, out = work / "seq", work / "out"
    shutil.copytree(sequence, root)
    for mutation in broken:
        _apply(root, mutation)
    argv = ["run", "--dataset", str(root), "--mode", mode, "--variant", variant, "--out", str(out)]
    if segmenter:
        argv += ["--segmenter", segmenter]
    rc, stderr = run_cli(argv, capfd)
    check_outcome(rc, stderr, written=[out / name for name in RUN_FILES], folders=[out, work])
    if rc == 2:
        assert not out.exists() or not any(out.iterdir())
    shutil.rmtree(work, ignore_errors=True)
