"""Conventions of DESIGN section 1, tested once: frames, pose naming, hitch-angle sign, quaternions."""
import numpy as np
import pytest

from ampc_vo.epipolar import gec_algebraic, gec_sampson
from ampc_vo.errors import BearingError
from ampc_vo.geometry import (
    check_bearings, invert_pose, make_pose, orthonormality_error, planar_pose, pose_from_xyz_quat, pose_to_xyz_quat,
    quat_xyzw_from_rotation, relative_pose, rot_x, rot_y, rot_z, rotation_from_quat_xyzw, rotation_from_vector,
    transform_points, unit_heading, unit_normal, wrap_angle, yaw_of,
)
from ampc_vo.rig import camera_rotation


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    return rot_z(rng.uniform(-np.pi, np.pi)) @ rot_y(rng.uniform(-1.5, 1.5)) @ rot_x(rng.uniform(-np.pi, np.pi))


def test_relative_pose_maps_points_of_view_j_into_view_i():
    rng = np.random.default_rng(0)
    T_world_i = make_pose(random_rotation(rng), rng.normal(size=3))
    T_world_j = make_pose(random_rotation(rng), rng.normal(size=3))
    point_j = rng.normal(size=(5, 3))
    T_i_j = relative_pose(T_world_i, T_world_j)
    expected = transform_points(invert_pose(T_world_i), transform_points(T_world_j, point_j))
    np.testing.assert_allclose(transform_points(T_i_j, point_j), expected, atol=1e-12)


def test_hitch_angle_positive_when_trailer_turned_counter_clockwise():
    # Trailer heading 30 deg left of the tractor, seen from above: theta = yaw_trailer - yaw_tractor > 0.
    T_world_tractor = planar_pose(3.0, 1.0, np.deg2rad(10.0))
    hitch_angle = np.deg2rad(30.0)
    T_world_trailer = T_world_tractor @ make_pose(rot_z(hitch_angle), np.zeros(3))
    assert yaw_of(T_world_trailer) - yaw_of(T_world_tractor) == pytest.approx(hitch_angle)
    # The trailer's x axis (forward) then points to the tractor's left (positive y).
    trailer_forward_in_tractor = (invert_pose(T_world_tractor) @ T_world_trailer)[:3, 0]
    assert trailer_forward_in_tractor[1] > 0


def test_heading_and_normal_vectors():
    angle = 0.3
    np.testing.assert_allclose(unit_heading(angle), rot_z(angle)[:, 0], atol=1e-15)
    np.testing.assert_allclose(unit_normal(angle), rot_z(angle)[:, 1], atol=1e-15)
    assert wrap_angle(np.pi + 0.1) == pytest.approx(-np.pi + 0.1)


def test_quaternion_round_trip_and_layout():
    rng = np.random.default_rng(1)
    for _ in range(200):
        rotation = random_rotation(rng)
        quaternion = quat_xyzw_from_rotation(rotation)
        assert quaternion[3] >= 0 and np.linalg.norm(quaternion) == pytest.approx(1.0)
        np.testing.assert_allclose(rotation_from_quat_xyzw(quaternion), rotation, atol=1e-12)
    # 90 deg about z is (0, 0, sin 45, cos 45) in x y z w order.
    np.testing.assert_allclose(quat_xyzw_from_rotation(rot_z(np.pi / 2)), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    pose = make_pose(random_rotation(rng), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(pose_from_xyz_quat(pose_to_xyz_quat(pose)), pose, atol=1e-12)


def test_forward_camera_looks_along_body_x_with_opencv_axes():
    R_body_camera = camera_rotation(yaw=0.0)
    np.testing.assert_allclose(R_body_camera @ [0, 0, 1], [1, 0, 0], atol=1e-15)  # optical axis forward
    np.testing.assert_allclose(R_body_camera @ [1, 0, 0], [0, -1, 0], atol=1e-15)  # image x to the right
    np.testing.assert_allclose(R_body_camera @ [0, 1, 0], [0, 0, -1], atol=1e-15)  # image y down
    rear = camera_rotation(yaw=np.pi, pitch_down=0.2)
    optical_axis = rear @ [0, 0, 1]
    assert optical_axis[0] < 0 and optical_axis[2] < 0  # looks backwards and down


def test_generalized_epipolar_residual_vanishes_only_at_the_true_motion():
    rng = np.random.default_rng(2)
    T_i_j = make_pose(rot_z(0.1) @ rot_x(0.02), [1.0, 0.1, 0.05])
    center_i, center_j = np.array([2.0, 0.5, 1.5]), np.array([2.0, -0.5, 1.5])
    points_i = rng.uniform([5, -10, -2], [30, 10, 5], size=(50, 3))
    points_j = transform_points(invert_pose(T_i_j), points_i)
    bearings_i = check_bearings(points_i - center_i)
    bearings_j = check_bearings(points_j - center_j)
    # Two different cameras (Plücker form) and one camera (c_i == c_j) both vanish at the truth.
    same_camera_j = check_bearings(points_j - center_i)
    assert np.max(np.abs(gec_sampson(bearings_i, same_camera_j, T_i_j[:3, :3], T_i_j[:3, 3], center_i))) < 1e-12
    assert np.max(np.abs(gec_sampson(bearings_i, bearings_j, T_i_j[:3, :3], T_i_j[:3, 3], center_i, center_j))) < 1e-12
    wrong = gec_sampson(bearings_i, bearings_j, T_i_j[:3, :3], T_i_j[:3, 3] + [0, 0.3, 0], center_i, center_j)
    assert np.median(np.abs(wrong)) > 1e-3
    # Broadcasting over hypotheses gives the same numbers as one call each.
    rotations = np.stack([T_i_j[:3, :3], rot_z(0.2)])
    translations = np.stack([T_i_j[:3, 3], np.array([1.0, 0.0, 0.0])])
    batched = gec_algebraic(bearings_i, bearings_j, rotations, translations, center_i, center_j)
    single = gec_algebraic(bearings_i, bearings_j, rot_z(0.2), np.array([1.0, 0.0, 0.0]), center_i, center_j)
    np.testing.assert_allclose(batched[1], single, atol=1e-14)


def test_sampson_residual_approximates_angular_error():
    rng = np.random.default_rng(3)
    T_i_j = make_pose(rot_z(0.05), [1.0, 0.0, 0.0])
    center = np.array([0.0, 1.0, 1.0])
    points_i = rng.uniform([5, -10, -2], [30, 10, 5], size=(200, 3))
    bearings_i = check_bearings(points_i - center)
    bearings_j = check_bearings(transform_points(invert_pose(T_i_j), points_i) - center)
    sigma = 1e-3  # radians
    noisy_j = check_bearings(bearings_j + rng.normal(scale=sigma, size=bearings_j.shape))
    residual = gec_sampson(bearings_i, noisy_j, T_i_j[:3, :3], T_i_j[:3, 3], center)
    # Noise on one bearing only, two tangent components: the residual's spread is about sigma.
    assert 0.3 * sigma < np.std(residual) < 1.5 * sigma


@pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.array([[0.0, 0.0, 0.0]]), np.array([[np.nan, 0, 1.0]])])
def test_check_bearings_rejects_bad_input(bad):
    with pytest.raises(BearingError):
        check_bearings(bad)


def test_rays_hit_box_slab_test():
    """Rays from outside meet a unit box ahead, miss it beside and behind; a ray from inside meets it."""
    from ampc_vo.geometry import rays_hit_box

    lower, upper = np.array([2.0, -0.5, -0.5]), np.array([3.0, 0.5, 0.5])
    directions = np.array([[1.0, 0.0, 0.0], [1.0, 0.2, 0.0], [1.0, 0.3, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.2]])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    np.testing.assert_array_equal(rays_hit_box(np.zeros(3), directions, lower, upper), [True, True, False, False, False, True])
    assert rays_hit_box(np.array([2.5, 0.0, 0.0]), directions, lower, upper).all()


@pytest.mark.parametrize("vector", [(0.0, 0.0, 0.0), (1e-9, -2e-9, 3e-9), (0.3, -0.2, 0.1), (0.0, 0.0, np.pi - 1e-3)])
def test_rotation_from_vector_matches_scipy_and_rot_z(vector):
    from scipy.spatial.transform import Rotation

    rotation = rotation_from_vector(np.array(vector))
    np.testing.assert_allclose(rotation, Rotation.from_rotvec(vector).as_matrix(), atol=1e-12)
    assert orthonormality_error(rotation) < 1e-12
    np.testing.assert_allclose(rotation_from_vector(np.array([0.0, 0.0, 0.7])), rot_z(0.7), atol=1e-12)
