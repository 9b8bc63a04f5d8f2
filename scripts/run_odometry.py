#!/usr/bin/env python
"""Run the odometry on a dataset folder with bearing measurements (issue 5, DESIGN sections 4, 5).

    python scripts/run_odometry.py DATASET --out OUT [--config CONFIG] [--mode MODE]

Reads DATASET/rig.yaml, frames.csv and measurements.npz; writes OUT/tractor.tum, OUT/trailer.tum,
OUT/hitch.csv incrementally (a crash keeps what was done), OUT/timing.json and OUT/config.yaml,
and prints a summary (frames, keyframes, distance, fps, backend time per keyframe).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ampc_vo.config import MODES, load_config
from ampc_vo.errors import AmpcError
from ampc_vo.pipeline import run_on_frames


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, help="dataset folder (rig.yaml, frames.csv, measurements.npz)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--config", type=Path, default=None, help="VO config YAML (default: built-in defaults = configs/vo/default.yaml)")
    parser.add_argument("--mode", choices=MODES, default=None, help="override the config's mode")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--wheel-speed-from-groundtruth", type=float, default=None, metavar="SIGMA_M",
                        help="simulate wheel odometry from groundtruth.csv with this noise (m) and enable the wheel-speed factor")
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config)
        if args.mode:
            config = config.with_mode(args.mode)
        logging.basicConfig(level=config.output.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
        from ampc_vo.datasets.folder import read_dataset

        dataset = read_dataset(args.dataset)
        if dataset.measurements is None:
            raise AmpcError(f"{args.dataset}: no measurements.npz (this script runs on bearing measurements; image datasets need the frontend)")
        frames = dataset.measurements.frames(dataset.rig)
        wheel = None
        if args.wheel_speed_from_groundtruth is not None:
            if dataset.groundtruth is None:
                raise AmpcError(f"{args.dataset}: --wheel-speed-from-groundtruth needs groundtruth.csv")
            import dataclasses

            from ampc_vo.pipeline import wheel_odometry_from_poses

            config = dataclasses.replace(config, scale=dataclasses.replace(config.scale, wheel_speed=True))
            wheel = wheel_odometry_from_poses(dataset.groundtruth.timestamps, dataset.groundtruth.T_world_tractor, dataset.rig.axle_x("tractor"), args.wheel_speed_from_groundtruth)
        summary, _ = run_on_frames(dataset.rig, config, frames, args.out, total=dataset.measurements.frame_count,
                                   progress=False if args.no_progress else None, wheel_odometry=wheel)
    except AmpcError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{args.dataset} -> {args.out}  (mode {summary.mode})")
    print(f"frames {summary.frames}  keyframes {summary.keyframes}  distance {summary.distance_m:.1f} m  "
          f"{summary.frames_per_second:.1f} frames/s  backend {summary.backend_ms_median:.1f} ms/keyframe (median)")
    print("backend breakdown (median ms): " + ", ".join(f"{name} {value:.1f}" for name, value in summary.backend_ms_breakdown.items()))
    print("keyframe statuses: " + ", ".join(f"{name} {count}" for name, count in summary.statuses.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
