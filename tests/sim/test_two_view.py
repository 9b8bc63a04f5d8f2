"""Tests of the synthetic two-view generator (ampc_vo.sim.two_view) against DESIGN 2 and paper eqs. (3)-(5)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.epipolar import gec_sampson
from ampc_vo.geometry import rot_z, unit_heading, unit_normal
from ampc_vo.sim.two_view import ackermann_translation, articulated_motion, make_two_view_problem, random_rig, reference_rig, trailer_yaw_change


def _axle_displacement(T_i_j: np.ndarray, axle_x: float) -> np.ndarray:
    axle = np.array([axle_x, 0.0, 0.0])
    return T_i_j[:3, :3] @ axle + T_i_j[:3, 3] - axle


def test_ackermann_translation_moves_the_axle_along_the_half_angle_chord() -> None:
    yaw, chord, axle_x = 0.3, 1.7, 0.8
    translation = ackermann_translation(yaw, chord, axle_x)
    displacement = rot_z(yaw) @ np.array([axle_x, 0, 0]) + translation - np.array([axle_x, 0, 0])
    np.testing.assert_allclose(displacement, chord * unit_heading(yaw / 2), atol=1e-12)


def test_articulated_motion_satisfies_both_nonholonomic_constraints_and_joint_loop() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        yaw, chord, theta = rng.uniform(-0.3, 0.3), rng.uniform(-2, 3), rng.uniform(-1.0, 1.0)
        tractor_axle, trailer_axle = rng.uniform(0, 1), rng.uniform(-10, -6)
        motion = articulated_motion(yaw, chord, theta, tractor_axle, trailer_axle)
        T, T_b = motion["T_i_j"], motion["T_trailer_i_j"]
        theta_j, psi = motion["hitch_angle_j"], motion["trailer_yaw_change"]
        # (NH) at both axles: displacement along u(yaw/2)
        assert abs(unit_normal(yaw / 2) @ _axle_displacement(T, tractor_axle)) < 1e-12
        assert abs(unit_normal(psi / 2) @ _axle_displacement(T_b, trailer_axle)) < 1e-12
        assert motion["trailer_chord"] * unit_heading(psi / 2) == pytest.approx(_axle_displacement(T_b, trailer_axle), abs=1e-12)
        # paper eqs. (3)-(5)
        Q, Q_j = rot_z(theta), rot_z(theta_j)
        np.testing.assert_allclose(T_b[:3, :3], Q.T @ T[:3, :3] @ Q_j, atol=1e-12)
        np.testing.assert_allclose(T_b[:3, 3], Q.T @ T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(T_b[:3, :3].T @ T_b[:3, 3], Q_j.T @ T[:3, :3].T @ T[:3, 3], atol=1e-12)
        assert psi == pytest.approx(trailer_yaw_change(theta, T[:3, 3], trailer_axle))
        assert psi == pytest.approx(yaw + theta_j - theta)


def test_noise_free_correspondences_satisfy_the_gec_and_lie_in_front_of_the_cameras() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        problem = make_two_view_problem(rng, n_tractor_cameras=2, n_trailer_cameras=2, outlier_fraction=0.2, points_per_body=60)
        assert len(problem.on("tractor")) == 2 and len(problem.on("trailer")) == 2
        for group in problem.correspondences:
            T = problem.T_i_j if group.body == "tractor" else problem.T_trailer_i_j
            residual = gec_sampson(group.body_bearings_i, group.body_bearings_j, T[:3, :3], T[:3, 3], group.center)
            assert np.max(np.abs(residual[group.inliers])) < 1e-10
            assert np.median(np.abs(residual[~group.inliers])) > 1e-3  # outliers are really wrong
            assert np.sum(~group.inliers) == round(0.2 * len(group))
            np.testing.assert_allclose(np.linalg.norm(group.bearings_i, axis=1), 1.0, atol=1e-12)
            np.testing.assert_allclose(group.body_bearings_j, group.bearings_j @ group.camera.R_body_camera.T, atol=1e-12)
            assert np.all(group.points_i[:, 2] > 0.0)
            distance = np.linalg.norm(group.points_i, axis=1)
            assert np.all((distance >= 3.0 - 1e-9) & (distance <= 40.0 + 1e-9))
            _, visible = group.camera.project(group.points_i)
            assert np.all(visible)
        assert sum(len(g) for g in problem.on("tractor")) == 60


def test_pixel_noise_gives_residuals_of_the_expected_size() -> None:
    rng = np.random.default_rng(3)
    problem = make_two_view_problem(rng, rig=reference_rig(), pixel_noise_px=1.0, points_per_body=400)
    group = problem.on("tractor")[0]
    residual = gec_sampson(group.body_bearings_i, group.body_bearings_j, problem.T_i_j[:3, :3], problem.T_i_j[:3, 3], group.center)
    sigma_px = 700.0 * np.std(residual)
    assert 0.6 < sigma_px < 1.6  # Sampson residual ~ angular error, sigma ~ noise / focal


def test_random_rigs_keep_cameras_off_the_axle_and_are_reproducible() -> None:
    for seed in range(30):
        rig = random_rig(np.random.default_rng(seed), n_tractor_cameras=3, n_trailer_cameras=2)
        for camera in rig.cameras:
            assert abs(camera.center[0] - rig.axle_x(camera.body)) >= 0.5 - 1e-12
        assert rig.axle_x("trailer") < 0 and len(rig.cameras_on("tractor")) == 3
    a = make_two_view_problem(np.random.default_rng(7), pixel_noise_px=1.0)
    b = make_two_view_problem(np.random.default_rng(7), pixel_noise_px=1.0)
    np.testing.assert_array_equal(a.correspondences[0].bearings_j, b.correspondences[0].bearings_j)
    assert a.hitch_angle_j == b.hitch_angle_j


def test_fixed_parameters_and_reference_rig() -> None:
    rig = reference_rig()
    assert rig.axle_x("trailer") == -8.0 and rig.camera("rear").center[0] == -12.5
    problem = make_two_view_problem(np.random.default_rng(4), rig=rig, yaw_change=0.05, chord=1.0, hitch_angle=0.3)
    assert (problem.yaw_change, problem.chord, problem.hitch_angle_i) == (0.05, 1.0, 0.3)
    bearings_i, bearings_j, center = problem.groups("trailer")[0]
    assert bearings_i.shape == (100, 3) and np.array_equal(center, rig.camera("rear").center)
