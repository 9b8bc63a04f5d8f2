"""Tests of factors.joint_loop (JointLoopFactor, paper eqs. (3)-(5))."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative31, numericalDerivative32, numericalDerivative33

from factors import JointLoopFactor, joint_loop_error
from factors_support import articulated_truth, as_float, assert_jacobian_close, hitch, random_pose

NOISE = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)


def _values(tractor, trailer, hitch_angle):
    values = gtsam.Values()
    values.insert(0, tractor)
    values.insert(1, trailer)
    values.insert(2, float(hitch_angle))
    return values


@pytest.mark.parametrize("seed", range(10))
def test_zero_error_at_ground_truth(seed):
    truth = articulated_truth(np.random.default_rng(seed))
    factor = JointLoopFactor(0, 1, 2, NOISE)
    for tractor, trailer, angle in ((truth.tractor_i, truth.trailer_i, truth.hitch_i), (truth.tractor_j, truth.trailer_j, truth.hitch_j)):
        error = factor.unwhitenedError(_values(tractor, trailer, angle))
        assert error.shape == (6,) and np.max(np.abs(error)) < 1e-12
    # the trailer motion of the simulator (paper eqs. (3), (4)) is the one the factor implies
    implied = truth.trailer_i.between(truth.trailer_j).matrix()
    np.testing.assert_allclose(implied, truth.problem.T_trailer_i_j, atol=1e-12)


def test_sign_conventions():
    tractor = random_pose(np.random.default_rng(1))
    trailer = tractor.compose(hitch(0.3 + 0.01))  # trailer rotated 0.01 rad further counter-clockwise
    error, _ = joint_loop_error(tractor, trailer, 0.3)
    np.testing.assert_allclose(error, [0.0, 0.0, 0.01, 0.0, 0.0, 0.0], atol=1e-12)
    shifted = tractor.compose(hitch(0.3)).compose(gtsam.Pose3(gtsam.Rot3(), np.array([0.2, 0.0, 0.0])))  # trailer origin 0.2 m ahead
    error, _ = joint_loop_error(tractor, shifted, 0.3)
    np.testing.assert_allclose(error, [0.0, 0.0, 0.0, 0.2, 0.0, 0.0], atol=1e-12)  # metres, trailer frame


@pytest.mark.parametrize("hitch_angle", [0.0, 1e-9, 1e-4, 0.4, -1.2, 3.0])
@pytest.mark.parametrize("offset_scale", [0.0, 1e-6, 0.05, 1.0])
def test_jacobians_match_numerical_derivatives(hitch_angle, offset_scale):
    rng = np.random.default_rng(int(1e3 * abs(hitch_angle)) + int(10 * offset_scale))
    tractor = random_pose(rng, 1.5, 10.0)
    trailer = tractor.compose(hitch(hitch_angle)).compose(gtsam.Pose3.Expmap(rng.normal(0.0, offset_scale, 6)))

    def residual(tractor_pose, trailer_pose, angle):
        return joint_loop_error(tractor_pose, trailer_pose, as_float(angle))[0]

    _, (by_tractor, by_trailer, by_hitch) = joint_loop_error(tractor, trailer, hitch_angle, jacobians=True)
    assert by_tractor.shape == (6, 6) and by_trailer.shape == (6, 6) and by_hitch.shape == (6, 1)
    assert_jacobian_close(by_tractor, numericalDerivative31(residual, tractor, trailer, hitch_angle))
    assert_jacobian_close(by_trailer, numericalDerivative32(residual, tractor, trailer, hitch_angle))
    assert_jacobian_close(by_hitch, numericalDerivative33(residual, tractor, trailer, hitch_angle))


def test_linearize_shape_and_guards():
    truth = articulated_truth(np.random.default_rng(3))
    factor = JointLoopFactor(0, 1, 2, NOISE)
    matrix, rhs = factor.linearize(_values(truth.tractor_i, truth.trailer_i, truth.hitch_i + 0.1)).jacobian()
    assert matrix.shape == (6, 13) and rhs.shape == (6,)
    with pytest.raises(ValueError, match="dimension"):
        JointLoopFactor(0, 1, 2, gtsam.noiseModel.Isotropic.Sigma(3, 1e-3))
    with pytest.raises(ValueError, match="distinct"):
        JointLoopFactor(0, 1, 1, NOISE)
    with pytest.raises(ValueError, match="key"):
        JointLoopFactor(0, 1, 2.5, NOISE)


@pytest.mark.parametrize("hitch_angle", [0.0, 0.4, -1.2])
@pytest.mark.parametrize("plate_pitch", [0.0, 0.05, -0.12])
def test_fifth_wheel_residual_isolates_the_plate_pitch(hitch_angle, plate_pitch):
    """A trailer pitched on the fifth wheel (``R_tractor_trailer = Ry(beta) Rz(theta)``) gives the
    residual ``(0, beta, 0, 0, 0, 0)``: only the free pitch component, whatever the hitch angle."""
    from factors.joint_loop import fifth_wheel_error

    tractor = random_pose(np.random.default_rng(3), 0.3, 10.0)
    trailer = tractor.compose(gtsam.Pose3(gtsam.Rot3.Ry(plate_pitch), np.zeros(3))).compose(hitch(hitch_angle))
    error, _ = fifth_wheel_error(tractor, trailer, hitch_angle)
    np.testing.assert_allclose(error, [0.0, plate_pitch, 0.0, 0.0, 0.0, 0.0], atol=1e-12)
    rolled = tractor.compose(gtsam.Pose3(gtsam.Rot3.Rx(0.02), np.zeros(3))).compose(hitch(hitch_angle))
    error, _ = fifth_wheel_error(tractor, rolled, hitch_angle)
    np.testing.assert_allclose(error[:3], [0.02, 0.0, 0.0], atol=1e-9)  # roll stays in component 0


@pytest.mark.parametrize("hitch_angle", [0.0, 0.4, -1.2, 3.0])
@pytest.mark.parametrize("offset_scale", [0.0, 0.05, 1.0])
def test_fifth_wheel_jacobians_match_numerical_derivatives(hitch_angle, offset_scale):
    from factors.joint_loop import fifth_wheel_error

    rng = np.random.default_rng(int(1e3 * abs(hitch_angle)) + int(10 * offset_scale) + 7)
    tractor = random_pose(rng, 1.5, 10.0)
    trailer = tractor.compose(hitch(hitch_angle)).compose(gtsam.Pose3.Expmap(rng.normal(0.0, offset_scale, 6)))

    def residual(tractor_pose, trailer_pose, angle):
        return fifth_wheel_error(tractor_pose, trailer_pose, as_float(angle))[0]

    _, (by_tractor, by_trailer, by_hitch) = fifth_wheel_error(tractor, trailer, hitch_angle, jacobians=True)
    assert_jacobian_close(by_tractor, numericalDerivative31(residual, tractor, trailer, hitch_angle))
    assert_jacobian_close(by_trailer, numericalDerivative32(residual, tractor, trailer, hitch_angle))
    assert_jacobian_close(by_hitch, numericalDerivative33(residual, tractor, trailer, hitch_angle))
