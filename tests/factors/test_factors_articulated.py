"""Tests of factors.articulated (ArticulatedEpipolarFactor, paper eq. (6))."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import (
    numericalDerivative41,
    numericalDerivative42,
    numericalDerivative43,
    numericalDerivative44,
)

from factors import ArticulatedEpipolarFactor, GeneralizedEpipolarFactor, articulated_epipolar_error, body_correspondences, robust_noise
from factors_support import articulated_truth, as_float, assert_jacobian_close, random_pose

SIGMA = 1.0 / 700.0


def _values(tractor_i, tractor_j, hitch_i, hitch_j):
    values = gtsam.Values()
    values.insert(0, tractor_i)
    values.insert(1, tractor_j)
    values.insert(2, float(hitch_i))
    values.insert(3, float(hitch_j))
    return values


@pytest.mark.parametrize("seed", range(6))
def test_zero_at_truth_and_equal_to_gec_on_trailer_poses(seed):
    truth = articulated_truth(np.random.default_rng(seed), pixel_noise_px=0.0)
    for group in truth.problem.on("trailer"):
        noise = robust_noise(SIGMA, len(group), None)
        factor = ArticulatedEpipolarFactor(0, 1, 2, 3, group.camera.T_body_camera, group.bearings_i, group.bearings_j, noise)
        assert np.max(np.abs(factor.unwhitenedError(_values(truth.tractor_i, truth.tractor_j, truth.hitch_i, truth.hitch_j)))) < 1e-9
        # away from the truth it equals the GEC factor on the implied trailer poses
        hitch_i, hitch_j = truth.hitch_i + 0.05, truth.hitch_j - 0.03
        trailer = GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, group.bearings_j, noise)
        trailer_values = gtsam.Values()
        trailer_values.insert(0, truth.tractor_i.compose(gtsam.Pose3(gtsam.Rot3.Rz(hitch_i), np.zeros(3))))
        trailer_values.insert(1, truth.tractor_j.compose(gtsam.Pose3(gtsam.Rot3.Rz(hitch_j), np.zeros(3))))
        np.testing.assert_allclose(
            factor.unwhitenedError(_values(truth.tractor_i, truth.tractor_j, hitch_i, hitch_j)),
            trailer.unwhitenedError(trailer_values),
            atol=1e-12,
        )


@pytest.mark.parametrize("hitch_i, hitch_j", [(0.0, 0.0), (1e-9, -1e-9), (0.3, 0.32), (-1.4, 2.0)])
def test_jacobians_match_numerical_derivatives(hitch_i, hitch_j):
    rng = np.random.default_rng(31)
    truth = articulated_truth(rng, pixel_noise_px=1.0)
    group = truth.problem.on("trailer")[0]
    correspondences = body_correspondences(group.camera.T_body_camera, group.bearings_i, group.bearings_j)
    tractor_i = random_pose(rng, 1.0, 10.0)
    tractor_j = tractor_i.compose(gtsam.Pose3(truth.problem.T_i_j))

    def residual(pose_i, pose_j, angle_i, angle_j):
        return articulated_epipolar_error(pose_i, pose_j, as_float(angle_i), as_float(angle_j), correspondences)[0]

    _, jacobians = articulated_epipolar_error(tractor_i, tractor_j, hitch_i, hitch_j, correspondences, jacobians=True)
    count = len(correspondences)
    assert [jacobian.shape for jacobian in jacobians] == [(count, 6), (count, 6), (count, 1), (count, 1)]
    derivatives = (numericalDerivative41, numericalDerivative42, numericalDerivative43, numericalDerivative44)
    for jacobian, derivative in zip(jacobians, derivatives):  # step 1e-6: O(delta^2) truncation ~1e-9
        assert_jacobian_close(jacobian, derivative(residual, tractor_i, tractor_j, hitch_i, hitch_j, delta=1e-6))


def test_linearize_shape_and_guards():
    truth = articulated_truth(np.random.default_rng(2), pixel_noise_px=1.0)
    group = truth.problem.on("trailer")[0]
    count = len(group)
    factor = ArticulatedEpipolarFactor(0, 1, 2, 3, group.camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(SIGMA, count, 1.345))
    matrix, rhs = factor.linearize(_values(truth.tractor_i, truth.tractor_j, truth.hitch_i, truth.hitch_j)).jacobian()
    assert matrix.shape == (count, 14) and rhs.shape == (count,)
    with pytest.raises(ValueError, match="distinct"):
        ArticulatedEpipolarFactor(0, 1, 2, 2, group.camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(SIGMA, count, 1.345))
    with pytest.raises(ValueError):
        ArticulatedEpipolarFactor(0, 1, 2, 3, group.camera.T_body_camera, group.bearings_i, group.bearings_j[:-1], robust_noise(SIGMA, count, 1.345))
