"""`coplanar run --dataset` on ROS bags: the same trajectories as on the EuRoC folder the
bag was written from (rendered, and the real MH_01 when ../shared is there); a bad bag is
one `error:` line, exit 2, nothing written."""

from __future__ import annotations

import json
import pathlib
import time

import numpy as np
import pytest

from backend.data.rosbag_writer import convert
from backend.data.source import ReaderOptions
from tests.app.test_dataset_folders import _one_error_line, _run
from tests.backend.data.test_rosbag import renders  # noqa: F401 - the rendered boxes scene as EuRoC, rosbag1, rosbag2: a fixture

SHARED = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data"
MH01_FRAMES = 120  # the whole 400 frames take ~45 s a side; 120 (6 s) include the VIO start at ~2 s
Renders = dict[str, tuple[pathlib.Path, ReaderOptions]]


def _input(renders: Renders, name: str) -> list[str]:
    path, options = renders[name]
    return ["--dataset", str(path)] + ([] if options.calib is None else ["--calib", str(options.calib)])


def _trajectory(out: pathlib.Path) -> np.ndarray:
    return np.loadtxt(out / "trajectory.txt", ndmin=2)


@pytest.mark.parametrize("mode", ["stereo", "vio"])
def test_a_bag_runs_as_its_euroc_folder(renders: Renders, tmp_path: pathlib.Path, mode: str) -> None:
    trajectories = {}
    for name in ("euroc", "rosbag1", "rosbag2"):
        out = tmp_path / name
        rc, stdout, err = _run([*_input(renders, name), "--mode", mode, "--variant", "PL-w", "--out", str(out)])
        assert rc == 0, err
        assert "21 frames" in stdout
        trajectories[name] = _trajectory(out)
    assert len(trajectories["euroc"]) >= 10
    for name in ("rosbag1", "rosbag2"):
        assert trajectories[name].shape == trajectories["euroc"].shape
        assert np.abs(trajectories[name] - trajectories["euroc"]).max() <= 1e-9, name


@pytest.mark.skipif(not (SHARED / "euroc_mh01_vio").exists(), reason="../shared/data is absent")
def test_the_real_mh01_as_a_ros1_bag_reproduces_the_folders_vio_run(tmp_path: pathlib.Path) -> None:
    folder = SHARED / "euroc_mh01_vio"
    bag = tmp_path / "bag"
    bag.mkdir()
    convert(folder, bag)
    runs = {}
    for name, source in (("folder", ["--dataset", str(folder)]), ("bag", ["--dataset", str(bag / "data.bag"), "--calib", str(bag / "calib")])):
        start = time.perf_counter()
        rc, _, err = _run([*source, "--mode", "vio", "--frames", str(MH01_FRAMES), "--variant", "PL-w", "--out", str(tmp_path / name)])
        assert rc == 0, err
        runs[name] = (_trajectory(tmp_path / name), json.loads((tmp_path / name / "metrics.json").read_text()), time.perf_counter() - start)
    (folder_poses, folder_metrics, _), (bag_poses, bag_metrics, _) = runs["folder"], runs["bag"]
    assert folder_metrics["vio"]["initialized"] and len(folder_poses) >= 100
    np.testing.assert_array_equal(bag_poses, folder_poses)
    assert bag_metrics["ate_rmse_cm"] == folder_metrics["ate_rmse_cm"] < 5.0


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        ("truncated", ["not a readable ROS1 bag", "Bag index looks damaged"]),
        ("missing topic", ["no topic /left for cam0", "topics in the bag: /cam0/image_raw (sensor_msgs/msg/Image)"]),
        ("no calib", ["a bag holds no camera calibration: pass --calib"]),
    ],
)
def test_a_bad_bag_is_one_line_and_exit_2(renders: Renders, tmp_path: pathlib.Path, damage: str, words: list[str]) -> None:
    path, options = renders["rosbag1"]
    argv = ["--dataset", str(path), "--calib", str(options.calib)]
    if damage == "truncated":
        cut = tmp_path / "cut.bag"
        data = path.read_bytes()
        cut.write_bytes(data[: len(data) // 2])
        argv[1] = str(cut)
    elif damage == "missing topic":
        argv += ["--topic", "cam0=/left"]
    else:
        argv = argv[:2]
    out = tmp_path / "out"
    rc, stdout, err = _run([*argv, "--variant", "PL-w", "--out", str(out)])
    assert rc == 2 and stdout == ""
    _one_error_line(err, [argv[1], *words])
    assert not out.exists()
