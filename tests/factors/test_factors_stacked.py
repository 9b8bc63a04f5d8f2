"""Tests of factors.stacked (StackedFactor): several small residuals in one CustomFactor."""
from __future__ import annotations

from functools import partial

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative11

from factors import JointLoopFactor, NonHolonomicFactor, PlanarMotionFactor, joint_loop_error, nonholonomic_error, planar_motion_error, robust_noise
from factors._custom import POSE, SCALAR
from factors.stacked import StackedFactor, Term
from factors_support import assert_jacobian_close, random_pose

PLANAR_SIGMAS = np.array([0.01, 0.02, 0.05])
NH_SIGMA = 0.02
JOINT_SIGMAS = np.array([1e-3] * 3 + [1e-2] * 3)


def _values(rng):
    values = gtsam.Values()
    values.insert(0, random_pose(rng, 0.2, 2.0))
    values.insert(1, random_pose(rng, 0.2, 2.0))
    values.insert(2, random_pose(rng, 0.2, 2.0))
    values.insert(3, 0.3)
    return values


def _terms(huber_k):
    return [
        Term((0, 1), (POSE, POSE), planar_motion_error, PLANAR_SIGMAS),
        Term((0, 1), (POSE, POSE), partial(nonholonomic_error, axle_x=0.5), np.array([NH_SIGMA]), huber_k),
        Term((1, 2, 3), (POSE, POSE, SCALAR), joint_loop_error, JOINT_SIGMAS),
    ]


def _separate(huber_k):
    graph = gtsam.NonlinearFactorGraph()
    graph.add(PlanarMotionFactor(0, 1, gtsam.noiseModel.Diagonal.Sigmas(PLANAR_SIGMAS)))
    graph.add(NonHolonomicFactor(0, 1, 0.5, robust_noise(NH_SIGMA, 1, huber_k)))
    graph.add(JointLoopFactor(1, 2, 3, gtsam.noiseModel.Diagonal.Sigmas(JOINT_SIGMAS)))
    return graph


def _system(graph, values):
    ordering = gtsam.Ordering()
    for key in (0, 1, 2, 3):
        ordering.push_back(key)
    return graph.linearize(values).hessian(ordering)


def test_gaussian_terms_give_the_error_and_linear_system_of_separate_factors():
    values = _values(np.random.default_rng(1))
    stacked = StackedFactor(_terms(None))
    separate = _separate(None)
    assert stacked.keys() == [0, 1, 2, 3] and stacked.dim() == 3 + 1 + 6
    graph = gtsam.NonlinearFactorGraph()
    graph.add(stacked)
    assert graph.error(values) == pytest.approx(separate.error(values), rel=1e-10)
    information, gradient = _system(graph, values)
    expected_information, expected_gradient = _system(separate, values)
    np.testing.assert_allclose(information, expected_information, rtol=1e-9, atol=1e-9 * np.abs(expected_information).max())
    np.testing.assert_allclose(gradient, expected_gradient, rtol=1e-9, atol=1e-9 * np.abs(expected_gradient).max())


def test_huber_term_has_the_robust_cost_and_gradient_of_gtsam_huber():
    values = _values(np.random.default_rng(2))
    huber_k = 0.5  # the random poses violate the non-holonomic constraint by many sigmas
    graph = gtsam.NonlinearFactorGraph()
    graph.add(StackedFactor(_terms(huber_k)))
    separate = _separate(huber_k)
    whitened = abs(nonholonomic_error(values.atPose3(0), values.atPose3(1), 0.5)[0][0]) / NH_SIGMA
    assert whitened > huber_k
    assert graph.error(values) == pytest.approx(separate.error(values), rel=1e-10)  # 1-D: gtsam's loss is Huber too
    _, gradient = _system(graph, values)
    _, expected_gradient = _system(separate, values)
    np.testing.assert_allclose(gradient, expected_gradient, rtol=1e-9, atol=1e-9 * np.abs(expected_gradient).max())


def test_gradient_matches_numerical_derivative_of_the_error():
    values = _values(np.random.default_rng(3))
    factor = StackedFactor(_terms(1.0))
    matrix, rhs = factor.linearize(values).jacobian()
    gradient = -matrix.T @ rhs
    for position, key in enumerate((0, 1, 2)):
        def error_of(pose, key=key):
            moved = gtsam.Values(values)
            moved.update(key, pose)
            return np.array([factor.error(moved)])

        numeric = numericalDerivative11(error_of, values.atPose3(key), 1e-6)
        assert_jacobian_close(gradient[None, 6 * position:6 * position + 6], numeric, rtol=1e-4)


def test_bad_terms_are_rejected():
    with pytest.raises(ValueError):
        StackedFactor([])
    with pytest.raises(ValueError):
        StackedFactor([Term((0, 1), (POSE, POSE), planar_motion_error, np.array([0.1, -1.0, 0.1]))])
    with pytest.raises(ValueError):
        StackedFactor([Term((0, 0), (POSE, POSE), planar_motion_error, PLANAR_SIGMAS)])
    with pytest.raises(ValueError):
        StackedFactor([Term((0, 1), (POSE, POSE), planar_motion_error, PLANAR_SIGMAS), Term((1,), (SCALAR,), lambda angle, jacobians=False: (np.zeros(1), [np.zeros((1, 1))]), np.ones(1))])
    factor = StackedFactor([Term((0, 1), (POSE, POSE), planar_motion_error, np.ones(2))])  # 3 residuals, 2 sigmas
    values = _values(np.random.default_rng(4))
    with pytest.raises(ValueError, match="sigmas have 2"):
        factor.error(values)


def test_huber_rows_with_a_threshold_per_row_is_huber_row_by_row():
    """:func:`huber_rows` with one threshold per row (``inf``: Gaussian) as the stacked factor uses it."""
    from factors.epipolar import huber_rows

    whitened = np.array([0.3, -2.0, 5.0, -0.1, 40.0, -7.0])
    thresholds = np.array([1.0, 1.0, np.inf, 0.5, 2.0, np.inf])
    robust, scale = huber_rows(whitened, thresholds)
    for row, (value, threshold) in enumerate(zip(whitened, thresholds)):
        expected, expected_scale = huber_rows(whitened[row:row + 1], None if np.isinf(threshold) else threshold)
        assert robust[row] == expected[0] and scale[row] == expected_scale[0]
