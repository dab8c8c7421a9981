"""Reader of TUM-VI's "exported in EuRoC format" folders (e.g. `dataset-corridor1_512_16`):
an EuRoC-style `mav0` with the calibration in Kalibr's files under `dso/`.

```
ROOT/mav0/cam0/{data.csv, data/<t>.png}    left fisheye camera, 16-bit grey PNG (the `_16`)
ROOT/mav0/cam1/{data.csv, data/<t>.png}    right
ROOT/mav0/imu0/data.csv                    EuRoC's IMU columns (rad/s, m/s²), IMU frame
ROOT/mav0/mocap0/data.csv                  #timestamp [ns], p_RS_R_x [m], ..., q_RS_w [], ... (8 columns)
ROOT/dso/camchain.yaml                     Kalibr: pinhole + equidistant cam0, cam1, T_cam_imu, T_cn_cnm1
ROOT/dso/imu_config.yaml                   Kalibr: noise densities (per √Hz) and update_rate (Hz)
```

Assumed of the real layout (from public converters and loaders of these exports, not from a
download): the camera and IMU folders hold no `sensor.yaml`, so the calibration is `dso/`'s
only (a `sensor.yaml` there is ignored); `dso/` may hold more (`cam0/` with DSO's camera and
vignette files, `gt_imu.csv`, `imu.txt`), which is not read; the 16-bit images keep their
high byte (`>> 8`), as OpenCV's 8-bit grey reading does; `mocap0/data.csv` is the pose of the
IMU (the body) in the motion-capture frame (a `mocap0/sensor.yaml` is not read); the
camchain's `timeshift_cam_imu` is not applied (the export's timestamps share one clock).
Motion capture covers only part of most sequences (the room, and the start and end of the
others): frames outside it, or in a gap over `max_ground_truth_gap_ns`, have NaN poses.

Everything else is the EuRoC reader's (`backend.data.euroc`): the CSV checks, stereo frames
as the common timestamps, the ground truth's interpolation, lazy image loading and the
one-line DatasetError naming the file. The equidistant cameras are rectified to a pinhole
pair as `backend.data.calibration` describes.
"""

from __future__ import annotations

import pathlib

from backend.data.calibration import CameraCalibration, ImuCalibration, read_kalibr_camchain, read_kalibr_imu
from backend.data.euroc import EurocDataset

CAMCHAIN = "dso/camchain.yaml"
IMU_CONFIG = "dso/imu_config.yaml"


def tumvi_root(path: pathlib.Path) -> pathlib.Path | None:
    """The export's root (the folder holding `mav0` and `dso/camchain.yaml`) for `path`, the
    root or its `mav0`; None when `path` is not a TUM-VI export."""
    for root in (path, path.parent if path.name == "mav0" else None):
        if root is not None and (root / "mav0").is_dir() and (root / CAMCHAIN).is_file():
            return root
    return None


class TumviDataset(EurocDataset):
    """A TUM-VI export (module docstring): `root` holds `mav0` and `dso` (or is its `mav0`).
    The ground truth is `mav0/mocap0`, the pose of the body (the IMU). Raises DatasetError on
    bad input."""

    GROUND_TRUTH_FOLDER = "mocap0"
    SIXTEEN_BIT_IMAGES = True

    def __init__(self, root: pathlib.Path | str, *, max_ground_truth_gap_ns: int = 100_000_000) -> None:
        root = pathlib.Path(root)
        self.dso = (tumvi_root(root) or root) / "dso"
        super().__init__(root, max_ground_truth_gap_ns=max_ground_truth_gap_ns)

    def _read_cameras(self, cam0_dir: pathlib.Path, cam1_dir: pathlib.Path) -> tuple[CameraCalibration, CameraCalibration]:
        """cam0 and cam1 of `dso/camchain.yaml`, with the IMU as the body."""
        return read_kalibr_camchain(self.dso / "camchain.yaml")

    def _read_imu_calibration(self, imu_dir: pathlib.Path) -> ImuCalibration:
        """The noise densities and rate of `dso/imu_config.yaml`; the IMU is the body."""
        return read_kalibr_imu(self.dso / "imu_config.yaml")
