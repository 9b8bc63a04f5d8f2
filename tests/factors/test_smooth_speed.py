"""Tests of factors.smooth_speed: zero error at constant speed, analytic vs numerical Jacobians."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X
from gtsam.utils.numerical_derivative import numericalDerivative31, numericalDerivative32, numericalDerivative33

from factors.smooth_speed import SmoothSpeedFactor


def _values(poses):
    values = gtsam.Values()
    for index, pose in enumerate(poses):
        values.insert(X(index), pose)
    return values


def test_zero_at_constant_speed_and_known_value():
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 0.1)
    factor = SmoothSpeedFactor(X(0), X(1), X(2), 0.1, 0.2, noise)
    poses = [gtsam.Pose3(gtsam.Rot3.Yaw(0.1 * k), gtsam.Point3(*(np.array([1.0, 0.5, 0.0]) * s))) for k, s in enumerate((0.0, 1.0, 3.0))]
    assert factor.unwhitenedError(_values(poses))[0] == pytest.approx(0.0, abs=1e-12)
    poses[2] = gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(*(np.array([1.0, 0.5, 0.0]) * 3.5)))
    assert factor.unwhitenedError(_values(poses))[0] == pytest.approx(np.sqrt(1.25) * 2.5 / 0.2 - np.sqrt(1.25) / 0.1)


def test_speed_is_signed_by_the_body_heading():
    """Reversing at the speed driven forward before is a change of velocity of twice that speed
    (the unsigned magnitude made a chord of the wrong sign free); reversing on and on costs nothing."""
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 1.0)
    factor = SmoothSpeedFactor(X(0), X(1), X(2), 0.5, 0.5, noise)
    heading = gtsam.Rot3.Yaw(0.3)
    forward = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    def at(distance):
        return gtsam.Pose3(heading, gtsam.Point3(*(forward * distance)))
    assert factor.unwhitenedError(_values([at(0.0), at(1.0), at(0.0)]))[0] == pytest.approx(-4.0)  # +2 m/s, then -2 m/s
    assert factor.unwhitenedError(_values([at(0.0), at(-1.0), at(-2.0)]))[0] == pytest.approx(0.0, abs=1e-12)
    assert factor.unwhitenedError(_values([at(0.0), at(1.0), at(1.1)]))[0] == pytest.approx(0.2 - 2.0)


@pytest.mark.parametrize("seed", range(8))
def test_jacobians_match_numerical(seed):
    rng = np.random.default_rng(seed)
    poses = [gtsam.Pose3(gtsam.Rot3.RzRyRx(*rng.normal(size=3)), gtsam.Point3(*(rng.normal(size=3) * 3))) for _ in range(3)]
    factor = SmoothSpeedFactor(X(0), X(1), X(2), 0.1, 0.3, gtsam.noiseModel.Isotropic.Sigma(1, 1.0))

    def error(a, b, c):
        return factor.unwhitenedError(_values([a, b, c]))

    jacobian, _ = factor.linearize(_values(poses)).jacobian()
    numerical = np.hstack([numericalDerivative31(error, *poses), numericalDerivative32(error, *poses), numericalDerivative33(error, *poses)])
    np.testing.assert_allclose(jacobian, numerical, atol=1e-6 * max(1.0, np.abs(numerical).max()))


def test_bad_arguments():
    with pytest.raises(ValueError):
        SmoothSpeedFactor(X(0), X(1), X(2), 0.0, 0.1, gtsam.noiseModel.Isotropic.Sigma(1, 1.0))
    with pytest.raises(ValueError):
        SmoothSpeedFactor(X(0), X(1), X(2), 0.1, 0.1, gtsam.noiseModel.Isotropic.Sigma(2, 1.0))


# ---------------------------------------------------------------------- factors.relative_pose
@pytest.mark.parametrize("angle", [0.0, 1e-6, 1e-3, 0.05, 0.5])
def test_relative_pose_factor_near_identity(angle):
    """Finite, correct Jacobians near the identity (small rotations), and the residual of ``BetweenFactorPose3``."""
    from factors.relative_pose import RelativePoseFactor

    rng = np.random.default_rng(1)
    first = gtsam.Pose3(gtsam.Rot3.Yaw(0.1), gtsam.Point3(1.0, 2.0, 0.0))
    second = first.compose(gtsam.Pose3(gtsam.Rot3.RzRyRx(angle, 0.3 * angle, -angle), gtsam.Point3(*rng.normal(size=3))))
    measured = gtsam.Pose3(gtsam.Rot3.Yaw(0.02), gtsam.Point3(0.5, 0.0, 0.0))
    factor = RelativePoseFactor(X(0), X(1), measured, gtsam.noiseModel.Isotropic.Sigma(6, 1.0))
    reference = gtsam.BetweenFactorPose3(X(0), X(1), measured, gtsam.noiseModel.Isotropic.Sigma(6, 1.0))
    values = _values([first, second])
    np.testing.assert_allclose(factor.unwhitenedError(values), reference.unwhitenedError(values), atol=1e-12)

    def error(a, b):
        return factor.unwhitenedError(_values([a, b]))

    from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

    jacobian, _ = factor.linearize(values).jacobian()
    assert np.all(np.isfinite(jacobian))
    numerical = np.hstack([numericalDerivative21(error, first, second), numericalDerivative22(error, first, second)])
    np.testing.assert_allclose(jacobian, numerical, atol=1e-6)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-6, 1e-3, 0.05, 0.5])
def test_between_prior_is_the_relative_pose_factor(scale):
    """The smoother's motion priors, gtsam's C++ ``BetweenFactorPose3`` (``between_prior``), give the
    error and whitened linear system of the Python ``RelativePoseFactor`` it replaced (to 1e-9) at
    random poses whose relative motion is ``scale`` away from the measurement, down to the identity
    (the standstill prior) and exactly at it."""
    from factors.relative_pose import RelativePoseFactor, between_prior

    rng = np.random.default_rng(7)
    sigmas = np.array([0.01, 0.02, 0.03, 0.1, 0.2, 0.3])
    for measured in (gtsam.Pose3(), gtsam.Pose3.Expmap(rng.normal(size=6) * 0.3)):
        for _ in range(20):
            first = gtsam.Pose3.Expmap(rng.normal(size=6) * 2.0)
            second = first.compose(measured).compose(gtsam.Pose3.Expmap(rng.normal(size=6) * scale))
            values = _values([first, second])
            replacement = between_prior(X(0), X(1), measured, sigmas)
            reference = RelativePoseFactor(X(0), X(1), measured, gtsam.noiseModel.Diagonal.Sigmas(sigmas))
            assert replacement.error(values) == pytest.approx(reference.error(values), rel=1e-9, abs=1e-12)
            matrix, rhs = replacement.linearize(values).jacobian()
            expected_matrix, expected_rhs = reference.linearize(values).jacobian()
            assert np.all(np.isfinite(matrix))
            np.testing.assert_allclose(matrix, expected_matrix, rtol=1e-9, atol=1e-9 * np.abs(expected_matrix).max())
            np.testing.assert_allclose(rhs, expected_rhs, rtol=1e-9, atol=1e-9)
