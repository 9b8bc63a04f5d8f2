"""Tests of factors.planar (PlanarMotionFactor)."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

from ampc_vo.geometry import make_pose, rot_x, rot_y, rot_z
from factors import PlanarMotionFactor, planar_motion_error
from factors.planar import planar_sigmas
from factors_support import articulated_truth, assert_jacobian_close, random_pose

NOISE = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.02]))


@pytest.mark.parametrize("seed", range(6))
def test_zero_error_at_ground_truth(seed):
    truth = articulated_truth(np.random.default_rng(seed))
    factor = PlanarMotionFactor(0, 1, NOISE)
    for pose_i, pose_j in ((truth.tractor_i, truth.tractor_j), (truth.trailer_i, truth.trailer_j)):
        values = gtsam.Values()
        values.insert(0, pose_i)
        values.insert(1, pose_j)
        assert np.max(np.abs(factor.unwhitenedError(values))) < 1e-12


def test_residual_is_roll_pitch_height():
    T_i_j = make_pose(rot_z(0.7) @ rot_y(0.02) @ rot_x(-0.03), np.array([1.0, 0.5, 0.04]))
    error, _ = planar_motion_error(gtsam.Pose3(), gtsam.Pose3(T_i_j))
    np.testing.assert_allclose(error, [-0.03, 0.02, 0.04], atol=1e-12)


@pytest.mark.parametrize("yaw, pitch, roll", [(0.0, 0.0, 0.0), (1e-8, 1e-9, -1e-9), (0.2, 0.01, -0.02), (2.8, -0.9, 1.2), (-1.5, 1.2, 2.5)])
def test_jacobians_match_numerical_derivatives(yaw, pitch, roll):
    rng = np.random.default_rng(23)
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(make_pose(rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), rng.normal(0.0, 2.0, 3))))
    _, (jacobian_i, jacobian_j) = planar_motion_error(pose_i, pose_j, jacobians=True)
    assert jacobian_i.shape == (3, 6) and jacobian_j.shape == (3, 6)

    def residual(T_world_i, T_world_j):
        return planar_motion_error(T_world_i, T_world_j)[0]

    assert_jacobian_close(jacobian_i, numericalDerivative21(residual, pose_i, pose_j))
    assert_jacobian_close(jacobian_j, numericalDerivative22(residual, pose_i, pose_j))


def test_linearize_shape_and_guards():
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(1, random_pose(np.random.default_rng(2), 0.1, 1.0))
    matrix, rhs = PlanarMotionFactor(0, 1, NOISE).linearize(values).jacobian()
    assert matrix.shape == (3, 12) and rhs.shape == (3,)
    with pytest.raises(ValueError, match="dimension"):
        PlanarMotionFactor(0, 1, gtsam.noiseModel.Isotropic.Sigma(6, 0.01))
    with pytest.raises(ValueError, match="distinct"):
        PlanarMotionFactor(0, 0, NOISE)


def test_planar_sigmas_widen_with_the_suspension_response_to_acceleration():
    """A truck braking at 1.5 m/s^2 and stopping within a keyframe pair: its nose rises by the
    empty tractor's pitch gain times the deceleration (the simulator's ``SUSPENSION`` table, from
    Gillespie ch. 5): 0.35 x 1.5 = 0.53 deg, 2.6 sigmas of a fixed 0.2 deg planar factor but within
    one of the widened one. Roll follows the lateral acceleration only, pitch the longitudinal."""
    from ampc_vo.sim.attitude import SUSPENSION

    floor, height = np.radians(0.2), 0.02
    roll_gain, pitch_gain = np.radians(0.9), np.radians(0.35)
    at_rest = planar_sigmas(0.0, 0.0, floor, roll_gain, pitch_gain, height)
    np.testing.assert_allclose(at_rest, [floor, floor, height])
    pitch_change = np.radians(SUSPENSION["empty"]["tractor"].pitch_gain_deg) * 1.5
    assert pitch_change / floor > 2.5
    braking = planar_sigmas(0.0, -1.5, floor, roll_gain, pitch_gain, height)
    assert braking[0] == pytest.approx(floor) and pitch_change < braking[1] < 1.1 * pitch_change
    cornering = planar_sigmas(2.0, 0.0, floor, roll_gain, pitch_gain, height)
    assert cornering[1] == pytest.approx(floor)
    assert np.degrees(cornering[0]) == pytest.approx(np.hypot(0.2, 1.8))
    roll_change = np.radians(SUSPENSION["loaded"]["trailer"].roll_gain_deg) * 2.0  # a loaded trailer entering a 2 m/s^2 turn
    assert roll_change <= cornering[0]
