#!/usr/bin/env python3
"""The body's direction of travel from road points, per frame pair, against the truth (issue 16).

A dataset camera's frontend tracks below the horizon meet the road plane of the body frame; with
the true rotation between two frames their bearings fix the body's planar translation
(``ampc_vo.tools.road_direction``). Prints the direction error's mean and standard deviation (the
epipolar geometry of a forward camera reads it to ~2 degrees per pair at 29 m/s) and the forward
translation over the truth.

    python scripts/measure_road_direction.py DATA [--camera cab_front] [--frames 420 470]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.errors import DatasetError  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder with images and groundtruth.csv")
    parser.add_argument("--camera", default="cab_front")
    parser.add_argument("--frames", type=int, nargs=2, metavar=("START", "STOP"), default=None, help="frames [START, STOP) (default: all)")
    args = parser.parse_args(argv)
    from ampc_vo.config import load_config
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.io.groundtruth import groundtruth_of
    from ampc_vo.tools.road_direction import MIN_ROAD_POINTS, road_direction_errors

    dataset = read_dataset(args.data)
    truth = groundtruth_of(dataset)
    if truth is None:
        raise DatasetError(f"{args.data}: no groundtruth.csv to compare with")
    if args.camera not in dataset.rig.camera_names:
        raise DatasetError(f"{args.data}: no camera {args.camera!r}; the rig has {', '.join(dataset.rig.camera_names)}")
    start, stop = args.frames or (0, len(dataset))
    errors = road_direction_errors(dataset, truth, args.camera, start, min(stop, len(dataset)), load_config(None).frontend)
    if len(errors.frame) == 0:
        raise DatasetError(f"{args.camera}: no frame pair with {MIN_ROAD_POINTS} road points in frames [{start}, {stop})")
    print(f"{args.camera}, frames {start}-{stop}: {len(errors.frame)} pairs, median {np.median(errors.road_points):.0f} road points")
    print(f"direction error: mean {errors.direction_error_deg.mean():+.3f} deg, standard deviation {errors.direction_error_deg.std():.3f} deg "
          f"(median {np.median(errors.direction_error_deg):+.3f})")
    print(f"forward translation / truth: median {np.median(errors.forward_ratio):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
