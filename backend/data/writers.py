"""The formats `coplanar render --format` writes. A rendered sequence is always written first
as an EuRoC ASL folder (`euroc_writer.py`: images, IMU, the renderer's exact ground truth,
depth and plane ids); every other format is converted from that folder, so that each reader
is tested on rendered data with exact truth against the EuRoC reader of the same render.

A writer is one module with a `convert(euroc_folder, out)` function plus one entry in
`DATASET_WRITERS`; its reader is an entry of `backend.data.source.DATASET_FORMATS`."""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Callable


@dataclasses.dataclass(frozen=True)
class DatasetWriter:
    """One output format: its `--format` name, a description for `--help`, the top-level
    entries it writes into the output folder (none may exist there yet), how to convert a
    rendered EuRoC folder into a folder (None: the EuRoC folder itself), and the options
    that read the result back (`{out}`: the output folder)."""

    name: str
    description: str
    entries: tuple[str, ...]
    convert: Callable[[pathlib.Path, pathlib.Path], None] | None
    read_back: str


def _convert_tumvi(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    from backend.data.tumvi_writer import convert

    convert(euroc_folder, out)


def _convert_kitti(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    from backend.data.kitti_writer import convert

    convert(euroc_folder, out)


def _convert_ros1(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    from backend.data.rosbag_writer import convert

    convert(euroc_folder, out, ros2=False)


def _convert_ros2(euroc_folder: pathlib.Path, out: pathlib.Path) -> None:
    from backend.data.rosbag_writer import convert

    convert(euroc_folder, out, ros2=True)


DATASET_WRITERS: tuple[DatasetWriter, ...] = (
    DatasetWriter("euroc", "EuRoC ASL folder (mav0)", ("mav0",), None, "--dataset {out}"),
    DatasetWriter("kitti", "KITTI odometry sequence (sequences/00, poses/00.txt)", ("sequences", "poses"), _convert_kitti, "--dataset {out}/sequences/00"),
    DatasetWriter("tumvi", "TUM-VI export in EuRoC format (mav0, dso/camchain.yaml; equidistant fisheye images)", ("mav0", "dso"), _convert_tumvi, "--dataset {out}"),
    DatasetWriter("rosbag1", "ROS1 bag data.bag with its calibration folder calib", ("data.bag", "calib"), _convert_ros1, "--dataset {out}/data.bag --calib {out}/calib"),
    DatasetWriter("rosbag2", "ROS2 bag folder data (sqlite3) with its calibration folder calib", ("data", "calib"), _convert_ros2, "--dataset {out}/data --calib {out}/calib"),
)


def dataset_writer(name: str) -> DatasetWriter:
    """The writer called `name` (KeyError for an unknown one)."""
    for writer in DATASET_WRITERS:
        if writer.name == name:
            return writer
    raise KeyError(name)
