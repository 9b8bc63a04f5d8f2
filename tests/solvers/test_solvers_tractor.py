"""Tests of the tractor 2-point Ackermann solver and the scale-free 1-point solver (DESIGN 2.1)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.errors import BearingError
from ampc_vo.epipolar import gec_algebraic
from ampc_vo.geometry import rot_z
from ampc_vo.solvers import ackermann_motion, tractor_motion_2pt, tractor_yaw_1pt
from ampc_vo.solvers.tractor import _quadratic_roots, arc_coefficients
from ampc_vo.sim.two_view import ackermann_translation, make_two_view_problem


def _two_points(problem):
    groups = problem.on("tractor")
    bearings_i = np.concatenate([g.body_bearings_i for g in groups])
    bearings_j = np.concatenate([g.body_bearings_j for g in groups])
    centers = np.concatenate([np.broadcast_to(g.center, (len(g), 3)) for g in groups])
    return bearings_i, bearings_j, centers


def test_two_point_solver_recovers_the_true_motion_in_1000_noise_free_trials() -> None:
    rng = np.random.default_rng(10)
    worst, two_cameras = 0.0, 0
    for _ in range(1000):
        cameras = int(rng.integers(1, 3))  # the two points from one camera or from two cameras
        two_cameras += cameras == 2
        problem = make_two_view_problem(
            rng, n_tractor_cameras=cameras, n_trailer_cameras=0, points_per_body=2, yaw_change=(-0.3, 0.3), chord=(-2.0, 3.0),
        )
        solutions = tractor_motion_2pt(*_two_points(problem), problem.tractor_axle_x)
        assert 1 <= len(solutions) <= 2
        errors = [max(np.rad2deg(abs(yaw - problem.yaw_change)), abs(chord - problem.chord)) for yaw, chord in solutions]
        worst = max(worst, min(errors))
    assert worst < 1e-6
    assert 300 < two_cameras < 700


def test_ackermann_motion_matches_the_generator_and_broadcasts() -> None:
    yaw, chord = np.array([0.1, -0.2]), np.array([1.0, 2.0])
    rotation, translation = ackermann_motion(yaw, chord, 0.7)
    assert rotation.shape == (2, 3, 3) and translation.shape == (2, 3)
    for k in range(2):
        np.testing.assert_allclose(rotation[k], rot_z(yaw[k]), atol=1e-15)
        np.testing.assert_allclose(translation[k], ackermann_translation(yaw[k], chord[k], 0.7), atol=1e-15)


def test_arc_coefficients_reduce_the_gec_to_the_design_form() -> None:
    """(rho - 2 sin(phi/2) p_y) U + 2 sin(phi/2) p_x N equals the algebraic GEC (DESIGN 2.1)."""
    rng = np.random.default_rng(11)
    f, g = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    yaw, chord, axle_x, center = 0.4, 1.3, 0.6, np.array([3.0, -0.7, 2.0])
    rotation, translation = ackermann_motion(yaw, chord, axle_x)
    u_c, u_s, n_c, n_s = arc_coefficients(f, g)
    c, s = np.cos(yaw / 2), np.sin(yaw / 2)
    p = center - np.array([axle_x, 0, 0])
    design = (chord - 2 * s * p[1]) * (c * u_c - s * u_s) + 2 * s * p[0] * (c * n_c - s * n_s)
    np.testing.assert_allclose(design, gec_algebraic(f, g, rotation, translation, center), atol=1e-12)


def test_quadratic_with_vanishing_leading_coefficient_keeps_the_linear_root() -> None:
    roots = _quadratic_roots(np.array([0.0, 1.0, 1.0]), np.array([2.0, -3.0, 0.0]), np.array([-1.0, 2.0, 1.0]))
    assert np.isnan(roots[0, 0]) and roots[0, 1] == pytest.approx(0.5)
    assert sorted(roots[1]) == pytest.approx([1.0, 2.0])
    assert np.all(np.isnan(roots[2]))  # x^2 + 1: no real root


def test_straight_motion_leaves_the_chord_undetermined_and_returns_nothing_wrong() -> None:
    problem = make_two_view_problem(np.random.default_rng(12), n_trailer_cameras=0, points_per_body=2, yaw_change=0.0, chord=1.0)
    for yaw, chord in tractor_motion_2pt(*_two_points(problem), problem.tractor_axle_x):
        assert np.isfinite(chord)
        assert abs(yaw) > 1e-6  # the true straight root (chord undetermined) is not returned with a made-up chord


def test_scale_free_one_point_solver_for_a_camera_above_the_axle() -> None:
    rng = np.random.default_rng(13)
    axle_x, center = 0.5, np.array([0.5, 0.8, 2.0])  # p_x = 0
    for _ in range(200):
        yaw, chord = rng.uniform(-0.3, 0.3), rng.uniform(0.3, 3.0)
        rotation, translation = ackermann_motion(yaw, chord, axle_x)
        point = center + rng.uniform(-20, 20, 3) + np.array([0, 0, 0])
        bearing_i = point - center
        bearing_j = rotation.T @ (point - translation) - center
        bearing_i, bearing_j = bearing_i / np.linalg.norm(bearing_i), bearing_j / np.linalg.norm(bearing_j)
        solved = tractor_yaw_1pt(bearing_i, bearing_j)
        assert solved is not None and abs(solved - yaw) < 1e-8
    assert tractor_yaw_1pt(np.array([0, 0, 1.0]), np.array([0, 0, 1.0])) is None  # no parallax: undefined


def test_bad_bearings_raise_a_clear_error() -> None:
    with pytest.raises(BearingError):
        tractor_motion_2pt(np.full((2, 3), np.nan), np.ones((2, 3)), np.zeros((2, 3)), 0.5)
    with pytest.raises(BearingError):
        tractor_motion_2pt(np.ones((3, 3)), np.ones((3, 3)), np.zeros((2, 3)), 0.5)
