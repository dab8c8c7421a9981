"""An EuRoC ASL folder (a real one, or one `coplanar render` wrote) as a ROS bag, with the
calibration folder a bag needs beside it (backend/data/rosbag_writer.py: the topics, frames
and what is written).

    .venv/bin/python scripts/euroc_to_bag.py FOLDER OUT            # OUT/data.bag + OUT/calib (ROS1)
    .venv/bin/python scripts/euroc_to_bag.py FOLDER OUT --ros2     # OUT/data/ (sqlite3) + OUT/calib
    .venv/bin/python scripts/euroc_to_bag.py FOLDER OUT --ros2 --mcap

Then: `coplanar run --dataset OUT/data.bag --calib OUT/calib ...` (`OUT/data` for ROS2).
OUT is created if missing and must not hold the bag or `calib` yet; the files are written
into a hidden staging folder and moved into place when complete. Bad input is one
`error:` line and exit code 2.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.common.atomic import make_folder, staged_folder
from backend.data.errors import DatasetError
from backend.data.rosbag_writer import convert


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=pathlib.Path, help="EuRoC ASL folder (holding mav0)")
    parser.add_argument("out", type=pathlib.Path, help="output folder: data.bag (or data/ with --ros2) and calib/")
    parser.add_argument("--ros2", action="store_true", help="a ROS2 bag folder instead of a ROS1 .bag file")
    parser.add_argument("--mcap", action="store_true", help="with --ros2: MCAP storage instead of sqlite3")
    args = parser.parse_args(argv)
    if args.mcap and not args.ros2:
        parser.error("--mcap: only with --ros2")
    bag = "data" if args.ros2 else "data.bag"
    try:
        for entry in (bag, "calib"):
            if (args.out / entry).exists():
                raise DatasetError(args.out / entry, "already exists; choose a new output folder")
        make_folder(args.out)
        with staged_folder(args.out) as stage:
            convert(args.folder, stage, ros2=args.ros2, storage="mcap" if args.mcap else "sqlite3")
    except DatasetError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"error: {args.out}: cannot write: {e.strerror or e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out / bag} and {args.out / 'calib'}; read it with --dataset {args.out / bag} --calib {args.out / 'calib'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
