"""The KITTI odometry reader (backend/data/kitti.py) and writer (backend/data/kitti_writer.py):
a sequence folder reads as a stereo source without an IMU, every bad file is one line naming
it, and a rendered EuRoC folder written as KITTI reads back exactly as the EuRoC reader
gives it."""

from __future__ import annotations

import os
import pathlib

import numpy as np
import pytest
from PIL import Image

from backend.data.errors import DatasetError
from backend.data.euroc import EurocDataset
from backend.data.kitti import KittiSequence, seconds_to_ns
from backend.data.kitti_writer import calib_text, convert
from backend.data.scenes import builtin_scene
from backend.data.source import RenderedTruth, StereoSource, dataset_format, open_dataset
from backend.data.synthetic import SequenceSettings, render_sequence
from backend.geometry.camera import PinholeCamera

# KITTI sequence 00's calib.txt (P2, P3 left out: the reader needs P0 and P1 only).
P0 = (
    "P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 7.188560000000e+02 "
    "1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00"
)
P1 = (
    "P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 7.188560000000e+02 "
    "1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 0.000000000000e+00"
)
TR = (
    "Tr: 4.276802385584e-04 -9.999672484946e-01 -8.084491683471e-03 -1.198459927713e-02 -7.210626507497e-03 8.081198471645e-03 "
    "-9.999413164504e-01 -5.403984729748e-02 9.999738645903e-01 4.859485810390e-04 -7.206933692422e-03 -2.921968648686e-01"
)
TIMES = ("0.000000e+00", "1.036594e-01", "2.072438e-01", "3.109284e-01")
WIDTH, HEIGHT = 1241, 376  # KITTI 00's image size: its calib.txt must fit the images


def _pose(k: int) -> np.ndarray:
    """Frame k's T_world_cam0: a turn about y (KITTI's down) and a step along z."""
    a = 0.05 * k
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    T[:3, 3] = (0.01 * k, 0.0, 0.8 * k)
    return T


def _images(k: int) -> tuple[np.ndarray, np.ndarray]:
    left = np.random.default_rng(k).integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8)
    return left, 255 - left


def _kitti(root: pathlib.Path, *, poses: bool = True) -> pathlib.Path:
    """A 4-frame KITTI odometry layout under `root`: `sequences/00` (returned) and
    `poses/00.txt`, numbers written as KITTI writes them."""
    sequence = root / "sequences" / "00"
    for i in (0, 1):
        (sequence / f"image_{i}").mkdir(parents=True)
    for k in range(len(TIMES)):
        for i, image in enumerate(_images(k)):
            Image.fromarray(image).save(sequence / f"image_{i}" / f"{k:06d}.png")
    (sequence / "calib.txt").write_text(f"{P0}\n{P1}\n{TR}\n")
    (sequence / "times.txt").write_text("".join(f"{t}\n" for t in TIMES))
    if poses:
        (root / "poses").mkdir()
        (root / "poses" / "00.txt").write_text("".join(" ".join(f"{x:.12e}" for x in _pose(k)[:3].ravel()) + "\n" for k in range(len(TIMES))))
    return sequence


def test_a_sequence_reads_as_a_stereo_source_with_its_ground_truth(tmp_path: pathlib.Path) -> None:
    source = KittiSequence(_kitti(tmp_path))
    assert isinstance(source, StereoSource) and not isinstance(source, RenderedTruth) and len(source) == 4
    np.testing.assert_array_equal(source.timestamps_ns, [0, 103_659_400, 207_243_800, 310_928_400])  # exact, no float rounding
    assert source.timestamps_ns.dtype == np.int64
    cam = source.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (718.856, 718.856, 607.1928, 185.2157, WIDTH, HEIGHT)
    assert cam.baseline == pytest.approx(386.1448 / 718.856, rel=1e-15)  # -P1[0,3] / P1[0,0]: 0.537 m
    for k in range(4):
        left, right = source.rectified_pair(k)
        assert left.dtype == np.uint8 and left.shape == (HEIGHT, WIDTH)
        np.testing.assert_array_equal(left, _images(k)[0])
        np.testing.assert_array_equal(right, _images(k)[1])
    assert source.ground_truth_valid.all()
    np.testing.assert_allclose(source.T_world_rect0, np.stack([_pose(k) for k in range(4)]), atol=1e-12)
    assert source.ground_truth_frame == "cam0"
    np.testing.assert_array_equal(source.T_truth_rect0, np.eye(4))
    np.testing.assert_allclose(source.projections["Tr"][2, 0], 0.9999738645903)


def test_without_a_poses_file_no_frame_has_ground_truth(tmp_path: pathlib.Path) -> None:
    source = KittiSequence(_kitti(tmp_path, poses=False))
    assert not source.ground_truth_valid.any() and np.isnan(source.T_world_rect0).all()
    assert source.T_world_rect0.shape == (4, 4, 4)


def test_a_row_of_nan_is_a_frame_without_ground_truth(tmp_path: pathlib.Path) -> None:
    sequence = _kitti(tmp_path)
    poses = tmp_path / "poses" / "00.txt"
    rows = poses.read_text().splitlines()
    poses.write_text("\n".join([*rows[:3], " ".join(["nan"] * 12)]) + "\n")
    np.testing.assert_array_equal(KittiSequence(sequence).ground_truth_valid, [True, True, True, False])


def test_no_imu_the_vio_way(tmp_path: pathlib.Path) -> None:
    """As an EuRoC folder without imu0: has_imu False, and asking for IMU data is one line."""
    source = KittiSequence(_kitti(tmp_path))
    assert source.has_imu is False
    for ask in (lambda: source.imu, lambda: source.imu_between(0, 10), lambda: source.imu_noise, lambda: source.T_body_rect0):
        with pytest.raises(DatasetError, match="no IMU data: IMU data is needed for VIO") as error:
            ask()
        assert "\n" not in str(error.value) and str(source.root) in str(error.value)


def test_images_load_lazily_and_a_broken_one_is_one_line_when_read(tmp_path: pathlib.Path) -> None:
    sequence = _kitti(tmp_path)
    source = KittiSequence(sequence)
    broken = sequence / "image_1" / "000002.png"
    broken.write_bytes(broken.read_bytes()[:30])
    source.rectified_pair(1)  # other frames still read
    with pytest.raises(DatasetError, match="not a readable image") as error:
        source.rectified_pair(2)
    assert str(error.value).startswith(str(broken)) and "\n" not in str(error.value)
    broken.unlink()
    with pytest.raises(DatasetError, match="missing image"):
        source.rectified_pair(2)
    Image.fromarray(np.zeros((HEIGHT, WIDTH + 1), np.uint8)).save(broken)
    with pytest.raises(DatasetError, match=f"image is {WIDTH + 1}x{HEIGHT}"):
        source.rectified_pair(2)


def _replace_line(path: pathlib.Path, index: int, text: str | None) -> None:
    lines = path.read_text().splitlines()
    if text is None:
        del lines[index]
    else:
        lines[index] = text
    path.write_text("\n".join(lines) + "\n")


def _row_of(values: np.ndarray) -> str:
    return " ".join(f"{x:.12e}" for x in values)


def _bad_rotation_row() -> str:
    T = _pose(2)[:3].copy()
    T[:, 0] *= 1.1
    return _row_of(T.ravel())


# (what to break, the file the message names, words it holds)
BAD = {
    "calib missing": (lambda s: (s / "calib.txt").unlink(), "calib.txt", "missing file"),
    "calib without P1": (lambda s: _replace_line(s / "calib.txt", 1, None), "calib.txt", "no P1 line"),
    "calib non-number": (lambda s: _replace_line(s / "calib.txt", 0, P0.replace("6.071928000000e+02", "6.07l928e+02")), "calib.txt line 1", "P0: non-numeric value '6.07l928e+02'"),
    "calib short P0": (lambda s: _replace_line(s / "calib.txt", 0, P0.rsplit(" ", 1)[0]), "calib.txt line 1", "P0 has 11 numbers, expected 12"),
    "calib no colon": (lambda s: _replace_line(s / "calib.txt", 2, "Tr 1 2 3"), "calib.txt line 3", "expected 'KEY: numbers'"),
    "zero focal length": (lambda s: _replace_line(s / "calib.txt", 0, P0.replace("7.188560000000e+02", "0", 1)), "calib.txt", "degenerate camera"),
    "zero baseline": (lambda s: _replace_line(s / "calib.txt", 1, P1.replace("-3.861448000000e+02", "0")), "calib.txt", "baseline of 0 m"),
    "right camera on the left": (lambda s: _replace_line(s / "calib.txt", 1, P1.replace("-3.861448000000e+02", "3.861448000000e+02")), "calib.txt", "baseline of -0.537"),
    "focal length in metres": (
        lambda s: _replace_line(s / "calib.txt", 0, P0.replace("7.188560000000e+02", "7.188560000000e-03", 1)),
        "calib.txt",
        "P0 fx = 0.00718856 px gives a 180.0° field of view",
    ),
    "principal point off the image": (
        lambda s: _replace_line(s / "calib.txt", 0, P0.replace("6.071928000000e+02", "6.071928000000e+03")),
        "calib.txt",
        "principal point (6071.93, 185.216) px lies outside the 1241x376 image",
    ),
    "baseline in millimetres": (lambda s: _replace_line(s / "calib.txt", 1, P1.replace("-3.861448000000e+02", "-3.861448000000e+05")), "calib.txt", "stereo baseline 537.2 m"),
    "times missing": (lambda s: (s / "times.txt").unlink(), "times.txt", "missing file"),
    "times fewer than images": (lambda s: _replace_line(s / "times.txt", 3, None), "times.txt", "3 times, but"),
    "times more than images": (lambda s: _replace_line(s / "times.txt", 3, "3.109284e-01\n4.2e-01"), "image_0/000004.png", "missing image of frame 4"),
    "times non-number": (lambda s: _replace_line(s / "times.txt", 1, "0.1O"), "times.txt line 2", "'0.1O' is not a time in seconds"),
    "times not increasing": (lambda s: _replace_line(s / "times.txt", 2, "1.0e-01"), "times.txt line 3", "not after the previous line's"),
    "image missing": (lambda s: (s / "image_1" / "000002.png").unlink(), "image_1/000002.png", "missing image of frame 2"),
    "image folder missing": (lambda s: [p.unlink() for p in (s / "image_1").iterdir()] and (s / "image_1").rmdir(), "image_1", "missing folder"),
    "poses row of 11": (lambda s: _replace_line(s.parent.parent / "poses" / "00.txt", 2, _row_of(_pose(2)[:3].ravel()[:11])), "poses/00.txt line 3", "11 numbers, expected 12"),
    "poses fewer than times": (lambda s: _replace_line(s.parent.parent / "poses" / "00.txt", 3, None), "poses/00.txt", "3 poses, but times.txt has 4"),
    "poses non-number": (lambda s: _replace_line(s.parent.parent / "poses" / "00.txt", 0, "x" + _row_of(_pose(0)[:3].ravel())), "poses/00.txt line 1", "non-numeric value"),
    "poses partly nan": (lambda s: _replace_line(s.parent.parent / "poses" / "00.txt", 1, "nan " + _row_of(_pose(1)[:3].ravel()[1:])), "poses/00.txt line 2", "non-finite"),
    "poses not a rotation": (lambda s: _replace_line(s.parent.parent / "poses" / "00.txt", 2, _bad_rotation_row()), "poses/00.txt line 3", "not a rotation"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_every_bad_file_is_one_line_naming_it(tmp_path: pathlib.Path, case: str) -> None:
    sequence = _kitti(tmp_path)
    breaks, file, words = BAD[case]
    breaks(sequence)
    with pytest.raises(DatasetError) as error:
        open_dataset(sequence)
    message = str(error.value)
    assert "\n" not in message and words in message, message
    where = tmp_path / "poses" / file.removeprefix("poses/") if file.startswith("poses/") else sequence / file
    assert message.startswith(str(where)), message


def test_the_format_is_recognized_from_its_files(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sequence = _kitti(tmp_path)
    assert dataset_format(sequence).label == "KITTI sequence"
    assert isinstance(open_dataset(sequence), KittiSequence)
    (sequence / "times.txt").unlink()  # one of the three missing: still KITTI, which names it
    assert dataset_format(sequence).label == "KITTI sequence"
    assert dataset_format(tmp_path).label == "EuRoC folder"  # the root itself is no sequence
    (sequence / "times.txt").write_text("".join(f"{t}\n" for t in TIMES))
    monkeypatch.chdir(sequence)  # `--dataset .` finds ../../poses/00.txt
    assert KittiSequence(pathlib.Path(".")).ground_truth_valid.all()


def test_seconds_are_read_exactly() -> None:
    assert seconds_to_ns("4.540630e+02") == 454_063_000_000
    assert seconds_to_ns("0.000000001") == 1 and seconds_to_ns("-0.5") == -500_000_000
    for bad in ("nan", "inf", "1,5", ""):
        with pytest.raises(ValueError):
            seconds_to_ns(bad)


def test_the_written_baseline_reads_back_to_the_last_place() -> None:
    for fx, baseline in ((458.0000000000001, 0.11000000000000001), (718.856, 0.5371657), (1000.0, 0.3)):
        calib = calib_text(PinholeCamera(fx=fx, fy=fx, cx=10.0, cy=8.0, width=20, height=16, baseline=baseline)).splitlines()
        P1 = np.array([float(x) for x in calib[1].split(":")[1].split()])
        assert abs(-P1[3] / P1[0] - baseline) <= np.spacing(baseline)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[pathlib.Path, pathlib.Path]:
    """`boxes` rendered for 0.2 s (5 frames) as EuRoC, and that folder converted to KITTI."""
    root = tmp_path_factory.mktemp("kitti")
    render_sequence(builtin_scene("boxes"), root / "euroc", settings=SequenceSettings(duration_s=0.2))
    convert(root / "euroc", root / "kitti")
    return root / "euroc", root / "kitti"


def test_a_rendered_folder_written_as_kitti_reads_back_as_the_euroc_reader_gives_it(rendered: tuple[pathlib.Path, pathlib.Path]) -> None:
    euroc_folder, kitti_folder = rendered
    euroc, kitti = EurocDataset(euroc_folder), open_dataset(kitti_folder / "sequences" / "00")
    assert isinstance(kitti, KittiSequence) and len(kitti) == len(euroc) == 5
    assert kitti.camera == euroc.camera  # every number, baseline included
    np.testing.assert_array_equal(kitti.timestamps_ns, euroc.timestamps_ns)
    np.testing.assert_array_equal(kitti.T_world_rect0, euroc.T_world_rect0)  # full precision, the render's world frame
    np.testing.assert_array_equal(kitti.ground_truth_valid, euroc.ground_truth_valid)
    for i in range(len(euroc)):
        for a, b in zip(kitti.rectified_pair(i), euroc.rectified_pair(i)):
            np.testing.assert_array_equal(a, b)
    calib = (kitti_folder / "sequences" / "00" / "calib.txt").read_text().splitlines()
    assert [line.split(":")[0] for line in calib] == ["P0", "P1", "P2", "P3", "Tr"]
    assert calib[2].split(":")[1] == calib[0].split(":")[1] and calib[3].split(":")[1] == calib[1].split(":")[1]
    assert sorted(os.listdir(kitti_folder)) == ["poses", "sequences"]
