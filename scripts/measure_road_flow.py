#!/usr/bin/env python3
"""Road flow read by KLT, plain and with the frontend's plane-warped second pass (DESIGN 4).

Each chosen image of a dataset camera is warped by the exact road-plane motion of a forward move
(``ampc_vo.tools.road_flow``); prints, per distance ahead, how many road tracks each tracker keeps
and the median of their flow over the true flow (1 = right; the ground-plane scale inherits it).

    python scripts/measure_road_flow.py DATA [--camera cab_front] [--move 2.5] [--frames 100 300 500]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ampc_vo.io.folder import read_dataset  # noqa: E402
from ampc_vo.tools.road_flow import road_flow_ratios  # noqa: E402

BINS_M = ((4, 12), (12, 16), (16, 22), (22, 30), (30, 60))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="dataset folder (rig.yaml, frames.csv, images)")
    parser.add_argument("--camera", default="cab_front")
    parser.add_argument("--move", type=float, default=2.5, help="forward move in metres (2.5 = 25 m/s at 10 Hz)")
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 300, 500])
    args = parser.parse_args(argv)
    dataset = read_dataset(args.data)
    camera = dataset.rig.camera(args.camera)
    results = [road_flow_ratios(camera, dataset.load_image(frame, camera.name), dataset.rig.ground_z, args.move) for frame in args.frames]
    distance = np.concatenate([r.distance_m for r in results])
    flow = np.concatenate([r.flow_px for r in results])
    print(f"{args.data} camera {camera.name}, forward move {args.move} m, frames {args.frames}")
    print(f"{'distance ahead':>16s} {'true flow':>10s} {'plain KLT':>18s} {'plane-warped':>18s}")
    for low, high in BINS_M:
        chosen = (distance >= low) & (distance < high)
        if not chosen.any():
            continue
        cells = []
        for name in ("plain_ratio", "warped_ratio"):
            ratio = np.concatenate([getattr(r, name) for r in results])[chosen]
            tracked = ratio[np.isfinite(ratio)]
            cells.append(f"{len(tracked):4d}/{chosen.sum():<4d} {np.median(tracked) if len(tracked) else float('nan'):7.4f}")
        print(f"{f'{low}-{high} m':>16s} {np.median(flow[chosen]):8.1f}px {cells[0]:>18s} {cells[1]:>18s}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
