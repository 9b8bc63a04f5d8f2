#!/usr/bin/env python
"""Estimate the tractor's Ackermann axle offset (``axle_x``) from ground-truth poses and print it.

    python scripts/estimate_axle_offset.py DATASET [--step N] [--min-yaw-deg D]

DATASET is a KITTI odometry folder (poses.txt; the body frame of ampc_vo.io.kitti, origin on
the ground below the left camera) or one of our dataset folders (groundtruth.csv; origin at the
hitch). Uses the turning pose pairs only: on straight driving axle_x is unobservable.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ampc_vo.tools.axle_offset import estimate_axle_x
from ampc_vo.io.kitti import is_kitti_folder, load_kitti
from ampc_vo.errors import AmpcError
from ampc_vo.tools.cli import exit_codes  # noqa: E402


@exit_codes
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--step", type=int, default=1, help="frames between the two poses of a pair")
    parser.add_argument("--min-yaw-deg", type=float, default=0.5, help="minimum yaw change of a pair")
    args = parser.parse_args()
    if is_kitti_folder(args.dataset):
        dataset = load_kitti(args.dataset)
        if dataset.T_world_tractor is None:
            raise AmpcError(f"{args.dataset}: no poses.txt")
        poses, configured = dataset.T_world_tractor, dataset.rig.axle_x("tractor")
    else:
        from ampc_vo.io.folder import read_dataset

        dataset = read_dataset(args.dataset, load_measurements_file=False)
        if dataset.groundtruth is None:
            raise AmpcError(f"{args.dataset}: no groundtruth.csv")
        poses, configured = dataset.groundtruth.T_world_tractor, dataset.rig.axle_x("tractor")
    estimate = estimate_axle_x(poses, step=args.step, min_yaw_change_rad=np.radians(args.min_yaw_deg))
    print(f"axle_x = {estimate.axle_x:.3f} m  (standard error {estimate.standard_error:.3f} m, "
          f"{estimate.pairs} turning pose pairs, residual rms {1000 * estimate.residual_rms:.1f} mm; configured {configured:.3f} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
