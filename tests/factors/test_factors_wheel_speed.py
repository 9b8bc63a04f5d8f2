"""Tests of factors.wheel_speed (WheelSpeedFactor)."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22, numericalDerivative31, numericalDerivative32, numericalDerivative33

from ampc_vo.geometry import make_pose, rot_z
from factors import WheelSpeedFactor, capture_chord_error, capture_chord_weights, chord_error, scaled_chord_error
from factors_support import articulated_truth, as_float, assert_jacobian_close, random_pose

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
    with pytest.raises(ValueError, match="distinct"):
        WheelSpeedFactor(0, 1, 0.5, 1.0, NOISE, scale_key=1)


@pytest.mark.parametrize("yaw_change", [0.0, 0.3, 2.5])
def test_scaled_chord_jacobians_match_numerical_derivatives(yaw_change):
    rng = np.random.default_rng(6)
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(make_pose(rot_z(yaw_change), np.array([1.2, 0.3, 0.05]))))
    scale = 1.013

    def residual(T_world_i, T_world_j, wheel_scale):
        return scaled_chord_error(T_world_i, T_world_j, as_float(wheel_scale), 0.7, 1.0)[0]

    _, (jacobian_i, jacobian_j, jacobian_scale) = scaled_chord_error(pose_i, pose_j, scale, 0.7, 1.0, jacobians=True)
    assert jacobian_scale.shape == (1, 1)
    assert_jacobian_close(jacobian_i, numericalDerivative31(residual, pose_i, pose_j, scale))
    assert_jacobian_close(jacobian_j, numericalDerivative32(residual, pose_i, pose_j, scale))
    assert_jacobian_close(jacobian_scale, numericalDerivative33(residual, pose_i, pose_j, scale))


def test_wheel_scale_is_recovered_beside_an_exact_metric_chord():
    """A precise wheel reading 1.5 % long on every pair beside a noisier but unbiased metric chord
    (the ground plane's, say): the optimised scale variable is 1.015 and every pose's chord is the
    true one; without the scale variable the wheel's error goes into the trajectory."""
    truth = articulated_truth(np.random.default_rng(3))
    axle_x, chord = truth.problem.tractor_axle_x, truth.problem.chord
    step = truth.tractor_i.between(truth.tractor_j)
    poses = [truth.tractor_i]
    for _ in range(4):
        poses.append(poses[-1].compose(step))
    for scaled in (True, False):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        scale_key, precise = 100, gtsam.noiseModel.Isotropic.Sigma(1, 0.002)
        graph.add(gtsam.PriorFactorPose3(0, poses[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        for index in range(4):
            rotation_only = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-6] * 3 + [10.0] * 3))
            graph.add(gtsam.BetweenFactorPose3(index, index + 1, step, rotation_only))
            graph.add(WheelSpeedFactor(index, index + 1, axle_x, 1.015 * chord, precise, scale_key if scaled else None))
            graph.add(WheelSpeedFactor(index, index + 1, axle_x, chord, gtsam.noiseModel.Isotropic.Sigma(1, 0.02)))
        for index, pose in enumerate(poses):
            values.insert(index, pose)
        if scaled:
            values.insert(scale_key, 1.0)
            graph.add(gtsam.PriorFactorDouble(scale_key, 1.0, gtsam.noiseModel.Isotropic.Sigma(1, 0.03)))
        result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
        chords = [chord_error(result.atPose3(index), result.atPose3(index + 1), axle_x, 0.0)[0][0] for index in range(4)]
        if scaled:
            assert result.atDouble(scale_key) == pytest.approx(1.015, abs=2e-3)
            np.testing.assert_allclose(chords, chord, rtol=2e-3)
        else:
            assert np.mean(chords) > 1.01 * chord


@pytest.mark.parametrize("yaw_change", [0.0, 0.3])
def test_capture_chord_jacobians_match_numerical_derivatives(yaw_change):
    rng = np.random.default_rng(7)
    poses = [random_pose(rng, 1.0, 10.0)]
    for step in ([1.2, 0.3, 0.05], [0.8, -0.1, 0.02], [0.5, 0.05, -0.01]):
        poses.append(poses[-1].compose(gtsam.Pose3(make_pose(rot_z(yaw_change), np.array(step)))))
    weights = (-0.02, 1.03, 0.05)

    def residual(T_world_a, T_world_b, T_world_c, T_world_d):
        return capture_chord_error(T_world_a, T_world_b, T_world_c, T_world_d, axle_x=0.7, chord_length=1.0, weights=weights)[0]

    _, jacobians = capture_chord_error(*poses, axle_x=0.7, chord_length=1.0, weights=weights, jacobians=True)
    step = 1e-6
    for index, jacobian in enumerate(jacobians):
        assert jacobian.shape == (1, 6)
        numerical = np.zeros((1, 6))
        for axis in range(6):
            delta = np.zeros(6)
            delta[axis] = step
            plus = [pose.retract(delta) if i == index else pose for i, pose in enumerate(poses)]
            minus = [pose.retract(-delta) if i == index else pose for i, pose in enumerate(poses)]
            numerical[0, axis] = (residual(*plus)[0] - residual(*minus)[0]) / (2 * step)
        assert_jacobian_close(jacobian, numerical)
    with pytest.raises(ValueError, match="3 weights need 4 poses"):
        capture_chord_error(*poses[:3], axle_x=0.7, chord_length=1.0, weights=weights)


@pytest.mark.parametrize("delay", [0.04, -0.03])
@pytest.mark.parametrize("with_before", [True, False])
def test_capture_chord_of_a_braking_truck(delay, with_before):
    """A truck braking at 2 m/s^2 on a straight road, keyframes 0.4, 0.5 and 0.6 s apart, its road
    points seen ``delay`` after each keyframe: the chord they measure is the keyframes' chord plus
    ``delay`` times the change of speed (4 cm short for 40 ms). The capture-time residual of the
    true poses is zero with the keyframe before and without it (three-point speeds, and the pair's
    mean speed the mean of its ends', are exact under constant acceleration); the plain chord's is
    the whole bias."""
    speed0, deceleration = 6.0, 2.0

    def arc(t):  # distance driven by time t (s), still braking
        return speed0 * t - 0.5 * deceleration * t * t

    times = np.array([0.0, 0.4, 0.9, 1.5])
    poses = [gtsam.Pose3(make_pose(np.eye(3), np.array([arc(t), 0.0, 0.0]))) for t in times]
    measured = arc(times[2] + delay) - arc(times[1] + delay)  # the pair (1, 2)
    plain = chord_error(poses[1], poses[2], 0.0, measured)[0][0]
    assert abs(plain) == pytest.approx(abs(delay) * deceleration * 0.5, rel=1e-9)
    intervals = np.diff(times)
    weights = capture_chord_weights(delay, intervals[0] if with_before else None, intervals[1], intervals[2])
    captured = capture_chord_error(*(poses if with_before else poses[1:]), axle_x=0.0, chord_length=measured, weights=weights)[0][0]
    assert abs(captured) < 1e-9
    with pytest.raises(ValueError, match="positive"):
        capture_chord_weights(delay, None, 0.0, 0.5)
