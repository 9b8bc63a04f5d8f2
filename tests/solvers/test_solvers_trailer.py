"""Tests of the trailer 1-point solver for both hitch angles (DESIGN 2.2)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.epipolar import gec_sampson
from ampc_vo.solvers import hitch_angles_1pt, hitch_angles_1pt_batch, positive_depth, trailer_motion_from_yaw
from ampc_vo.sim.two_view import make_two_view_problem


def test_one_point_solver_recovers_both_hitch_angles_in_1000_noise_free_trials() -> None:
    rng = np.random.default_rng(20)
    worst, counts = 0.0, []
    for _ in range(1000):
        problem = make_two_view_problem(
            rng, n_tractor_cameras=0, n_trailer_cameras=int(rng.integers(1, 3)), points_per_body=2,
            hitch_angle=(-np.deg2rad(60), np.deg2rad(60)), yaw_change=(-0.3, 0.3), chord=(0.3, 3.0),
        )
        group = problem.on("trailer")[int(rng.integers(0, len(problem.on("trailer"))))]
        solutions = hitch_angles_1pt(
            group.body_bearings_i[0], group.body_bearings_j[0], group.center, problem.yaw_change, problem.hitch_translation,
            problem.trailer_axle_x,
        )
        counts.append(len(solutions))
        errors = [max(abs(a - problem.hitch_angle_i), abs(b - problem.hitch_angle_j)) for a, b in solutions]
        worst = max(worst, np.rad2deg(min(errors, default=np.inf)))
    assert worst < 1e-6
    assert max(counts) <= 3


def test_batch_solver_matches_single_and_marks_invalid_candidates() -> None:
    problem = make_two_view_problem(np.random.default_rng(21), n_trailer_cameras=1, points_per_body=20, hitch_angle=0.4)
    bearings_i, bearings_j, center = problem.groups("trailer")[0]
    result = hitch_angles_1pt_batch(bearings_i, bearings_j, center, problem.yaw_change, problem.hitch_translation, problem.trailer_axle_x)
    assert result["valid"].shape == (20, 8)
    assert np.all(np.isnan(result["hitch_angle_i"][~result["valid"]]))
    best = np.nanmin(np.abs(result["hitch_angle_i"] - problem.hitch_angle_i), axis=1)
    assert np.all(best < 1e-8)


def test_trailer_motion_from_yaw_reproduces_the_true_trailer_motion() -> None:
    problem = make_two_view_problem(np.random.default_rng(22), hitch_angle=-0.7, yaw_change=0.1, chord=1.5)
    theta_i, theta_j, rotation, translation = trailer_motion_from_yaw(
        problem.trailer_yaw_change, 1.0, problem.yaw_change, problem.hitch_translation, problem.trailer_axle_x
    )
    assert theta_i == pytest.approx(problem.hitch_angle_i, abs=1e-12) and theta_j == pytest.approx(problem.hitch_angle_j, abs=1e-12)
    np.testing.assert_allclose(rotation, problem.T_trailer_i_j[:3, :3], atol=1e-12)
    np.testing.assert_allclose(translation, problem.T_trailer_i_j[:3, 3], atol=1e-12)


def test_positive_depth_rejects_the_mirrored_motion() -> None:
    problem = make_two_view_problem(np.random.default_rng(23), points_per_body=50, chord=1.0, yaw_change=0.02)
    bearings_i, bearings_j, center = problem.groups("tractor")[0]
    T = problem.T_i_j
    assert np.all(positive_depth(bearings_i, bearings_j, T[:3, :3], T[:3, 3], center))
    mirrored = -T[:3, 3] - (T[:3, :3] @ center - center) * 2  # baseline reversed
    assert np.mean(positive_depth(bearings_i, bearings_j, T[:3, :3], mirrored, center)) < 0.2
    # the GEC alone cannot tell: residuals of the reversed baseline are equally small
    reversed_residual = gec_sampson(bearings_i, bearings_j, T[:3, :3], mirrored, center)
    assert np.max(np.abs(reversed_residual)) < 1e-9


def test_standstill_and_untranslated_input_give_no_solution() -> None:
    bearing = np.array([0.0, 0.3, 1.0]) / np.hypot(0.3, 1.0)
    assert hitch_angles_1pt(bearing, bearing, np.array([-12.0, 0, 3]), 0.0, np.zeros(3), -8.0) == []


def test_trailer_camera_above_its_axle_still_gives_both_hitch_angles() -> None:
    """p_x = 0: the quartic has a double root at U = 0 (DESIGN 2.2); polishing keeps the true one."""
    from ampc_vo.rig import Rig, replace_camera
    from ampc_vo.sim.two_view import reference_rig

    rig = reference_rig()
    rear = rig.camera("rear")
    T = rear.T_body_camera.copy()
    T[0, 3] = rig.axle_x("trailer")
    rig = Rig(rig.bodies, (rig.camera("front"), replace_camera(rear, T_body_camera=T)))
    rng = np.random.default_rng(24)
    for _ in range(200):
        problem = make_two_view_problem(rng, rig=rig, points_per_body=2, yaw_change=(-0.2, 0.2), chord=(0.3, 2.0), hitch_angle=(-1.0, 1.0))
        group = problem.on("trailer")[0]
        solutions = hitch_angles_1pt(group.body_bearings_i[0], group.body_bearings_j[0], group.center, problem.yaw_change,
                                     problem.hitch_translation, problem.trailer_axle_x)
        errors = [max(abs(a - problem.hitch_angle_i), abs(b - problem.hitch_angle_j)) for a, b in solutions]
        assert min(errors, default=np.inf) < 1e-8
