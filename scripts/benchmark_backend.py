#!/usr/bin/env python
"""Backend time per keyframe (issue 5): 4 cameras, N tracks each, simulated bearings.

    python scripts/benchmark_backend.py [--sim-config configs/sim/ci_short.yaml] [--tracks 150] [--config CONFIG]

Simulates the route in memory with ``max_tracks_per_camera = --tracks``, runs the odometry and
prints the median time per keyframe of the smoother with its breakdown: factor building,
optimisation (the BatchFixedLagSmoother update) and marginals (gtsam.Marginals for the hitch
sigma), plus the front-end RANSAC share of the whole run. The tracks per camera printed are the
simulator's mean observations per frame (check: 150 each). Wall-clock times depend on the load
of the machine (printed); the backend's process CPU time per keyframe is printed as well.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

from ampc_vo.config import load_config
from ampc_vo.backend.pipeline import OdometryPipeline
from ampc_vo.sim.config import load_sim_config
from ampc_vo.sim.simulation import simulate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sim-config", type=Path, default=Path(__file__).resolve().parents[1] / "configs" / "sim" / "ci_short.yaml")
    parser.add_argument("--tracks", type=int, default=150, help="tracks per camera")
    parser.add_argument("--config", type=Path, default=None, help="VO config (default: built-in defaults)")
    parser.add_argument("--mode", default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    sim_config = dataclasses.replace(load_sim_config(args.sim_config), max_tracks_per_camera=args.tracks)
    result = simulate(sim_config)
    config = load_config(args.config)
    config = dataclasses.replace(config, output=dataclasses.replace(config.output, progress=False))
    if args.mode:
        config = config.with_mode(args.mode)
    pipeline = OdometryPipeline(result.rig, config)
    frames = [result.measurements.observations(frame, result.rig) for frame in range(result.measurements.frame_count)]
    started = time.perf_counter()
    for frame in frames:
        pipeline.process(frame)
    pipeline.finish()
    total = time.perf_counter() - started
    timings = pipeline.smoother.timings
    per_camera = {name: round(count) for name, count in result.measurements.tracks_per_camera().items()}
    backend_total = sum(t.total for t in timings)
    print(f"route {args.sim_config.name}: {len(frames)} frames, {len(timings)} smoother updates, tracks per camera {per_camera}, mode {config.mode}")
    print(f"backend per keyframe (median over {len(timings)}): {np.median([t.total for t in timings]) * 1e3:.1f} ms "
          f"(p90 {np.percentile([t.total for t in timings], 90) * 1e3:.1f} ms)")
    for name in ("factors", "optimisation", "marginals"):
        values = np.array([getattr(t, name) for t in timings]) * 1e3
        print(f"  {name:<13s} median {np.median(values):7.1f} ms   mean {np.mean(values):7.1f} ms")
    print(f"  residuals per update: median {np.median([t.residuals for t in timings]):.0f}; LM iterations per update: median {np.median([t.iterations for t in timings]):.0f}")
    print(f"backend CPU time per keyframe (its thread's CPU time, unaffected by other load): median {np.median([t.cpu for t in timings]) * 1e3:.1f} ms; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"whole run {total:.2f} s = {total / len(frames) * 1e3:.1f} ms/frame; backend {backend_total:.2f} s, "
          f"front-end RANSAC + keyframe selection {total - backend_total:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
