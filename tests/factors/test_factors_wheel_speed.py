"""Tests of factors.wheel_speed (WheelSpeedFactor)."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

from ampc_vo.geometry import make_pose, rot_z
from factors import WheelSpeedFactor, chord_error
from factors_support import articulated_truth, assert_jacobian_close, random_pose

NOISE = gtsam.noiseModel.Isotropic.Sigma(1, 0.05)


@pytest.mark.parametrize("seed", range(6))
def test_zero_error_at_ground_truth(seed):
    truth = articulated_truth(np.random.default_rng(seed))
    problem = truth.problem
    values = gtsam.Values()
    values.insert(0, truth.tractor_i)
    values.insert(1, truth.tractor_j)
    factor = WheelSpeedFactor(0, 1, problem.tractor_axle_x, problem.chord, NOISE)
    assert abs(factor.unwhitenedError(values)[0]) < 1e-12
    longer = WheelSpeedFactor(0, 1, problem.tractor_axle_x, problem.chord + 0.3, NOISE)
    np.testing.assert_allclose(longer.unwhitenedError(values), [-0.3], atol=1e-12)  # moved less than measured


@pytest.mark.parametrize("yaw_change", [0.0, 1e-8, 0.3, 2.5])
def test_jacobians_match_numerical_derivatives(yaw_change):
    rng = np.random.default_rng(5)
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(make_pose(rot_z(yaw_change), np.array([1.2, 0.3, 0.05]))))

    def residual(T_world_i, T_world_j):
        return chord_error(T_world_i, T_world_j, 0.7, 1.0)[0]

    _, (jacobian_i, jacobian_j) = chord_error(pose_i, pose_j, 0.7, 1.0, jacobians=True)
    assert jacobian_i.shape == (1, 6) and jacobian_j.shape == (1, 6)
    assert_jacobian_close(jacobian_i, numericalDerivative21(residual, pose_i, pose_j))
    assert_jacobian_close(jacobian_j, numericalDerivative22(residual, pose_i, pose_j))


def test_standstill_and_guards():
    pose = random_pose(np.random.default_rng(1))
    error, (jacobian_i, jacobian_j) = chord_error(pose, pose, 0.5, 0.0, jacobians=True)
    assert abs(error[0]) < 1e-12 and not np.any(jacobian_i) and not np.any(jacobian_j)
    with pytest.raises(ValueError, match="chord_length"):
        WheelSpeedFactor(0, 1, 0.5, -1.0, NOISE)
    with pytest.raises(ValueError, match="dimension"):
        WheelSpeedFactor(0, 1, 0.5, 1.0, gtsam.noiseModel.Isotropic.Sigma(2, 0.05))
