#!/usr/bin/env python
"""A rendered route with unsynchronised cameras, run from our dataset folder and from recordings
calibrated through a Kalibr camchain (issue 15 acceptance; ``ampc_vo.tools.recordings``).

    python scripts/experiment_recordings.py --out OUT [--route configs/sim/demo.yaml] [--frames N]
                                            [--offsets-ms 0,17,33,50] [--formats ros2-mcap,ros1]
                                            [--raw | --image-format png]

Renders the route with camera k capturing at frame time + offset k (OUT/folder, reused when
there), writes it as each recording format with JPEG-compressed images (--image-format png: PNG,
lossless; --raw: uncompressed),
builds the rig through camchain.yaml + layout.yaml, runs the odometry on all and prints one row
each: tractor ATE, trailer ATE, hitch RMSE and their ratio to the folder's.
"""
from __future__ import annotations

import argparse
import logging
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from ampc_vo.tools.cli import exit_codes  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@exit_codes
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--route", type=Path, default=ROOT / "configs" / "sim" / "demo.yaml")
    parser.add_argument("--frames", type=int, default=None, help="first N frames of the route (default: all)")
    parser.add_argument("--offsets-ms", default="0,17,33,50", help="capture offset of each rig camera (ms), in rig order")
    parser.add_argument("--formats", default="ros2-mcap,ros1")
    parser.add_argument("--raw", action="store_true", help="uncompressed images in the recordings")
    parser.add_argument("--image-format", choices=("jpeg", "png"), default="jpeg", help="compression of the images (JPEG quality 95, or PNG)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from ampc_vo.sim.config import load_sim_config
    from ampc_vo.tools.recordings import compare_log_with_folder, render_unsynchronised

    rig = load_sim_config(args.route).load_rig()
    offsets = [float(value) * 1e-3 for value in args.offsets_ms.split(",")]
    if len(offsets) != len(rig.cameras):
        parser.error(f"--offsets-ms: {len(rig.cameras)} offsets needed (cameras {rig.camera_names}), got {len(offsets)}")
    folder = args.out / "folder"
    if not (folder / "frames.csv").is_file():
        render_unsynchronised(args.route, folder, dict(zip(rig.camera_names, offsets)), args.frames, progress=True)
    work = args.out / ("raw" if args.raw else f"compressed-{args.image_format}")
    shutil.rmtree(work, ignore_errors=True)
    comparison = compare_log_with_folder(folder, work, tuple(args.formats.split(",")), compressed=not args.raw, image_format=args.image_format)
    base = comparison.folder
    print(f"{args.route.name}: offsets {args.offsets_ms} ms, images {'raw' if args.raw else {'jpeg': 'JPEG q95', 'png': 'PNG'}[args.image_format]}, {base.distance_m:.0f} m")
    print("| source | keyframes | tractor ATE m | trailer ATE m | hitch RMSE deg | ATE / folder | hitch / folder |")
    print("|---|---|---|---|---|---|---|")
    for name, metrics in [("folder", base), *comparison.logs.items()]:
        print(f"| {name} | {metrics.frames} | {metrics.tractor_ate_m:.4f} | {metrics.trailer_ate_m:.4f} | {metrics.hitch_rmse_deg:.4f} | "
              f"{metrics.tractor_ate_m / base.tractor_ate_m:.3f} | {metrics.hitch_rmse_deg / base.hitch_rmse_deg:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
