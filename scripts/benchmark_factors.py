#!/usr/bin/env python
"""Linearisation cost per residual of the vectorised epipolar factor (issue 4, DESIGN section 3).

    PYTHONPATH=. python scripts/benchmark_factors.py [--counts 50 100 200 400] [--repeats 200]

For N correspondences of one camera between two keyframes, times ``graph.linearize(values)`` of
four graphs holding the same information, in the same run:

* ``vectorised``: one ``factors.GeneralizedEpipolarFactor`` with N Sampson residuals;
* ``per-correspondence``: N ``GeneralizedEpipolarFactor`` objects with one residual each
  (one Python ``CustomFactor`` callback per correspondence);
* ``C++ Between``: N built-in ``gtsam.BetweenFactorPose3`` (6 residuals each) on the same keys;
* ``C++ projection``: N built-in ``gtsam.GenericProjectionFactorCal3_S2`` (2 residuals each)
  with one landmark per correspondence.

Prints microseconds per linearisation and per residual (best of several batches) and the ratio
to the vectorised factor. Target: at most 2 us per residual for the vectorised factor.
"""
from __future__ import annotations

import argparse
import time
from typing import Callable

import gtsam
import numpy as np

from ampc_vo.sim.two_view import make_two_view_problem, reference_rig
from factors import GeneralizedEpipolarFactor, robust_noise

FOCAL_PX = 700.0


def _best_time_us(function: Callable[[], object], repeats: int, batches: int = 5) -> float:
    """Best-of-``batches`` mean time of ``function`` in microseconds."""
    function()  # warm-up
    best = np.inf
    for _ in range(batches):
        start = time.perf_counter()
        for _ in range(repeats):
            function()
        best = min(best, (time.perf_counter() - start) / repeats)
    return best * 1e6


def _graphs(count: int, seed: int) -> tuple[dict[str, tuple[gtsam.NonlinearFactorGraph, gtsam.Values, int]], int]:
    rng = np.random.default_rng(seed)
    problem = make_two_view_problem(rng, rig=reference_rig(FOCAL_PX), points_per_body=count, pixel_noise_px=1.0)
    group = problem.on("tractor")[0]
    count = len(group)
    camera = group.camera
    sigma = 1.0 / FOCAL_PX
    pose_i = gtsam.Pose3()
    pose_j = gtsam.Pose3(problem.T_i_j)
    poses = gtsam.Values()
    poses.insert(0, pose_i)
    poses.insert(1, pose_j)

    vectorised = gtsam.NonlinearFactorGraph()
    vectorised.add(GeneralizedEpipolarFactor(0, 1, camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(sigma, count, 1.345)))

    per_correspondence = gtsam.NonlinearFactorGraph()
    single_noise = robust_noise(sigma, 1, 1.345)
    for index in range(count):
        per_correspondence.add(
            GeneralizedEpipolarFactor(0, 1, camera.T_body_camera, group.bearings_i[index : index + 1], group.bearings_j[index : index + 1], single_noise)
        )

    between = gtsam.NonlinearFactorGraph()
    between_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.345, gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar),
        gtsam.noiseModel.Isotropic.Sigma(6, 0.01),
    )
    measured = pose_i.between(pose_j)
    for _ in range(count):
        between.add(gtsam.BetweenFactorPose3(0, 1, measured, between_noise))

    projection = gtsam.NonlinearFactorGraph()
    projection_values = gtsam.Values()
    projection_values.insert(0, pose_i.compose(gtsam.Pose3(camera.T_body_camera)))
    calibration = gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)
    pixel_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.345, gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar),
        gtsam.noiseModel.Isotropic.Sigma(2, 1.0),
    )
    pixels, _ = camera.project(group.points_i)
    for index in range(count):
        landmark = gtsam.symbol("l", index)
        projection_values.insert(landmark, group.points_i[index])
        projection.add(gtsam.GenericProjectionFactorCal3_S2(pixels[index], pixel_noise, 0, landmark, calibration))

    return {
        "vectorised": (vectorised, poses, count),
        "per-correspondence": (per_correspondence, poses, count),
        "C++ Between": (between, poses, 6 * count),
        "C++ projection": (projection, projection_values, 2 * count),
    }, count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", type=int, nargs="+", default=[50, 100, 200, 400], help="correspondences per factor")
    parser.add_argument("--repeats", type=int, default=200, help="linearisations per timing batch")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    print(f"{'N':>5} {'graph':<20} {'us/linearize':>13} {'us/residual':>12} {'x vectorised':>13}")
    for requested in args.counts:
        graphs, count = _graphs(requested, args.seed)
        per_residual = {}
        for name, (graph, values, residuals) in graphs.items():
            repeats = max(5, args.repeats // (count if name == "per-correspondence" else 1))
            total = _best_time_us(lambda graph=graph, values=values: graph.linearize(values), repeats)
            per_residual[name] = total / residuals
            ratio = per_residual[name] / per_residual["vectorised"]
            print(f"{count:>5} {name:<20} {total:>13.1f} {per_residual[name]:>12.3f} {ratio:>13.2f}")
        verdict = "meets" if per_residual["vectorised"] <= 2.0 else "misses"
        print(f"      vectorised {per_residual['vectorised']:.3f} us/residual {verdict} the 2 us target; "
              f"per-correspondence is {per_residual['per-correspondence'] / per_residual['vectorised']:.0f}x slower")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
