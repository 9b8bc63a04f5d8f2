#!/usr/bin/env python3
"""Measure KLT survival on rendered images of a simulated route (issue 6 acceptance).

For every ``--step``-th pair of consecutive frames and every camera: GFTT features on the first image,
OpenCV pyramidal LK forward and backward with the frontend's ``TrackerConfig`` LK settings (window,
pyramid levels, criteria; override with ``--lk-window`` / ``--lk-levels``), survival = forward-backward
error <= 0.5 px. Only features whose true next position (depth buffer + ground-truth poses) stays inside
the image and unoccluded are counted (``ampc_vo.tools.klt_survival``). Prints survival per camera and per
segment (straight / turn, by the yaw change of the camera's body), pooled.

    PYTHONPATH=. python scripts/measure_klt_survival.py --config configs/sim/demo.yaml [--step 5]
        [--lk-window 15] [--lk-levels 4] [--first 0] [--last -1] [--cameras front rear]
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the renderer's products are tiny: threads only add overhead

import numpy as np  # noqa: E402

REPOSITORY_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPOSITORY_ROOT))

from ampc_vo.config import TrackerConfig  # noqa: E402
from ampc_vo.sim.kinematics import simulate_kinematics  # noqa: E402
from ampc_vo.tools.klt_survival import SEGMENTS, SurvivalSettings, measure_route, summarise  # noqa: E402
from ampc_vo.sim.render import Renderer, render_options_from_dict  # noqa: E402
from ampc_vo.sim.scene import build_scene  # noqa: E402
from ampc_vo.sim.config import load_sim_config  # noqa: E402


def _cell(counts: tuple[int, int] | None) -> str:
    if not counts or counts[1] == 0:
        return f"{'-':>16s}"
    survived, counted = counts
    return f"{100.0 * survived / counted:6.1f}% ({counted:5d})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPOSITORY_ROOT / "configs" / "sim" / "demo.yaml"))
    parser.add_argument("--step", type=int, default=5, help="use every STEP-th frame pair (1: all pairs)")
    parser.add_argument("--first", type=int, default=0, help="first frame of the first pair")
    parser.add_argument("--last", type=int, default=-1, help="last first-frame of a pair (-1: up to the end)")
    parser.add_argument("--lk-window", type=int, default=None, help="LK window (default: TrackerConfig)")
    parser.add_argument("--lk-levels", type=int, default=None, help="LK pyramid levels (default: TrackerConfig)")
    parser.add_argument("--cameras", nargs="*", default=None, help="camera names (default: all)")
    args = parser.parse_args()

    config = load_sim_config(args.config)
    rig = config.load_rig()
    trajectory = simulate_kinematics(config.route, config.rate_hz, rig.axle_x("tractor"), rig.axle_x("trailer"),
                                     config.initial_hitch_angle, config.duration)
    scene = build_scene(trajectory, np.random.default_rng(config.seed), config.scene)
    # Clean images (no sensor noise, exposure change or blur): the check is about the renderer's geometry and texture.
    renderer = Renderer(scene, None, render_options_from_dict(None))
    tracker = TrackerConfig()
    overrides = {name: value for name, value in (("lk_window", args.lk_window), ("lk_levels", args.lk_levels)) if value is not None}
    tracker = dataclasses.replace(tracker, **overrides)
    settings = SurvivalSettings()
    last = len(trajectory) - 2 if args.last < 0 else min(args.last, len(trajectory) - 2)
    frames = list(range(max(args.first, 0), last + 1, max(args.step, 1)))

    started = time.perf_counter()
    results = measure_route(renderer, rig, trajectory, frames, tracker, settings, args.cameras)
    elapsed = time.perf_counter() - started
    table = summarise(results)

    print(f"{config.source}: {len(frames)} frame pairs (every {args.step}, frames {frames[0]}..{frames[-1] + 1}) x "
          f"{len({r.camera for r in results})} cameras; LK window {tracker.lk_window}, levels {tracker.lk_levels}, "
          f"criteria ({tracker.lk_iterations}, {tracker.lk_epsilon}); GFTT {settings.max_features} corners; "
          f"FB error <= {settings.fb_threshold_px} px; {elapsed:.0f} s")
    camera_pairs = {segment: sum(r.segment == segment for r in results) for segment in SEGMENTS}
    print(f"camera frame pairs per segment (turn: yaw change of the camera's body > {settings.turn_threshold_deg} deg "
          f"per pair): {camera_pairs}")
    print(f"{'camera':8s}" + "".join(f"{name:>18s}" for name in (*SEGMENTS, "all")) + "   (survival, counted features)")
    for camera in [c.name for c in rig.cameras if c.name in table] + ["all"]:
        print(f"{camera:8s}" + "".join(f"  {_cell(table[camera].get(segment))}" for segment in (*SEGMENTS, "all")))
    left = sum(r.left_image for r in results)
    occluded = sum(r.occluded for r in results)
    detected = sum(r.detected for r in results)
    errors = np.concatenate([r.tracking_error_px[r.survives] for r in results] or [np.zeros(0)])
    worst = min(results, key=lambda r: r.survival if r.counted else 1.0)
    print(f"excluded from the denominator: {left} of {detected} features leave the image, {occluded} become occluded")
    print(f"surviving features: median distance from the true position {np.median(errors):.2f} px, "
          f"p90 {np.percentile(errors, 90):.2f} px")
    print(f"worst pair: {worst.camera} frame {worst.frame} ({worst.segment}) {100 * worst.survival:.1f}% of {worst.counted}")
    survived, counted = table["all"]["all"]
    return 0 if counted and survived / counted >= 0.8 else 1


if __name__ == "__main__":
    sys.exit(main())
