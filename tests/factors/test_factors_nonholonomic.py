"""Tests of factors.nonholonomic (NonHolonomicFactor, DESIGN (NH))."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

from ampc_vo.geometry import make_pose, rot_x, rot_y, rot_z
from ampc_vo.sim.two_view import ackermann_translation
from factors import NonHolonomicFactor, nonholonomic_error
from factors_support import articulated_truth, assert_jacobian_close, random_pose

NOISE = gtsam.noiseModel.Isotropic.Sigma(1, 0.02)


def _values(pose_i, pose_j):
    values = gtsam.Values()
    values.insert(0, pose_i)
    values.insert(1, pose_j)
    return values


@pytest.mark.parametrize("seed", range(10))
def test_zero_error_at_ground_truth_for_tractor_and_trailer(seed):
    truth = articulated_truth(np.random.default_rng(seed), hitch_angle=(-1.0, 1.0), yaw_change=(-0.4, 0.4))
    tractor = NonHolonomicFactor(0, 1, truth.problem.tractor_axle_x, NOISE)
    trailer = NonHolonomicFactor(0, 1, truth.problem.trailer_axle_x, NOISE)
    assert abs(tractor.unwhitenedError(_values(truth.tractor_i, truth.tractor_j))[0]) < 1e-10
    assert abs(trailer.unwhitenedError(_values(truth.trailer_i, truth.trailer_j))[0]) < 1e-10
    # the wrong axle (a skidding body) violates the constraint when the body turns
    if abs(truth.problem.yaw_change) > 0.05:
        wrong = NonHolonomicFactor(0, 1, truth.problem.tractor_axle_x + 2.0, NOISE)
        assert abs(wrong.unwhitenedError(_values(truth.tractor_i, truth.tractor_j))[0]) > 0.02


def test_residual_is_the_lateral_offset_in_metres():
    axle_x = 0.8
    for yaw_change in (0.0, 0.2, -0.5):
        translation = ackermann_translation(yaw_change, 1.5, axle_x)
        lateral = rot_z(0.5 * yaw_change) @ np.array([0.0, 0.1, 0.0])  # 10 cm to the left of the chord
        pose_j = gtsam.Pose3(make_pose(rot_z(yaw_change), translation + lateral))
        error, _ = nonholonomic_error(gtsam.Pose3(), pose_j, axle_x)
        np.testing.assert_allclose(error, [0.1], atol=1e-12)


CASES = {
    "zero yaw change": (0.0, 0.0),
    "tiny yaw change": (1e-8, 0.0),
    "keyframe turn": (0.15, 0.02),
    "large yaw change": (2.5, 0.1),
    "negative large yaw with tilt": (-2.0, 0.3),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("axle_x", [0.6, -8.0, 0.0])
def test_jacobians_match_numerical_derivatives(case, axle_x):
    yaw_change, tilt = CASES[case]
    rng = np.random.default_rng(17)
    rotation = rot_z(yaw_change) @ rot_y(tilt) @ rot_x(-tilt)
    T_i_j = make_pose(rotation, ackermann_translation(yaw_change, 1.3, axle_x) + rng.normal(0.0, 0.05, 3))
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(T_i_j))

    def residual(T_world_i, T_world_j):
        return nonholonomic_error(T_world_i, T_world_j, axle_x)[0]

    _, (jacobian_i, jacobian_j) = nonholonomic_error(pose_i, pose_j, axle_x, jacobians=True)
    assert jacobian_i.shape == (1, 6) and jacobian_j.shape == (1, 6)
    assert_jacobian_close(jacobian_i, numericalDerivative21(residual, pose_i, pose_j))
    assert_jacobian_close(jacobian_j, numericalDerivative22(residual, pose_i, pose_j))


def test_linearize_shape_guards_and_late_binding():
    truth = articulated_truth(np.random.default_rng(4), yaw_change=0.3)
    values = _values(truth.tractor_i, truth.tractor_j)
    axles = [-8.0, -4.0, 0.0, 1.0]
    built = [NonHolonomicFactor(0, 1, axle_x, NOISE) for axle_x in axles]
    for factor, axle_x in zip(built, axles):
        assert factor.unwhitenedError(values)[0] == nonholonomic_error(truth.tractor_i, truth.tractor_j, axle_x)[0][0]
        matrix, rhs = factor.linearize(values).jacobian()
        assert matrix.shape == (1, 12) and rhs.shape == (1,)
    with pytest.raises(ValueError, match="axle_x"):
        NonHolonomicFactor(0, 1, float("nan"), NOISE)
    with pytest.raises(ValueError, match="dimension"):
        NonHolonomicFactor(0, 1, 0.5, gtsam.noiseModel.Isotropic.Sigma(2, 0.02))
    with pytest.raises(ValueError, match="distinct"):
        NonHolonomicFactor(3, 3, 0.5, NOISE)


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("crab_deg", [0.0, 0.4, -3.0])
def test_crabbed_jacobians_match_numerical_derivatives(case, crab_deg):
    from gtsam.utils.numerical_derivative import numericalDerivative31, numericalDerivative32, numericalDerivative33

    from factors import crabbed_nonholonomic_error

    yaw_change, tilt = CASES[case]
    rng = np.random.default_rng(23)
    axle_x = -8.5
    rotation = rot_z(yaw_change) @ rot_y(tilt) @ rot_x(-tilt)
    T_i_j = make_pose(rotation, ackermann_translation(yaw_change, 1.3, axle_x) + rng.normal(0.0, 0.05, 3))
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(T_i_j))
    crab = np.radians(crab_deg)

    def residual(T_world_i, T_world_j, crab_angle):
        return crabbed_nonholonomic_error(T_world_i, T_world_j, float(np.ravel(crab_angle)[0]), axle_x)[0]

    _, (jacobian_i, jacobian_j, jacobian_crab) = crabbed_nonholonomic_error(pose_i, pose_j, crab, axle_x, jacobians=True)
    assert jacobian_crab.shape == (1, 1)
    assert_jacobian_close(jacobian_i, numericalDerivative31(residual, pose_i, pose_j, crab))
    assert_jacobian_close(jacobian_j, numericalDerivative32(residual, pose_i, pose_j, crab))
    assert_jacobian_close(jacobian_crab, numericalDerivative33(residual, pose_i, pose_j, crab))
    # without crab it is the plain arc residual
    if crab_deg == 0.0:
        np.testing.assert_allclose(crabbed_nonholonomic_error(pose_i, pose_j, 0.0, axle_x)[0], nonholonomic_error(pose_i, pose_j, axle_x)[0])


def test_a_crabbing_trailer_is_consistent_with_its_crab_angle_only():
    # a trailer moving straight at 0.3 deg to its x axis: the arc model says 6.8 mm off over 1.3 m,
    # the crabbed one with the true angle nothing
    crab = np.radians(0.3)
    motion = gtsam.Pose3(make_pose(np.eye(3), 1.3 * np.array([np.cos(crab), np.sin(crab), 0.0])))
    plain, _ = nonholonomic_error(gtsam.Pose3(), motion, -8.5)
    assert abs(plain[0]) == pytest.approx(1.3 * np.sin(crab), rel=1e-9)
    from factors import crabbed_nonholonomic_error

    assert abs(crabbed_nonholonomic_error(gtsam.Pose3(), motion, crab, -8.5)[0][0]) < 1e-12
