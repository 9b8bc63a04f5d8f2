#!/usr/bin/env python
"""Benchmark: our tractor RANSAC (2-point Ackermann) vs poselib's generalized relative pose.

Both estimators get the same simulated correspondences (ampc_vo.sim.two_view): Ackermann motion of a
tractor with a front and a side camera (non-overlapping, intra-camera matches), 1 px noise, 700 px
focal, 10% outliers. Prints time per call, rotation error, translation-direction error and scale
error for both, the time ratio, and the per-solver microseconds of the minimal solvers.

    PYTHONPATH=. python scripts/benchmark_solvers.py [--trials 60] [--seed 0]

poselib (``pip install poselib``, the ``bench`` extra) is optional; without it only our numbers
are printed.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from ampc_vo.geometry import invert_pose, rotation_angle
from ampc_vo.solvers import (
    RansacConfig,
    SolverStatus,
    estimate_hitch_angles,
    estimate_tractor_motion,
    hitch_angles_1pt,
    hitch_angles_1pt_batch,
    refine_joint,
    tractor_motion_2pt,
    tractor_motion_2pt_batch,
)
from ampc_vo.sim.two_view import TwoViewProblem, make_two_view_problem, random_rig, reference_rig

try:
    import poselib
except ImportError:  # optional dependency
    poselib = None


def _clock() -> float:
    """CPU time of this process (both estimators are single-threaded): less sensitive than wall
    time to other processes on a shared machine."""
    return time.process_time()


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    cosine = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def _errors(T_est: np.ndarray | None, T_true: np.ndarray) -> tuple[float, float, float]:
    """Rotation error (deg), translation direction error (deg), scale error (m, | |t| - |t_true| |)."""
    if T_est is None or not np.all(np.isfinite(T_est)):
        return float("nan"), float("nan"), float("nan")
    rotation = np.degrees(rotation_angle(T_est[:3, :3].T @ T_true[:3, :3]))
    direction = _angle_between(T_est[:3, 3], T_true[:3, 3])
    scale = abs(np.linalg.norm(T_est[:3, 3]) - np.linalg.norm(T_true[:3, 3]))
    return rotation, direction, scale


def _poselib_inputs(problem: TwoViewProblem):
    """Pixels, intrinsics and extrinsics of the tractor cameras in poselib's conventions
    (``CameraPose`` maps rig to camera: ``x_cam = R x_rig + t``)."""
    matches, extrinsics, cameras = [], [], []
    for index, group in enumerate(problem.on("tractor")):
        camera = group.camera
        cameras.append(poselib.Camera("PINHOLE", [camera.fx, camera.fy, camera.cx, camera.cy], camera.width, camera.height))
        T_camera_body = invert_pose(camera.T_body_camera)
        extrinsic = poselib.CameraPose()
        extrinsic.R, extrinsic.t = T_camera_body[:3, :3], T_camera_body[:3, 3]
        extrinsics.append(extrinsic)
        match = poselib.PairwiseMatches()
        match.cam_id1 = match.cam_id2 = index
        match.x1 = group.bearings_i[:, :2] / group.bearings_i[:, 2:] * camera.fx + np.array([camera.cx, camera.cy])
        match.x2 = group.bearings_j[:, :2] / group.bearings_j[:, 2:] * camera.fx + np.array([camera.cx, camera.cy])
        matches.append(match)
    return matches, extrinsics, cameras


def _run_poselib(problem: TwoViewProblem, ransac_options: dict) -> tuple[np.ndarray, float]:
    matches, extrinsics, cameras = _poselib_inputs(problem)
    start = _clock()
    pose, _ = poselib.estimate_generalized_relative_pose(matches, extrinsics, cameras, extrinsics, cameras, ransac_options, {})
    elapsed = _clock() - start
    T_j_i = np.eye(4)  # poselib maps rig 1 to rig 2: x_2 = R x_1 + t, the inverse of our T_i_j
    T_j_i[:3, :3], T_j_i[:3, 3] = pose.R, pose.t
    return invert_pose(T_j_i), elapsed


def _summary(name: str, times: list[float], errors: list[tuple[float, float, float]]) -> float:
    errors_array = np.array(errors)
    failed = int(np.sum(np.isnan(errors_array[:, 0])))
    stats = []
    for column in range(3):
        values = errors_array[:, column]
        values = values[np.isfinite(values)]
        stats += [np.median(values), np.percentile(values, 90)] if values.size else [np.nan, np.nan]
    mean_ms = 1e3 * float(np.mean(times))
    print(f"{name:<28s} {mean_ms:8.2f} ms   rot {stats[0]:.4f}/{stats[1]:.4f} deg   dir {stats[2]:.3f}/{stats[3]:.3f} deg   "
          f"scale {stats[4]:.4f}/{stats[5]:.4f} m   failed {failed}")
    return mean_ms


def _microseconds(function, repeats: int) -> float:
    start = _clock()
    for _ in range(repeats):
        function()
    return 1e6 * (_clock() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    rig = random_rig(rng, n_tractor_cameras=2, n_trailer_cameras=1)
    threshold = 0.004  # rad, ~2.8 px at 700 px
    config = RansacConfig(sampson_threshold=threshold)
    poselib_default = {"max_epipolar_error": threshold * 700.0}
    poselib_fast = {"max_epipolar_error": threshold * 700.0, "min_iterations": 50}

    fast_config = RansacConfig(sampson_threshold=threshold, local_optimizations=1, chord_seeds=(), refine_rounds=2)
    ours_times, ours_errors, statuses = [], [], []
    fast_times, fast_errors = [], []
    pl_times, pl_errors, plf_times, plf_errors = [], [], [], []
    problems = []
    for _ in range(args.trials):
        yaw = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.1))  # Ackermann turns of 1.7-5.7 deg per metre
        problem = make_two_view_problem(rng, rig=rig, yaw_change=yaw, chord=1.0, points_per_body=100, pixel_noise_px=1.0,
                                        outlier_fraction=0.1, hitch_angle=(-0.7, 0.7))
        problems.append(problem)
        start = _clock()
        estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, config)
        ours_times.append(_clock() - start)
        statuses.append(estimate.status)
        ours_errors.append(_errors(estimate.T_i_j, problem.T_i_j))
        start = _clock()
        estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, fast_config)
        fast_times.append(_clock() - start)
        fast_errors.append(_errors(estimate.T_i_j, problem.T_i_j))
        if poselib is not None:
            T, elapsed = _run_poselib(problem, poselib_default)
            pl_times.append(elapsed)
            pl_errors.append(_errors(T, problem.T_i_j))
            T, elapsed = _run_poselib(problem, poselib_fast)
            plf_times.append(elapsed)
            plf_errors.append(_errors(T, problem.T_i_j))

    print(f"Tractor motion, {args.trials} trials: 2 cameras (front+side), 100 points, 1 px noise, 700 px focal, 10% outliers, "
          f"Ackermann |yaw| 1.7-5.7 deg, chord 1 m")
    print("errors as median/p90; times are CPU ms per call")
    ours_ms = _summary("ours (2-pt Ackermann RANSAC)", ours_times, ours_errors)
    print(f"  statuses: { {s.value: statuses.count(s) for s in set(statuses)} }")
    fast_ms = _summary("ours, no LO seeds (fast)", fast_times, fast_errors)
    if poselib is not None:
        pl_ms = _summary("poselib gen. relpose default", pl_times, pl_errors)
        plf_ms = _summary("poselib min_iterations=50", plf_times, plf_errors)
        print(f"time ratio poselib(default)/ours = {pl_ms / ours_ms:.2f}x; poselib(min_iterations=50)/ours = {plf_ms / ours_ms:.2f}x; "
              f"poselib(default)/ours-fast = {pl_ms / fast_ms:.2f}x; poselib(min_iterations=50)/ours-fast = {plf_ms / fast_ms:.2f}x")
    else:
        print("poselib not installed: pip install poselib")

    # trailer, DESIGN 2.3: reference rig (s_B = 8 m, rear camera 12.5 m behind the hitch)
    reference = reference_rig()
    hitch_times, hitch_errors, joint_errors = [], [], {True: [], False: []}
    for trial in range(args.trials):
        problem = make_two_view_problem(rng, rig=reference, yaw_change=(-0.1, 0.1), chord=1.0, points_per_body=100, pixel_noise_px=1.0,
                                        outlier_fraction=0.1, hitch_angle=(-0.8, 0.8))
        start = _clock()
        hitch = estimate_hitch_angles(problem.groups("trailer"), (problem.yaw_change, problem.hitch_translation), problem.trailer_axle_x, config)
        hitch_times.append(_clock() - start)
        hitch_errors.append(np.degrees([hitch.hitch_angle_i - problem.hitch_angle_i, hitch.hitch_angle_j - problem.hitch_angle_j]))
        tractor = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, config)
        if tractor.status is not SolverStatus.OK:
            continue
        hitch = estimate_hitch_angles(problem.groups("trailer"), (tractor.yaw_change, tractor.translation), problem.trailer_axle_x, config)
        for nonholonomic in (True, False):
            joint = refine_joint(problem.groups("tractor"), problem.groups("trailer"), tractor, hitch, problem.tractor_axle_x,
                                 problem.trailer_axle_x, config, trailer_nonholonomic=nonholonomic)
            joint_errors[nonholonomic].append([np.degrees(abs(joint.hitch_angle_i - problem.hitch_angle_i)), abs(joint.chord - problem.chord),
                                               np.degrees(abs(joint.yaw_change - problem.yaw_change))])
    hitch_errors = np.abs(np.array(hitch_errors))
    print(f"trailer 1-pt RANSAC + refinement, front motion known (DESIGN 2.3, {args.trials} trials): {1e3 * np.mean(hitch_times):.2f} ms; "
          f"theta error median {np.nanmedian(hitch_errors[:, 0]):.3f} deg, p90 {np.nanpercentile(hitch_errors[:, 0], 90):.3f} deg; "
          f"theta' median {np.nanmedian(hitch_errors[:, 1]):.3f}, p90 {np.nanpercentile(hitch_errors[:, 1], 90):.3f} deg")
    for nonholonomic in (True, False):
        errors = np.array(joint_errors[nonholonomic])
        label = "with trailer NH (phi, rho, psi)" if nonholonomic else "without (phi, rho, theta, theta')"
        print(f"joint refinement {label:<34s} ({len(errors)} trials, front from RANSAC): theta median {np.median(errors[:, 0]):.3f} deg, "
              f"chord median {np.median(errors[:, 1]):.4f} m, yaw median {np.median(errors[:, 2]):.4f} deg")

    # minimal solvers
    problem = problems[0]
    group = problem.on("tractor")[0]
    bearings_i, bearings_j = group.body_bearings_i[:2], group.body_bearings_j[:2]
    centers = np.broadcast_to(group.center, (2, 3))
    batch = 1000
    sample = rng.integers(0, len(group), (batch, 2))
    b_i, b_j, b_c = group.body_bearings_i[sample], group.body_bearings_j[sample], np.broadcast_to(group.center, (batch, 2, 3))
    trailer = problem.on("trailer")[0]
    t = problem.hitch_translation
    index = rng.integers(0, len(trailer), batch)
    print("minimal solvers (microseconds per sample):")
    print(f"  tractor 2-pt single call  {_microseconds(lambda: tractor_motion_2pt(bearings_i, bearings_j, centers, problem.tractor_axle_x), 2000):8.1f}")
    batched = _microseconds(lambda: tractor_motion_2pt_batch(b_i, b_j, b_c, problem.tractor_axle_x), 20) / batch
    print(f"  tractor 2-pt batched      {batched:8.2f}")
    print(f"  trailer 1-pt single call  {_microseconds(lambda: hitch_angles_1pt(trailer.body_bearings_i[0], trailer.body_bearings_j[0], trailer.center, problem.yaw_change, t, problem.trailer_axle_x), 1000):8.1f}")
    batched = _microseconds(lambda: hitch_angles_1pt_batch(trailer.body_bearings_i[index], trailer.body_bearings_j[index], trailer.center, problem.yaw_change, t, problem.trailer_axle_x), 10) / batch
    print(f"  trailer 1-pt batched      {batched:8.2f}")
    if poselib is not None:
        groups = problem.on("tractor")
        p = np.concatenate([np.broadcast_to(g.center, (3, 3)) for g in groups])
        x1 = np.concatenate([g.body_bearings_i[:3] for g in groups])
        x2 = np.concatenate([g.body_bearings_j[:3] for g in groups])
        print(f"  poselib gen_relpose_6pt   {_microseconds(lambda: poselib.gen_relpose_6pt(p, x1, p, x2), 300):8.1f}")
        print(f"  poselib gen_relpose_upright_4pt {_microseconds(lambda: poselib.gen_relpose_upright_4pt(p[:4], x1[:4], p[:4], x2[:4]), 1000):8.1f}")


if __name__ == "__main__":
    main()
