"""Tests of factors.epipolar (GeneralizedEpipolarFactor) and the Sampson Jacobian in ampc_vo.epipolar."""
from __future__ import annotations

import gc

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative11, numericalDerivative21, numericalDerivative22

from ampc_vo.epipolar import gec_sampson, gec_sampson_jacobian
from ampc_vo.errors import BearingError
from ampc_vo.geometry import make_pose, rot_x, rot_y, rot_z
from factors import GeneralizedEpipolarFactor, body_correspondences, epipolar_error, robust_noise
from factors_support import articulated_truth, assert_jacobian_close, random_pose

SIGMA = 1.0 / 700.0


def _values(*poses: gtsam.Pose3) -> gtsam.Values:
    values = gtsam.Values()
    for key, pose in enumerate(poses):
        values.insert(key, pose)
    return values


def _camera(yaw: float, pitch: float, center) -> np.ndarray:
    """T_body_camera of an OpenCV camera looking along body yaw, pitched down."""
    body_from_opencv = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return make_pose(rot_z(yaw) @ rot_y(pitch) @ body_from_opencv, np.asarray(center, dtype=float))


def _two_camera_bearings(rng, T_i_j, T_body_camera_i, T_body_camera_j, count=30):
    """Points seen by camera A in view i and camera B in view j (Plücker form), camera-frame bearings."""
    points_i = rng.uniform([-30.0, -30.0, -3.0], [30.0, 30.0, 10.0], (count, 3))
    points_j = (points_i - T_i_j[:3, 3]) @ T_i_j[:3, :3]
    in_camera_i = (points_i - T_body_camera_i[:3, 3]) @ T_body_camera_i[:3, :3]
    in_camera_j = (points_j - T_body_camera_j[:3, 3]) @ T_body_camera_j[:3, :3]
    return in_camera_i / np.linalg.norm(in_camera_i, axis=1, keepdims=True), in_camera_j / np.linalg.norm(in_camera_j, axis=1, keepdims=True)


# ---------------------------------------------------------------------- zero at ground truth
@pytest.mark.parametrize("seed", range(8))
def test_zero_error_at_ground_truth_on_both_bodies(seed):
    truth = articulated_truth(np.random.default_rng(seed))
    for group in truth.problem.correspondences:
        poses = (truth.tractor_i, truth.tractor_j) if group.body == "tractor" else (truth.trailer_i, truth.trailer_j)
        factor = GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(SIGMA, len(group), None))
        error = factor.unwhitenedError(_values(*poses))
        assert error.shape == (len(group),)
        assert np.max(np.abs(error)) < 1e-9
        # wrong motion: the residuals are clearly non-zero (in units of the pixel noise)
        wrong = poses[1].compose(gtsam.Pose3(gtsam.Rot3.Expmap(np.array([0.05, 0.05, 0.05])), np.array([0.0, 0.5, 0.3])))
        assert np.max(np.abs(factor.unwhitenedError(_values(poses[0], wrong)))) > 3 * SIGMA


def test_value_is_gec_sampson_of_relative_motion():
    truth = articulated_truth(np.random.default_rng(11), pixel_noise_px=1.0)
    group = truth.problem.correspondences[0]
    correspondences = body_correspondences(group.camera.T_body_camera, group.bearings_i, group.bearings_j)
    pose_j = truth.tractor_j.compose(random_pose(np.random.default_rng(1), 0.05, 0.2))
    residual, _ = epipolar_error(truth.tractor_i, pose_j, correspondences)
    T_i_j = truth.tractor_i.between(pose_j)
    expected = gec_sampson(group.body_bearings_i, group.body_bearings_j, T_i_j.rotation().matrix(), T_i_j.translation(), group.center)
    np.testing.assert_allclose(residual, expected, atol=1e-12)


def test_plucker_two_camera_form_zero_at_truth_and_observes_standstill():
    rng = np.random.default_rng(3)
    camera_a = _camera(0.3, 0.1, [4.0, 1.0, 2.5])
    camera_b = _camera(-0.4, 0.2, [3.5, -1.0, 2.0])
    for T_i_j in (make_pose(rot_z(0.2), np.array([1.5, 0.2, 0.0])), np.eye(4)):
        bearings_i, bearings_j = _two_camera_bearings(rng, T_i_j, camera_a, camera_b)
        factor = GeneralizedEpipolarFactor(0, 1, camera_a, bearings_i, bearings_j, robust_noise(SIGMA, 30, None), T_body_camera_j=camera_b)
        pose_i = random_pose(rng)
        pose_j = pose_i.compose(gtsam.Pose3(T_i_j))
        assert np.max(np.abs(factor.unwhitenedError(_values(pose_i, pose_j)))) < 1e-9
        # metric scale is observable: scaling the translation breaks the constraint
        scaled = gtsam.Pose3(gtsam.Rot3(T_i_j[:3, :3]), 1.5 * T_i_j[:3, 3] + [0.0, 0.3, 0.0])
        assert np.max(np.abs(factor.unwhitenedError(_values(pose_i, pose_i.compose(scaled))))) > 1e-3


# ---------------------------------------------------------------------- Jacobians
MOTIONS = {
    "zero yaw change": make_pose(np.eye(3), np.array([1.2, 0.0, 0.0])),
    "tiny yaw change": make_pose(rot_z(1e-7), np.array([1.0, 1e-8, 0.0])),
    "planar turn": make_pose(rot_z(0.15), np.array([1.5, 0.1, 0.0])),
    "large 3-D rotation": make_pose(rot_z(1.4) @ rot_x(0.7) @ rot_y(-0.9), np.array([-2.0, 3.0, 1.0])),
    "short baseline": make_pose(rot_z(0.01), np.array([0.02, 0.001, 0.0])),
}


@pytest.mark.parametrize("motion", list(MOTIONS))
@pytest.mark.parametrize("two_cameras", [False, True])
def test_jacobians_match_numerical_derivatives(motion, two_cameras):
    rng = np.random.default_rng(7)
    T_i_j = MOTIONS[motion]
    camera_a = _camera(0.0, 0.15, [5.0, 0.3, 2.5])
    camera_b = _camera(1.5, 0.1, [2.0, 1.3, 2.2]) if two_cameras else camera_a
    bearings_i, bearings_j = _two_camera_bearings(rng, T_i_j, camera_a, camera_b, count=25)
    bearings_j = bearings_j + rng.normal(0.0, 0.01, bearings_j.shape)  # off the constraint surface
    correspondences = body_correspondences(camera_a, bearings_i, bearings_j, camera_b if two_cameras else None)
    pose_i = random_pose(rng, 1.0, 10.0)
    pose_j = pose_i.compose(gtsam.Pose3(T_i_j))

    def residual(T_world_i, T_world_j):
        return epipolar_error(T_world_i, T_world_j, correspondences)[0]

    value, (jacobian_i, jacobian_j) = epipolar_error(pose_i, pose_j, correspondences, jacobians=True)
    assert jacobian_i.shape == (25, 6) and jacobian_j.shape == (25, 6)
    np.testing.assert_array_equal(value, residual(pose_i, pose_j))
    # central differences err by O(delta^2 f'''): the Sampson residual has large third derivatives
    # (a 2 cm baseline next to 5 m lever arms even more so), hence steps below the default 1e-5
    delta = 1e-7 if motion == "short baseline" else 1e-6
    assert_jacobian_close(jacobian_i, numericalDerivative21(residual, pose_i, pose_j, delta=delta))
    assert_jacobian_close(jacobian_j, numericalDerivative22(residual, pose_i, pose_j, delta=delta))


def test_sampson_jacobian_zero_baseline_is_finite():
    rng = np.random.default_rng(0)
    bearings = rng.normal(size=(5, 3))
    bearings /= np.linalg.norm(bearings, axis=1, keepdims=True)
    residual, jacobian = gec_sampson_jacobian(bearings, bearings, np.eye(3), np.zeros(3), np.array([1.0, 0.0, 2.0]))
    assert np.all(residual == 0.0) and np.all(jacobian == 0.0)


# ---------------------------------------------------------------------- GTSAM integration, shapes
def test_linearize_shapes_and_survives_python_object():
    rng = np.random.default_rng(5)
    truth = articulated_truth(rng, pixel_noise_px=1.0)
    graph = gtsam.NonlinearFactorGraph()
    groups = truth.problem.on("tractor")

    def add_factors():  # factors go out of Python scope; the graph keeps the C++ objects alive
        for group in groups:
            graph.add(GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(SIGMA, len(group), 1.345)))

    add_factors()
    gc.collect()
    values = _values(truth.tractor_i, truth.tractor_j)
    linear = graph.linearize(values)
    for index, group in enumerate(groups):
        matrix, rhs = linear.at(index).jacobian()
        assert matrix.shape == (len(group), 12) and rhs.shape == (len(group),)
        expected, _ = epipolar_error(truth.tractor_i, truth.tractor_j, body_correspondences(group.camera.T_body_camera, group.bearings_i, group.bearings_j))
        np.testing.assert_allclose(graph.at(index).unwhitenedError(values), expected, atol=1e-14)


def test_factors_built_in_a_loop_keep_their_own_data():
    rng = np.random.default_rng(9)
    truth = articulated_truth(rng, pixel_noise_px=1.0)
    values = _values(truth.tractor_i, truth.tractor_j.compose(random_pose(rng, 0.02, 0.1)))
    built = [
        GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, group.bearings_j, robust_noise(SIGMA, len(group), None))
        for group in truth.problem.correspondences
    ]
    for factor, group in zip(built, truth.problem.correspondences):
        expected, _ = epipolar_error(truth.tractor_i, values.atPose3(1), body_correspondences(group.camera.T_body_camera, group.bearings_i, group.bearings_j))
        np.testing.assert_array_equal(factor.unwhitenedError(values), expected)


# ---------------------------------------------------------------------- guards
GOOD = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.2, 1.0]])


@pytest.mark.parametrize(
    "bearings_i, bearings_j",
    [
        (GOOD[:, :2], GOOD[:, :2]),  # wrong shape
        (GOOD[0], GOOD[0]),  # 1-D
        (GOOD, GOOD[:2]),  # mismatched counts
        (np.where(np.eye(3, dtype=bool), np.nan, GOOD), GOOD),  # NaN
        (GOOD, np.vstack([GOOD[:2], np.zeros(3)])),  # zero length
        (np.zeros((0, 3)), np.zeros((0, 3))),  # empty
    ],
)
def test_bad_bearings_raise_bearing_error(bearings_i, bearings_j):
    with pytest.raises(BearingError):
        GeneralizedEpipolarFactor(0, 1, np.eye(4), bearings_i, bearings_j, robust_noise(SIGMA, 3, None))


def test_other_bad_inputs_raise_value_error():
    noise = robust_noise(SIGMA, 3, None)
    with pytest.raises(ValueError, match="dimension"):
        GeneralizedEpipolarFactor(0, 1, np.eye(4), GOOD, GOOD, robust_noise(SIGMA, 4, None))
    with pytest.raises(ValueError, match="distinct"):
        GeneralizedEpipolarFactor(2, 2, np.eye(4), GOOD, GOOD, noise)
    with pytest.raises(ValueError, match="key"):
        GeneralizedEpipolarFactor(-1, 2, np.eye(4), GOOD, GOOD, noise)
    with pytest.raises(ValueError, match="rigid"):
        GeneralizedEpipolarFactor(0, 1, 2.0 * np.eye(4), GOOD, GOOD, noise)
    with pytest.raises(ValueError, match="4x4"):
        GeneralizedEpipolarFactor(0, 1, np.eye(3), GOOD, GOOD, noise)
    with pytest.raises(ValueError, match="noiseModel"):
        GeneralizedEpipolarFactor(0, 1, np.eye(4), GOOD, GOOD, SIGMA)
    with pytest.raises(ValueError):
        robust_noise(-1.0, 3, 1.0)
    with pytest.raises(ValueError):
        robust_noise(SIGMA, 0, 1.0)


# ---------------------------------------------------------------------- per-residual robust weighting
def test_scalar_huber_downweights_only_the_outlier():
    """One gross outlier among N residuals: Scalar reweighting scales its row alone; Block scales all."""
    rng = np.random.default_rng(21)
    truth = articulated_truth(rng, pixel_noise_px=0.5, points_per_body=60)
    group = truth.problem.correspondences[0]
    bearings_j = group.bearings_j.copy()
    outlier = 7
    bearings_j[outlier] = [0.3, -0.2, 1.0]
    count = len(group)
    values = _values(truth.tractor_i, truth.tractor_j)
    rows = {}
    for name, noise in {
        "gaussian": robust_noise(SIGMA, count, None),
        "scalar": robust_noise(SIGMA, count, 1.345),
        "block": robust_noise(SIGMA, count, 1.345, per_residual=False),
    }.items():
        factor = GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, bearings_j, noise)
        rows[name] = factor.linearize(values).jacobian()[0]
    whitened = np.abs(GeneralizedEpipolarFactor(0, 1, group.camera.T_body_camera, group.bearings_i, bearings_j, robust_noise(SIGMA, count, None)).whitenedError(values))
    assert whitened[outlier] > 50.0 and np.max(np.delete(whitened, outlier)) < 1.345  # inliers inside the Huber core
    weight = np.linalg.norm(rows["scalar"], axis=1) / np.linalg.norm(rows["gaussian"], axis=1)
    np.testing.assert_allclose(np.delete(weight, outlier), 1.0, atol=1e-12)
    np.testing.assert_allclose(weight[outlier], np.sqrt(1.345 / whitened[outlier]), rtol=1e-9)
    block_weight = np.linalg.norm(rows["block"], axis=1) / np.linalg.norm(rows["gaussian"], axis=1)
    assert np.all(block_weight < 0.5) and np.ptp(block_weight) < 1e-9  # every inlier loses weight too


def _stacked_scenario(seed: int = 5):
    """Three poses, four blocks: two cameras on (0, 2), one on (1, 2), one Plücker camera pair on (0, 1)."""
    rng = np.random.default_rng(seed)
    poses = [random_pose(rng, 0.3, 3.0) for _ in range(3)]
    cameras = [_camera(0.0, 0.2, [2.5, 0.0, 2.5]), _camera(1.6, 0.1, [1.5, 1.2, 2.6])]
    from factors import EpipolarBlock

    blocks = []
    for key_i, key_j, camera_i, camera_j, count in ((0, 2, 0, 0, 12), (0, 2, 1, 1, 9), (1, 2, 0, 0, 7), (0, 1, 0, 1, 5)):
        T_i_j = poses[key_i].between(poses[key_j]).matrix()
        bearings_i, bearings_j = _two_camera_bearings(rng, T_i_j, cameras[camera_i], cameras[camera_j], count)
        bearings_j = bearings_j + rng.normal(0.0, 2e-3, bearings_j.shape)  # noisy: non-zero residuals
        blocks.append(EpipolarBlock(key_i, key_j, body_correspondences(cameras[camera_i], bearings_i, bearings_j, cameras[camera_j])))
    return poses, cameras, blocks


def _hessian(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys) -> tuple[np.ndarray, np.ndarray]:
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    return graph.linearize(values).hessian(ordering)


def _graph(*factors) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    for factor in factors:
        graph.add(factor)
    return graph


def _per_block_graph(stacked, poses, huber_k):
    graph = gtsam.NonlinearFactorGraph()
    residuals = []
    for block in stacked.blocks:
        c = block.correspondences
        residuals.append(epipolar_error(poses[block.key_i], poses[block.key_j], c)[0])
        T_i, T_j = make_pose(np.eye(3), c.center_i), make_pose(np.eye(3), c.center_j)  # body-frame inputs
        graph.add(GeneralizedEpipolarFactor(block.key_i, block.key_j, T_i, c.bearings_i, c.bearings_j, robust_noise(SIGMA, len(c), huber_k), T_j))
    return graph, np.concatenate(residuals)


def test_stacked_factor_has_the_linear_system_of_one_factor_per_block():
    """Gaussian: the compressed factor (6 rows per keyframe pair + 1) gives exactly the error,
    information matrix and gradient of one GeneralizedEpipolarFactor per block."""
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario()
    values = _values(*poses)
    stacked = StackedEpipolarFactor(blocks, SIGMA, huber_k=None)
    assert stacked.keys() == [0, 2, 1] and stacked.dim() == 6 * 3 + 1
    assert len(stacked) == sum(len(block.correspondences) for block in blocks)
    graph, residuals = _per_block_graph(stacked, poses, None)
    assert stacked.error(values) == pytest.approx(0.5 * np.sum((residuals / SIGMA) ** 2), rel=1e-10)
    information_stacked, gradient_stacked = _hessian(_graph(stacked), values, (0, 1, 2))
    information_blocks, gradient_blocks = _hessian(graph, values, (0, 1, 2))
    scale = np.max(np.abs(information_blocks))
    np.testing.assert_allclose(information_stacked, information_blocks, atol=1e-9 * scale)
    np.testing.assert_allclose(gradient_stacked, gradient_blocks, atol=1e-9 * np.max(np.abs(gradient_blocks)))


def test_stacked_factor_robust_cost_is_the_sum_of_huber_losses_with_huber_gradient():
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=11)
    values = _values(*poses)
    huber_k = 1.0
    stacked = StackedEpipolarFactor(blocks, SIGMA, huber_k=huber_k)
    graph, residuals = _per_block_graph(stacked, poses, huber_k)
    whitened = np.abs(residuals / SIGMA)
    assert np.any(whitened > huber_k) and np.any(whitened < huber_k)
    huber = np.where(whitened <= huber_k, 0.5 * whitened**2, huber_k * whitened - 0.5 * huber_k**2)
    assert stacked.error(values) == pytest.approx(np.sum(huber), rel=1e-10)
    _, gradient_stacked = _hessian(_graph(stacked), values, (0, 1, 2))
    _, gradient_blocks = _hessian(graph, values, (0, 1, 2))  # gtsam per-residual Huber: same gradient
    np.testing.assert_allclose(gradient_stacked, gradient_blocks, atol=1e-9 * np.max(np.abs(gradient_blocks)))


def _assert_gradient_matches_numerical(factor, values: gtsam.Values, poses, relative: float | None = None) -> None:
    """The factor's gradient (its linearisation's ``J^T r``) against numerical derivatives of its error
    per pose: to ``rtol`` 1e-4, or with ``relative`` to that fraction of the largest derivative."""
    matrix, rhs = factor.linearize(values).jacobian()
    gradient = -matrix.T @ rhs  # d error / d xi = J^T r (gtsam's rhs is -r)
    for position, key in enumerate(factor.keys()):
        def error_of(pose, key=key):
            moved = gtsam.Values(values)
            moved.update(key, pose)
            return np.array([factor.error(moved)])

        numeric = numericalDerivative11(error_of, poses[key], 1e-6)
        if relative is None:
            assert_jacobian_close(gradient[None, 6 * position:6 * position + 6], numeric, rtol=1e-4)
        else:
            np.testing.assert_allclose(gradient[6 * position:6 * position + 6], numeric[0], atol=relative * np.max(np.abs(numeric)))


def test_stacked_factor_gradient_matches_numerical_derivative_of_its_error():
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=9)
    factor = StackedEpipolarFactor(blocks, [SIGMA, 2 * SIGMA, SIGMA, 1.5 * SIGMA], huber_k=1.345)
    values = _values(*poses)
    _assert_gradient_matches_numerical(factor, values, poses)


def _moved(poses, steps):
    """Each pose times ``Exp(step)`` (right perturbation, GTSAM's retract)."""
    return [pose.retract(np.asarray(step, dtype=float)) for pose, step in zip(poses, steps)]


def test_stacked_factor_relinearisation_gives_its_gauss_newton_model_below_the_threshold():
    """With ``relinearize_threshold``: at a point whose keyframe pairs moved less than it, the factor
    returns the linear model of its last full evaluation (``r0 + J0 xi``: exactly what
    ``linearize`` at that evaluation predicts), its cost within second order of the exact one; a
    motion of the whole window leaves it at ``r0``; beyond the threshold it is evaluated anew,
    bitwise as a factor without the threshold."""
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=9)
    mounts = [np.radians(0.05), np.radians(0.1), np.radians(0.2), np.radians(0.1)]
    exact = StackedEpipolarFactor(blocks, SIGMA, huber_k=1.345, mount_sigmas=mounts)
    fluid = StackedEpipolarFactor(blocks, SIGMA, huber_k=1.345, mount_sigmas=mounts, relinearize_threshold=1e-4)
    values = _values(*poses)
    r0 = fluid.unwhitenedError(values)
    np.testing.assert_array_equal(r0, exact.unwhitenedError(values))
    matrix, rhs = fluid.linearize(values).jacobian()  # keys in the factor's order [0, 2, 1]
    np.testing.assert_allclose(-rhs, r0, rtol=1e-12)  # Unit noise: the rows are the residual

    steps = [[3e-5, -2e-5, 1e-5, 2e-5, -3e-5, 1e-5], [-2e-5, 1e-5, 2e-5, -1e-5, 2e-5, 3e-5], [1e-5, 3e-5, -2e-5, 2e-5, 1e-5, -2e-5]]
    steps = 0.2 * np.array(steps)  # a few 1e-6: the pairs' relative motions move by less than 1e-4 (poses metres apart)
    small = _moved(poses, steps)
    model = fluid.unwhitenedError(_values(*small))
    xi = np.concatenate([steps[key] for key in fluid.keys()])
    np.testing.assert_allclose(model, r0 + matrix @ xi, atol=1e-6 * np.max(np.abs(r0)))
    # the cost (the compressed rows' basis is not comparable between points): the step changed it
    # measurably, and the model's follows the exact one (to the 3 % of the mounts' Kaufman gradient)
    error_0, error_true = exact.error(values), exact.error(_values(*small))
    assert abs(error_true - error_0) > 1e-4 * error_0
    assert fluid.error(_values(*small)) == pytest.approx(error_true, abs=0.05 * abs(error_true - error_0))
    # Gaussian rigid rows (an exact gradient): the model misses only the rows' curvature, O(xi^2)
    gaussian, gaussian_fluid = (StackedEpipolarFactor(blocks, SIGMA, huber_k=None, relinearize_threshold=threshold) for threshold in (0.0, 1e-4))
    gaussian_fluid.error(values)
    misses = []
    for fraction in (1.0, 0.5):
        moved = _values(*_moved(poses, fraction * steps))
        misses.append(abs(gaussian_fluid.error(moved) - gaussian.error(moved)))
    assert misses[1] < misses[0] / 3.0 and misses[0] < 0.01 * abs(gaussian.error(_values(*small)) - gaussian.error(values))
    _assert_gradient_matches_numerical(fluid, _values(*small), small, relative=1e-3)  # its Jacobians: the model's

    window = gtsam.Pose3(gtsam.Rot3.Rz(0.3), np.array([5.0, -2.0, 0.4]))
    shifted = [window.compose(pose) for pose in poses]  # the whole window moved: no pair's motion changed
    np.testing.assert_allclose(fluid.unwhitenedError(_values(*shifted)), r0, atol=1e-9 * np.max(np.abs(r0)))

    large = _moved(poses, [[0.0] * 6, [0.0, 0.0, 2e-3, 0.0, 0.0, 0.0], [0.0] * 6])
    np.testing.assert_array_equal(fluid.unwhitenedError(_values(*large)), exact.unwhitenedError(_values(*large)))
    with pytest.raises(ValueError, match="relinearize_threshold"):
        StackedEpipolarFactor(blocks, SIGMA, relinearize_threshold=-1.0)


def test_stacked_factor_rejects_bad_input():
    from factors import StackedEpipolarFactor

    _, _, blocks = _stacked_scenario()
    with pytest.raises(ValueError):
        StackedEpipolarFactor([], SIGMA)
    with pytest.raises(ValueError):
        StackedEpipolarFactor(blocks, [SIGMA])
    with pytest.raises(ValueError):
        StackedEpipolarFactor(blocks, -1.0)
    with pytest.raises(ValueError, match="mount_sigmas"):
        StackedEpipolarFactor(blocks, SIGMA, mount_sigmas=[0.001, 0.001])
    with pytest.raises(ValueError, match="mount_sigmas"):
        StackedEpipolarFactor(blocks, SIGMA, mount_sigmas=0.0)


def test_evaluation_cache_returns_identical_results_and_follows_value_changes():
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=3)
    factor = StackedEpipolarFactor(blocks, SIGMA)
    values = _values(*poses)
    first = factor.unwhitenedError(values)
    np.testing.assert_array_equal(factor.unwhitenedError(values), first)
    moved = gtsam.Values(values)
    moved.update(2, poses[2].retract(np.full(6, 1e-3)))
    changed = factor.unwhitenedError(moved)
    assert np.max(np.abs(changed - first)) > 1e-6
    fresh = StackedEpipolarFactor(blocks, SIGMA)
    np.testing.assert_array_equal(fresh.unwhitenedError(moved), changed)
    np.testing.assert_array_equal(factor.unwhitenedError(values), first)


# ---------------------------------------------------------------------- rolling shutter: one centre per ray
def _rolling_shutter_block(rng, T_i_j, T_body_camera, count=25, speed=15.0, yaw_rate=0.2, readout=0.03):
    """Points seen by one camera whose rows are exposed at different times: row r of view i at
    ``readout r``, on a body moving at ``speed`` along x and turning at ``yaw_rate``. Returns the
    per-row extrinsics of both views and the camera-frame bearings seen from them."""
    from ampc_vo.backend.smoother import planar_motions

    twist = np.array([0.0, 0.0, yaw_rate, speed, 0.0, 0.0])
    points_i = rng.uniform([10.0, -20.0, -2.0], [40.0, 20.0, 8.0], (count, 3))
    rows_i, rows_j = rng.uniform(0.0, 1.0, count), rng.uniform(0.0, 1.0, count)
    extrinsics = []
    bearings = []
    for rows, points in ((rows_i, points_i), (rows_j, (points_i - T_i_j[:3, 3]) @ T_i_j[:3, :3])):
        motions, shifts = planar_motions(twist, readout * rows)
        rotations = motions @ T_body_camera[:3, :3]
        centers = motions @ T_body_camera[:3, 3] + shifts
        in_camera = np.einsum("nba,nb->na", rotations, points - centers)
        extrinsics.append((rotations, centers))
        bearings.append(in_camera / np.linalg.norm(in_camera, axis=1, keepdims=True))
    return extrinsics, bearings


def test_per_row_centres_are_zero_at_the_truth_where_one_extrinsic_is_not():
    """A rolling-shutter camera on a truck at 15 m/s: with each row's own extrinsic the GEC is zero at
    the true motion, with the image's one extrinsic it is not (0.45 m of travel over the readout)."""
    from factors import EpipolarBlock, StackedEpipolarFactor, body_correspondences_per_row

    rng = np.random.default_rng(4)
    T_world_i = random_pose(rng, 0.1, 5.0)
    T_i_j = make_pose(rot_z(0.02), np.array([1.5, 0.02, 0.0]))
    T_world_j = T_world_i.compose(gtsam.Pose3(T_i_j))
    camera = _camera(0.0, 0.1, [2.0, 0.3, 2.5])
    (rows_i, rows_j), (bearings_i, bearings_j) = _rolling_shutter_block(rng, T_i_j, camera)
    per_row = body_correspondences_per_row(rows_i[0], rows_i[1], bearings_i, rows_j[0], rows_j[1], bearings_j)
    assert per_row.center_i.shape == (25, 3)
    values = _values(T_world_i, T_world_j)
    exact = StackedEpipolarFactor([EpipolarBlock(0, 1, per_row)], SIGMA, huber_k=None)
    one = StackedEpipolarFactor([EpipolarBlock(0, 1, body_correspondences(camera, bearings_i, bearings_j))], SIGMA, huber_k=None)
    assert exact.error(values) < 1e-16
    assert one.error(values) > 1.0  # more than a sigma's worth of residual per block
    with pytest.raises(ValueError, match="StackedEpipolarFactor"):
        epipolar_error(T_world_i, T_world_j, per_row)
    with pytest.raises(ValueError, match="centers_j"):
        body_correspondences_per_row(rows_i[0], rows_i[1], bearings_i, rows_j[0], rows_j[1][:3], bearings_j)


def test_stacked_factor_with_per_row_centres_matches_numerical_derivatives():
    """The per-row centres (rolling shutter) beside ordinary blocks: the Jacobians of the compressed
    factor against numerical derivatives of its error."""
    from factors import EpipolarBlock, StackedEpipolarFactor, body_correspondences_per_row

    poses, cameras, blocks = _stacked_scenario(seed=13)
    rng = np.random.default_rng(13)
    T_i_j = poses[0].between(poses[2]).matrix()
    (rows_i, rows_j), (bearings_i, bearings_j) = _rolling_shutter_block(rng, T_i_j, cameras[1], count=11)
    bearings_j = bearings_j + rng.normal(0.0, 2e-3, bearings_j.shape)
    per_row = body_correspondences_per_row(rows_i[0], rows_i[1], bearings_i, rows_j[0], rows_j[1], bearings_j)
    factor = StackedEpipolarFactor(blocks + [EpipolarBlock(0, 2, per_row)], SIGMA, huber_k=1.345)
    values = _values(*poses)
    baselines = per_row.center_j @ T_i_j[:3, :3].T + T_i_j[:3, 3] - per_row.center_i  # one per row
    assert np.linalg.norm(baselines, axis=1).min() > 1.0 and np.ptp(baselines, axis=0).max() > 0.1
    _assert_gradient_matches_numerical(factor, values, poses)


# ---------------------------------------------------------------------- gec_sampson_pairs_jacobian vs reference
def _reference_pairs_jacobian(bearings_i, bearings_j, rotations, translations, centers_i, centers_j, pair_starts, jacobian=True):
    """Straightforward row-major implementation of ampc_vo.epipolar.gec_sampson_pairs_jacobian
    (its code before the component-major rewrite), the reference for equality to rounding."""
    def cross(a, b):
        return np.cross(a, b)

    def rowdot(a, b):
        return np.sum(a * b, axis=1)

    bounds = [int(start) for start in pair_starts] + [bearings_i.shape[0]]
    rotated_j = np.empty_like(bearings_j)
    rotated_center = np.empty_like(centers_j)
    offsets = np.empty_like(centers_j)
    for rotation, translation, start, stop in zip(rotations, translations, bounds[:-1], bounds[1:]):
        rotated_j[start:stop] = bearings_j[start:stop] @ rotation.T
        rotated_center[start:stop] = centers_j[start:stop] @ rotation.T
        offsets[start:stop] = translation
    baseline = rotated_center + offsets - centers_i
    grad_f = cross(rotated_j, baseline)
    grad_g = cross(baseline, bearings_i)
    residual = rowdot(bearings_i, grad_f)
    tangent_f = grad_f - residual[:, None] * bearings_i
    tangent_g = grad_g - rowdot(grad_g, rotated_j)[:, None] * rotated_j
    norm = np.sqrt(rowdot(tangent_f, tangent_f) + rowdot(tangent_g, tangent_g))
    clamped = np.maximum(norm, 1e-12)
    sampson = residual / clamped
    if not jacobian:
        return sampson, None
    inv_norm = (norm >= 1e-12) / clamped
    s_over_n = sampson * inv_norm
    s_over_n2 = s_over_n * inv_norm
    alpha = (1.0 + 2.0 * s_over_n * residual) * inv_norm
    g_dot_d = rowdot(rotated_j, baseline)
    f_dot_d = rowdot(bearings_i, baseline)
    g_dot_f = rowdot(rotated_j, bearings_i)
    s_g_dot_d = (s_over_n2 * g_dot_d)[:, None]
    gradients = np.empty((residual.shape[0], 2, 3))
    gradients[:, 0] = (alpha * g_dot_f)[:, None] * baseline - (alpha * g_dot_d)[:, None] * bearings_i + s_g_dot_d * grad_f
    gradients[:, 1] = (
        alpha[:, None] * cross(bearings_i, rotated_j)
        + s_g_dot_d * rotated_j
        + (s_over_n2 * f_dot_d)[:, None] * bearings_i
        - (2.0 * s_over_n2)[:, None] * baseline
    )
    local = np.empty_like(gradients)
    for rotation, start, stop in zip(rotations, bounds[:-1], bounds[1:]):
        local[start:stop] = gradients[start:stop] @ rotation
    result = np.empty((residual.shape[0], 6))
    result[:, :3] = local[:, 0] + cross(centers_j, local[:, 1])
    result[:, 3:] = local[:, 1]
    return sampson, result


def _pairs_inputs(rng, count, pairs):
    def unit(vectors):
        return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)

    rotations = np.array([random_pose(rng, 1.0, 1.0).rotation().matrix() for _ in range(pairs)])
    translations = rng.normal(0.0, 2.0, (pairs, 3))
    centers_i = rng.normal(0.0, 3.0, (count, 3))
    centers_j = np.where(rng.random((count, 1)) < 0.5, centers_i, rng.normal(0.0, 3.0, (count, 3)))  # both forms
    starts = np.sort(np.concatenate([[0], rng.choice(np.arange(1, count), pairs - 1, replace=False)]))
    return unit(rng.normal(size=(count, 3))), unit(rng.normal(size=(count, 3))), rotations, translations, centers_i, centers_j, starts


def _assert_close_to_rounding(actual, expected):
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12 * np.max(np.abs(expected)))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("count, pairs", [(1, 1), (20, 1), (150, 1), (340, 2), (600, 5)])
def test_pairs_jacobian_equals_reference_implementation(seed, count, pairs):
    from ampc_vo.epipolar import gec_sampson_pairs_jacobian

    args = _pairs_inputs(np.random.default_rng(seed), count, pairs)
    sampson, jacobian = gec_sampson_pairs_jacobian(*args)
    expected_sampson, expected_jacobian = _reference_pairs_jacobian(*args)
    assert jacobian.shape == (count, 6) and jacobian.flags.c_contiguous
    _assert_close_to_rounding(sampson, expected_sampson)
    _assert_close_to_rounding(jacobian, expected_jacobian)
    only, none = gec_sampson_pairs_jacobian(*args, jacobian=False)
    assert none is None
    np.testing.assert_array_equal(only, sampson)


@pytest.mark.parametrize("seed", range(3))
def test_pairs_bearing_jacobian_matches_numerical_derivative_of_turning_view_j_bearings(seed):
    """``bearing_jacobian``: the derivative w.r.t. a rotation ``f' -> Exp(epsilon) f'`` of view j's
    bearings alone (the camera mount rotation), central differences; it is the motion Jacobian's
    rotation part without the lever arm ``c_j x (ds/dd R)``, and the other outputs are unchanged."""
    from ampc_vo.epipolar import gec_sampson_pairs_jacobian

    bearings_i, bearings_j, rotations, translations, centers_i, centers_j, starts = _pairs_inputs(np.random.default_rng(seed), 60, 2)
    args = (bearings_i, bearings_j, rotations, translations, centers_i, centers_j, starts)
    sampson, jacobian, bearing_jacobian = gec_sampson_pairs_jacobian(*args, bearing_jacobian=True)
    plain_sampson, plain_jacobian = gec_sampson_pairs_jacobian(*args)
    np.testing.assert_array_equal(sampson, plain_sampson)
    np.testing.assert_array_equal(jacobian, plain_jacobian)
    step = 1e-6
    numerical = np.zeros((len(sampson), 3))
    for axis in range(3):
        turn = np.zeros(3)
        turn[axis] = step
        plus = gec_sampson_pairs_jacobian(bearings_i, bearings_j @ gtsam.Rot3.Expmap(turn).matrix().T, *args[2:], jacobian=False)[0]
        minus = gec_sampson_pairs_jacobian(bearings_i, bearings_j @ gtsam.Rot3.Expmap(-turn).matrix().T, *args[2:], jacobian=False)[0]
        numerical[:, axis] = (plus - minus) / (2 * step)
    np.testing.assert_allclose(bearing_jacobian, numerical, rtol=1e-5, atol=1e-7 * np.max(np.abs(numerical)))
    lever_arm = np.cross(centers_j, jacobian[:, 3:])
    np.testing.assert_allclose(bearing_jacobian, jacobian[:, :3] - lever_arm, rtol=1e-9, atol=1e-12 * np.max(np.abs(jacobian)))


def test_pairs_jacobian_zero_baseline_rows_match_reference_and_one_pair_form():
    from ampc_vo.epipolar import gec_sampson_pairs_jacobian

    rng = np.random.default_rng(4)
    bearings_i, bearings_j, rotations, translations, centers_i, centers_j, starts = _pairs_inputs(rng, 40, 2)
    # pair 1: zero translation and common centres -> zero baseline: residual 0, Jacobian 0
    translations[1] = 0.0
    centers_i[starts[1]:] = 0.0
    centers_j[starts[1]:] = 0.0
    args = (bearings_i, bearings_j, rotations, translations, centers_i, centers_j, starts)
    sampson, jacobian = gec_sampson_pairs_jacobian(*args)
    expected_sampson, expected_jacobian = _reference_pairs_jacobian(*args)
    assert np.all(np.isfinite(jacobian))
    np.testing.assert_array_equal(jacobian[starts[1]:], 0.0)
    _assert_close_to_rounding(sampson, expected_sampson)
    _assert_close_to_rounding(jacobian, expected_jacobian)
    # pair 0 alone, one shared centre: gec_sampson_jacobian's values
    stop = starts[1]
    single, single_jacobian = gec_sampson_jacobian(bearings_i[:stop], bearings_j[:stop], rotations[0], translations[0], centers_i[0], centers_j[0])
    shared = gec_sampson_pairs_jacobian(
        bearings_i[:stop], bearings_j[:stop], rotations[:1], translations[:1],
        np.tile(centers_i[0], (stop, 1)), np.tile(centers_j[0], (stop, 1)), np.array([0]),
    )
    _assert_close_to_rounding(shared[0], single)
    _assert_close_to_rounding(shared[1], single_jacobian)


# ---------------------------------------------------------------------- camera mounts: a marginalised rotation per block
def _augmented_mount_system(blocks, poses, mount_sigma):
    """Information and gradient (gtsam's ``eta = -J^T r``) over the three poses and the error of
    the GEC rows with an explicit rotation ``epsilon`` of view j's bearings per block (numerical
    derivatives, prior ``N(0, mount_sigma^2)``), the rotations eliminated by a dense Schur complement."""
    from dataclasses import replace

    columns = 6 * len(poses) + 3 * len(blocks)
    jacobian_rows, residual_rows = [], []
    for number, block in enumerate(blocks):
        def rows(pose_i, pose_j, epsilon, block=block):
            turned = replace(block.correspondences, bearings_j=block.correspondences.bearings_j @ gtsam.Rot3.Expmap(epsilon).matrix().T)
            return epipolar_error(pose_i, pose_j, turned)[0] / SIGMA

        pose_i, pose_j, zero = poses[block.key_i], poses[block.key_j], np.zeros(3)
        jacobian = np.zeros((len(block.correspondences), columns))
        jacobian[:, 6 * block.key_i:6 * block.key_i + 6] = numericalDerivative11(lambda pose: rows(pose, pose_j, zero), pose_i, 1e-6)
        jacobian[:, 6 * block.key_j:6 * block.key_j + 6] = numericalDerivative11(lambda pose: rows(pose_i, pose, zero), pose_j, 1e-6)
        start = 6 * len(poses) + 3 * number
        for axis in range(3):
            step = np.zeros(3)
            step[axis] = 1e-7
            jacobian[:, start + axis] = (rows(pose_i, pose_j, step) - rows(pose_i, pose_j, -step)) / 2e-7
        prior = np.zeros((3, columns))
        prior[:, start:start + 3] = np.eye(3) / mount_sigma
        jacobian_rows += [jacobian, prior]
        residual_rows += [rows(pose_i, pose_j, zero), np.zeros(3)]
    jacobian, residual = np.vstack(jacobian_rows), np.concatenate(residual_rows)
    information, eta = jacobian.T @ jacobian, -jacobian.T @ residual
    poses_part, mount_part = slice(0, 6 * len(poses)), slice(6 * len(poses), columns)
    inverse = np.linalg.inv(information[mount_part, mount_part])
    schur = information[poses_part, poses_part] - information[poses_part, mount_part] @ inverse @ information[mount_part, poses_part]
    reduced_eta = eta[poses_part] - information[poses_part, mount_part] @ inverse @ eta[mount_part]
    error = 0.5 * (residual @ residual - eta[mount_part] @ inverse @ eta[mount_part])
    return schur, reduced_eta, error


def test_mount_rotation_is_marginalised_as_the_schur_complement_of_explicit_rotations():
    """With ``mount_sigmas``, the stacked factor's linear system and error are those of the same rows
    with one explicit rotation of view j's bearings per block (prior sigma), eliminated: an
    independent computation from numerical derivatives of the plain GEC."""
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=17)
    mount_sigma = np.radians(0.1)
    stacked = StackedEpipolarFactor(blocks, SIGMA, huber_k=None, mount_sigmas=mount_sigma)
    values = _values(*poses)
    information, eta = _hessian(_graph(stacked), values, (0, 1, 2))
    expected_information, expected_eta, expected_error = _augmented_mount_system(stacked.blocks, poses, mount_sigma)
    np.testing.assert_allclose(information, expected_information, atol=1e-5 * np.max(np.abs(expected_information)))
    np.testing.assert_allclose(eta, expected_eta, atol=1e-5 * np.max(np.abs(expected_eta)))
    assert stacked.error(values) == pytest.approx(expected_error, rel=1e-5)
    rigid = StackedEpipolarFactor(blocks, SIGMA, huber_k=None)
    assert stacked.error(values) < 0.9 * rigid.error(values)  # the rotations explain part of the noise
    assert np.linalg.norm(information - _hessian(_graph(rigid), values, (0, 1, 2))[0]) > 0.01 * np.linalg.norm(information)


def test_mount_rotation_gradient_matches_numerical_derivative_of_its_error():
    """Huber rows with the mount rotations marginalised: the gradient (Kaufman: the rotations' rows
    held at the current motion) against numerical derivatives of the error, to 3 % (without the
    robust solve of the rotations it was off by a factor of 2)."""
    from factors import StackedEpipolarFactor

    poses, _, blocks = _stacked_scenario(seed=19)
    factor = StackedEpipolarFactor(blocks, SIGMA, huber_k=1.345, mount_sigmas=[np.radians(0.05), np.radians(0.1), np.radians(0.2), np.radians(0.1)])
    _assert_gradient_matches_numerical(factor, _values(*poses), poses, relative=0.03)


def test_mount_rotation_takes_the_scale_out_of_a_turned_camera_on_a_lever_arm():
    """A trailer camera 12 m behind the body origin on a straight 2 m chord while the body pitches by
    0.05 deg (the lever arm lowers the camera by 1 cm), its bracket turned by 0.1 deg between the
    views: with rigid mounts the GEC, evaluated at the true rotation, prefers a wrong chord length (the
    bracket's rotation read as a baseline direction that only another scale explains); with the
    rotation marginalised the true chord is the best."""
    from factors import EpipolarBlock, StackedEpipolarFactor

    rng = np.random.default_rng(23)
    camera = _camera(np.pi, 0.15, [-12.0, 0.0, 2.5])  # looking back from the trailer's rear
    rotation = rot_y(np.radians(0.05))
    T_i_j = make_pose(rotation, np.array([2.0, 0.0, 0.0]))
    points_i = rng.uniform([-60.0, -15.0, -1.2], [-14.0, 15.0, 6.0], (120, 3))
    points_j = (points_i - T_i_j[:3, 3]) @ T_i_j[:3, :3]
    in_camera_i = (points_i - camera[:3, 3]) @ camera[:3, :3]
    turned = camera.copy()
    turned[:3, :3] = camera[:3, :3] @ rot_x(np.radians(0.1)) @ rot_y(np.radians(0.07))
    in_camera_j = (points_j - turned[:3, 3]) @ turned[:3, :3]
    bearings_i, bearings_j = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in (in_camera_i, in_camera_j))
    block = EpipolarBlock(0, 1, body_correspondences(camera, bearings_i, bearings_j))
    sigma = 0.5 / 700.0
    scales = np.array([0.25, 0.5, 1.0, 2.0, 4.0])

    def costs(factor):
        return np.array([factor.error(_values(gtsam.Pose3(), gtsam.Pose3(make_pose(rotation, np.array([2.0 * s, 0.0, 0.0]))))) for s in scales])

    rigid = costs(StackedEpipolarFactor([block], sigma, huber_k=None))
    marginal = costs(StackedEpipolarFactor([block], sigma, huber_k=None, mount_sigmas=np.radians(0.15)))
    assert scales[np.argmin(rigid)] != 1.0
    assert scales[np.argmin(marginal)] == 1.0 and marginal.min() < 0.01 * rigid.min()
