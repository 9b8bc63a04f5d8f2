#!/usr/bin/env python
"""Stereo PnP VO (the peer baseline) on a KITTI odometry folder, evaluated with evo.

    python scripts/kitti_baseline.py [KITTI_FOLDER] [--out OUT]

Prints ATE (SE(3) and Sim(3) alignment), RPE over 10 m segments (percent) and frame-to-frame RPE,
both for the body frame and for KITTI's left-camera frame, and the time per frame. With ``--out``
writes ``baseline_tractor.tum`` and ``baseline_metrics.json``. Default folder: ../shared/data/kitti-clip.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

import numpy as np  # noqa: E402
from evo.core import metrics  # noqa: E402

from ampc_vo.tools.baseline import StereoPnpConfig, stereo_pnp_odometry  # noqa: E402
from ampc_vo.io.kitti import load_kitti  # noqa: E402
from ampc_vo.errors import AmpcError  # noqa: E402
from ampc_vo.tools.cli import exit_codes  # noqa: E402
from ampc_vo.io.groundtruth import GroundTruth  # noqa: E402
from ampc_vo.tools.evaluation import _evo_trajectory, evaluate
from ampc_vo.io.outputs import Trajectory, write_tum  # noqa: E402

DEFAULT_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti-clip"


def frame_to_frame_rpe(truth: np.ndarray, estimate: np.ndarray, timestamps: np.ndarray) -> tuple[float, float]:
    """RMSE of the frame-to-frame relative pose error: translation (m) and rotation (deg), with evo."""
    reference, estimated = _evo_trajectory(timestamps, truth), _evo_trajectory(timestamps, estimate)
    translation = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames)
    translation.process_data((reference, estimated))
    rotation = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, delta=1, delta_unit=metrics.Unit.frames)
    rotation.process_data((reference, estimated))
    return float(translation.get_statistic(metrics.StatisticsType.rmse)), float(rotation.get_statistic(metrics.StatisticsType.rmse))


@exit_codes
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path, nargs="?", default=DEFAULT_CLIP, help="KITTI odometry folder")
    parser.add_argument("--out", type=Path, help="folder for baseline_tractor.tum and baseline_metrics.json")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    dataset = load_kitti(args.dataset)
    if dataset.truth is None:
        raise AmpcError(f"{args.dataset}: no poses.txt, nothing to evaluate against")
    start = time.perf_counter()
    result = stereo_pnp_odometry(dataset.rig, ((dataset.timestamps[k], dataset.images(k)) for k in range(len(dataset))), StereoPnpConfig())
    seconds = time.perf_counter() - start
    estimate = Trajectory(result.timestamps, result.T_world_body)
    # dataset.truth compares in KITTI's left-camera frame (T_tractor_reference); the body frame too
    body_truth = GroundTruth(dataset.timestamps, dataset.T_world_tractor)
    body = evaluate(body_truth, estimate, seconds_per_frame=seconds / len(dataset)).metrics
    camera = evaluate(dataset.truth, estimate).metrics
    rpe_m, rpe_deg = frame_to_frame_rpe(dataset.T_world_tractor, result.T_world_body, dataset.timestamps)
    summary = {
        "frames": len(dataset),
        "distance_m": body.distance_m,
        "ate_se3_m": body.tractor_ate_m,
        "ate_sim3_m": body.tractor_ate_sim3_m,
        "sim3_scale": body.sim3_scale,
        "rpe_10m_percent": body.tractor_rpe_percent,
        "rpe_frame_m": rpe_m,
        "rpe_frame_deg": rpe_deg,
        "left_camera_ate_se3_m": camera.tractor_ate_m,
        "left_camera_rpe_10m_percent": camera.tractor_rpe_percent,
        "pnp_failures": len(result.failed_frames),
        "median_pnp_inliers": float(np.median(result.inliers[1:])) if len(result.inliers) > 1 else 0.0,
        "ms_per_frame": 1e3 * seconds / len(dataset),
    }
    print(f"stereo PnP baseline on {args.dataset} ({len(dataset)} frames, {body.distance_m:.1f} m)")
    for key, value in summary.items():
        print(f"  {key:<28s} {value:.4g}" if isinstance(value, float) else f"  {key:<28s} {value}")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        write_tum(args.out / "baseline_tractor.tum", estimate)
        (args.out / "baseline_metrics.json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
