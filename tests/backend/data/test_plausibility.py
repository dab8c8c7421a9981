"""Plausibility checks: inputs no parser rejects but that make a run silently wrong get a
reason, as a careless user would make them. Each case: before, a number or a shrug (exit 0);
now one line. On a rendered EuRoC folder and, where ../shared is present, on the real MH_01
slice."""

from __future__ import annotations

import pathlib
import shutil

import numpy as np
import pytest

from backend.data.errors import DatasetError
from backend.data.plausibility import check_imu, ground_truth_scale_warning
from backend.data.source import open_dataset

SLICE = pathlib.Path(__file__).resolve().parents[3].parent / "shared" / "data" / "euroc_mh01_slice"


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> pathlib.Path:
    """The room rendered for 1 s while moving (21 frames) into an EuRoC folder."""
    from backend.data.scenes import builtin_scene
    from backend.data.synthetic import SequenceSettings, render_sequence

    root = tmp_path_factory.mktemp("euroc") / "room"
    render_sequence(builtin_scene("room"), root, settings=SequenceSettings(duration_s=1.0, seed=0))
    return root


def _copy(root: pathlib.Path, to: pathlib.Path) -> pathlib.Path:
    """A copy of the dataset whose image files are links (cheap), the rest copied."""
    shutil.copytree(root, to, copy_function=lambda src, dst: shutil.copy(src, dst) if not src.endswith((".png", ".jpg")) else pathlib.Path(dst).symlink_to(pathlib.Path(src).resolve()))
    return to


def _swap_cameras(root: pathlib.Path) -> None:
    mav0 = root / "mav0"
    (mav0 / "cam0").rename(mav0 / "tmp")
    (mav0 / "cam1").rename(mav0 / "cam0")
    (mav0 / "tmp").rename(mav0 / "cam1")
    for cam in ("cam0", "cam1"):  # the calibration stays where it was: only the images moved
        (mav0 / cam / "sensor.yaml").rename(mav0 / cam / "sensor.other")
    for cam, other in (("cam0", "cam1"), ("cam1", "cam0")):
        (mav0 / other / "sensor.other").rename(mav0 / cam / "sensor.yaml")


def _one_frame_late(root: pathlib.Path) -> None:
    """cam1's data.csv names, for each timestamp, the next frame's image."""
    csv = root / "mav0" / "cam1" / "data.csv"
    lines = csv.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if line and not line.startswith("#")]
    names = [lines[i].split(",")[1] for i in rows]
    for k, i in enumerate(rows):
        lines[i] = f"{lines[i].split(',')[0]},{names[min(k + 1, len(names) - 1)]}"
    csv.write_text("\n".join(lines) + "\n")


def _edit_yaml(root: pathlib.Path, cam: str, old: str, new: str) -> None:
    path = root / "mav0" / cam / "sensor.yaml"
    text = path.read_text()
    assert old in text, text
    path.write_text(text.replace(old, new, 1))


def _intrinsics(root: pathlib.Path, cam: str) -> list[str]:
    line = next(line for line in (root / "mav0" / cam / "sensor.yaml").read_text().splitlines() if line.startswith("intrinsics:"))
    return line.split("[")[1].split("]")[0].split(",")


@pytest.mark.parametrize("data", ["rendered", "real"])
def test_swapped_cameras_are_an_error(data: str, rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """Before: 39 of 40 frames lost on the slice, then a trajectory (exit 0)."""
    root = _input(data, rendered, tmp_path)
    _swap_cameras(root)
    with pytest.raises(DatasetError, match="cam0 and cam1 swapped"):
        open_dataset(root)


@pytest.mark.parametrize("data", ["rendered", "real"])
def test_cam1_one_frame_late_is_a_warning(data: str, rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    root = _input(data, rendered, tmp_path)
    _one_frame_late(root)
    warnings = open_dataset(root).warnings
    assert len(warnings) == 1 and "out of step" in warnings[0] and str(root) in warnings[0]


@pytest.mark.parametrize("data", ["rendered", "real"])
def test_correct_inputs_pass_without_warning(data: str, rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    source = open_dataset(_input(data, rendered, tmp_path))
    assert not getattr(source, "warnings", ())


def _input(data: str, rendered: pathlib.Path, tmp_path: pathlib.Path) -> pathlib.Path:
    if data == "real" and not SLICE.is_dir():
        pytest.skip("../shared/data/euroc_mh01_slice is absent")
    return _copy(SLICE if data == "real" else rendered, tmp_path / "seq")


@pytest.mark.parametrize(
    ("case", "words"),
    [
        ("millimetre baseline", ["cam1/sensor.yaml", "stereo baseline", "millimetres"]),
        ("tiny focal length", ["cam0/sensor.yaml", "focal length fu = 10 px", "field of view"]),
        ("principal point outside", ["cam0/sensor.yaml", "principal point (5000", "outside"]),
        ("k1 = 1e4", ["cam0/sensor.yaml", "distortion coefficients", "corners"]),
        ("folding distortion", ["cam0/sensor.yaml", "fold the image"]),
    ],
)
def test_implausible_calibrations_are_one_line_naming_the_file(case: str, words: list[str], rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """Before (the slice): each ran, with 1 keyframe in 40 frames and 'ATE n/a (no ground
    truth)', or a trajectory off by the error."""
    root = _copy(SLICE if SLICE.is_dir() else rendered, tmp_path / "seq")
    fx, fy, cx, cy = _intrinsics(root, "cam0")
    if case == "millimetre baseline":
        path = root / "mav0" / "cam1" / "sensor.yaml"
        text = path.read_text()
        head, data = text.split("data:", 1)
        values = data.split("]")[0].strip(" [\n").split(",")
        for i in (3, 7, 11):
            values[i] = repr(float(values[i]) * 1000.0)
        path.write_text(head + "data: [" + ", ".join(v.strip() for v in values) + "]" + data.split("]", 1)[1])
    elif case == "tiny focal length":
        _edit_yaml(root, "cam0", f"[{fx},", "[10.0,")
    elif case == "principal point outside":
        _edit_yaml(root, "cam0", f",{cx},", ", 5000.0,")
    else:
        path = root / "mav0" / "cam0" / "sensor.yaml"
        lines = path.read_text().splitlines()
        i = next(i for i, line in enumerate(lines) if line.startswith("distortion_coefficients:"))
        lines[i] = "distortion_coefficients: [10000.0, 0.0, 0.0, 0.0]" if case == "k1 = 1e4" else "distortion_coefficients: [-2.0, 0.0, 0.0, 0.0]"
        path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError) as error:
        open_dataset(root)
    message = str(error.value)
    assert "\n" not in message and all(w in message for w in words), message


def test_ground_truth_an_hour_off_says_so(rendered: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """Before: "no ground truth" although the file was there."""
    root = _copy(rendered, tmp_path / "seq")
    csv = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(line if line.startswith("#") or not line else f"{int(line.split(',')[0]) + 3600 * 10**9},{line.split(',', 1)[1]}" for line in lines) + "\n")
    (warning,) = open_dataset(root).warnings
    assert "overlaps none of the frames" in warning and "+3600.0" in warning and "a clock offset?" in warning


def test_ground_truth_in_millimetres_is_a_warning() -> None:
    """Before: ATE 12,271 cm reported as if real."""
    rng = np.random.default_rng(0)
    p_estimate = np.cumsum(rng.normal(0, 0.05, (50, 3)), axis=0)
    assert ground_truth_scale_warning(p_estimate, p_estimate + 0.002, stereo=True) is None
    warning = ground_truth_scale_warning(p_estimate, 1000.0 * p_estimate, stereo=True)
    assert warning is not None and warning.startswith("the ground truth is 1000 times the metric stereo trajectory in size (in millimetres?)")
    assert ground_truth_scale_warning(p_estimate, 1000.0 * p_estimate, stereo=False) is None  # monocular scale: not a unit check


def test_imu_samples_in_g_or_degrees_per_second_are_errors() -> None:
    t = np.arange(400, dtype=np.int64) * 5_000_000
    rng = np.random.default_rng(0)
    gyro = rng.normal(0, 0.5, (400, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.3, (400, 3))
    check_imu(t, gyro, accel, where="imu0/data.csv")
    with pytest.raises(DatasetError, match=r"imu0/data.csv: the accelerometer's median magnitude is [01]\.\d+, not gravity's 9.81 m/s² .* \(in g\?\)"):
        check_imu(t, gyro, accel / 9.81, where="imu0/data.csv")
    with pytest.raises(DatasetError, match="degrees per second"):
        check_imu(t, np.degrees(gyro) * 3, accel, where="imu0/data.csv")
