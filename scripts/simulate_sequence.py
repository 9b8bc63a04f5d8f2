#!/usr/bin/env python3
"""Simulate a truck-with-trailer sequence into a dataset folder (DESIGN section 5).

Writes rig.yaml, frames.csv, groundtruth.csv, measurements.npz and (unless --no-images, and if the
renderer is available) images/<camera>/<frame:06d>.png.

Usage: python scripts/simulate_sequence.py --config configs/sim/demo.yaml --out runs/demo [--no-images] [--rig RIG]

--rig replaces the config's rig (e.g. the same route seen by the fisheye rig: configs/rigs/fisheye.yaml).
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.errors import ConfigError  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.sim.config import load_sim_config  # noqa: E402
from ampc_vo.sim.simulation import simulate_dataset  # noqa: E402


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulate a tractor-trailer sequence into a dataset folder.")
    parser.add_argument("--config", required=True, help="simulation config (configs/sim/*.yaml)")
    parser.add_argument("--out", required=True, help="output dataset folder")
    parser.add_argument("--no-images", action="store_true", help="write bearing measurements only, no images")
    parser.add_argument("--rig", type=Path, default=None, help="rig.yaml to use instead of the config's rig (e.g. configs/rigs/fisheye.yaml)")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    started = time.perf_counter()
    config = load_sim_config(args.config)
    if args.rig is not None:
        if not args.rig.is_file():
            raise ConfigError(f"{args.rig}: rig file not found")
        config = dataclasses.replace(config, rig_path=args.rig.resolve())
    result = simulate_dataset(config, args.out, with_images=not args.no_images, progress=True)
    trajectory = result.trajectory
    print(f"wrote {args.out}: {len(trajectory)} frames, {trajectory.timestamps[-1] - trajectory.timestamps[0]:.1f} s, "
          f"cameras {', '.join(result.rig.camera_names)}")
    counts = result.measurements.tracks_per_camera()
    print("tracks per frame: " + ", ".join(f"{name} {count:.0f}" for name, count in counts.items()))
    if args.no_images:
        print("images not written (--no-images)")
    elif not result.images_written:
        print("images not written: renderer not available yet")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
