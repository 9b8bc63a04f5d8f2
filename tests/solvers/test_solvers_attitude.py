"""Tests of the tractor motion with a body attitude change (ampc_vo.solvers.attitude, DESIGN 2.1):
pitch over a bump or under braking that no planar motion fits."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ampc_vo.geometry import make_pose
from ampc_vo.solvers import RansacConfig, SolverStatus, estimate_tractor_motion
from ampc_vo.solvers.attitude import attitude_motion, attitude_rotations, estimate_attitude_motion
from ampc_vo.solvers.estimates import as_groups, attitude_compensated_parallax, median_parallax

AXLE_X = -0.3
# a cab camera and two mirror cameras looking back along the sides (tractor frame, metres)
CAMERA_CENTERS = (np.array([1.5, 0.0, 1.4]), np.array([1.0, 1.3, 1.0]), np.array([1.0, -1.3, 1.0]))
CAMERA_AXES = (np.array([1.0, 0.0, -0.05]), np.array([-1.0, 0.3, -0.1]), np.array([-1.0, -0.3, -0.1]))
FOCAL_PX = 500.0


def _correspondences(rng: np.random.Generator, T_i_j: np.ndarray, count: int = 150, noise_px: float = 0.5, outliers: float = 0.1) -> list:
    """Per camera, body-frame bearings of ``count`` static points 4-40 m away in view i and j
    (``p_i = R p_j + t``), with pixel-like noise and a share of random outliers in view j."""
    groups = []
    R, t = T_i_j[:3, :3], T_i_j[:3, 3]
    for center, axis in zip(CAMERA_CENTERS, CAMERA_AXES):
        axis = axis / np.linalg.norm(axis)
        directions = axis + 0.35 * rng.normal(size=(count, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        points_i = center + directions * rng.uniform(4.0, 40.0, (count, 1))
        points_j = (points_i - t) @ R
        bearings_i = points_i - center
        bearings_j = points_j - center
        bearings_i = bearings_i / np.linalg.norm(bearings_i, axis=1, keepdims=True) + rng.normal(0.0, noise_px / FOCAL_PX, (count, 3))
        bearings_j = bearings_j / np.linalg.norm(bearings_j, axis=1, keepdims=True) + rng.normal(0.0, noise_px / FOCAL_PX, (count, 3))
        bad = rng.random(count) < outliers
        bearings_j[bad] = bearings_j[bad] + rng.normal(0.0, 0.05, (int(bad.sum()), 3))
        bearings_i /= np.linalg.norm(bearings_i, axis=1, keepdims=True)
        bearings_j /= np.linalg.norm(bearings_j, axis=1, keepdims=True)
        groups.append((bearings_i, bearings_j, center))
    return groups


def test_attitude_rotation_is_pitch_then_roll_about_the_body_axes() -> None:
    pitch, roll = np.radians(1.3), np.radians(-0.7)
    expected = Rotation.from_euler("YX", [pitch, roll]).as_matrix()
    np.testing.assert_allclose(attitude_rotations(pitch, roll), expected, atol=1e-12)
    batch = attitude_rotations(np.array([pitch, 0.0]), np.array([roll, 0.0]))
    np.testing.assert_allclose(batch[1], np.eye(3), atol=1e-12)
    rotation, translation = attitude_motion(0.02, 1.5, pitch, roll, AXLE_X)
    np.testing.assert_allclose(rotation, Rotation.from_euler("ZYX", [0.02, pitch, roll]).as_matrix(), atol=1e-12)
    assert translation[0] == pytest.approx(1.5 * np.cos(0.01) + AXLE_X * (1 - np.cos(0.02)))


@pytest.mark.parametrize("pitch_deg, roll_deg", [(1.0, 0.0), (-1.2, 0.3), (0.6, -0.5)])
def test_a_pitched_pair_is_found_where_no_planar_motion_fits(pitch_deg: float, roll_deg: float) -> None:
    """A 2 m chord with a pitch change of a degree (a bump, braking): the planar RANSAC explains
    few tracks (< 40 %); with the attitude search the pitch and roll come back within 0.1 degree,
    the yaw within 0.05 degree and 80 % of the tracks are inliers (status scale-unobservable with
    the prior's chord: the chord trades off against the attitude)."""
    rng = np.random.default_rng(int(10 * pitch_deg + 100 * roll_deg) % 997)
    yaw, chord = np.radians(0.4), 2.0
    rotation, translation = attitude_motion(yaw, chord, np.radians(pitch_deg), np.radians(roll_deg), AXLE_X)
    groups = _correspondences(rng, make_pose(rotation, translation))
    total = sum(len(group[0]) for group in groups)
    threshold = 2.0 / FOCAL_PX
    planar = estimate_tractor_motion(groups, AXLE_X, RansacConfig(sampson_threshold=threshold), chord_prior=chord)
    assert planar.num_inliers < 0.4 * total
    config = RansacConfig(sampson_threshold=threshold, max_attitude_change=np.radians(2.0), attitude_fraction=0.6)
    found = estimate_tractor_motion(groups, AXLE_X, config, chord_prior=chord)
    assert found.status is SolverStatus.SCALE_UNOBSERVABLE and found.chord == pytest.approx(chord)
    assert np.degrees(abs(found.attitude[0] - np.radians(pitch_deg))) < 0.1
    assert np.degrees(abs(found.attitude[1] - np.radians(roll_deg))) < 0.1
    assert np.degrees(abs(found.yaw_change - yaw)) < 0.05
    assert found.num_inliers > 0.8 * total
    np.testing.assert_allclose(found.T_i_j[:3, :3], rotation, atol=np.radians(0.1))


def test_a_planar_pair_keeps_its_planar_estimate() -> None:
    """Where the planar motion explains the tracks, the attitude search is not run: the result is
    the planar RANSAC's, chord measured."""
    rng = np.random.default_rng(5)
    yaw, chord = np.radians(4.0), 2.0
    groups = _correspondences(rng, make_pose(*attitude_motion(yaw, chord, 0.0, 0.0, AXLE_X)))
    threshold = 2.0 / FOCAL_PX
    planar = estimate_tractor_motion(groups, AXLE_X, RansacConfig(sampson_threshold=threshold))
    with_search = estimate_tractor_motion(groups, AXLE_X, RansacConfig(sampson_threshold=threshold, max_attitude_change=np.radians(2.0)))
    assert with_search.status is planar.status is SolverStatus.OK
    assert with_search.chord == planar.chord and with_search.attitude == (0.0, 0.0)
    assert abs(with_search.chord - chord) < 0.1


def test_the_search_refines_all_four_parameters_when_the_chord_is_free() -> None:
    rng = np.random.default_rng(8)
    yaw, chord, pitch, roll = np.radians(3.0), 1.5, np.radians(0.8), np.radians(-0.4)
    groups = as_groups(_correspondences(rng, make_pose(*attitude_motion(yaw, chord, pitch, roll, AXLE_X)), noise_px=0.2, outliers=0.0))
    found = estimate_attitude_motion(groups, [(0.0, 1.2)], AXLE_X, 2.0 / FOCAL_PX, np.radians(2.0))
    assert found is not None and not found.chord_fixed and found.covariance.shape == (4, 4)
    assert abs(found.chord - chord) < 0.15 and np.degrees(abs(found.pitch - pitch)) < 0.05 and np.degrees(abs(found.roll - roll)) < 0.05
    assert found.inliers.mean() > 0.95
    assert estimate_attitude_motion(groups, [], AXLE_X, 2.0 / FOCAL_PX, np.radians(2.0)) is None


def test_no_attitude_search_for_a_truck_predicted_at_rest() -> None:
    """A chord fixed near zero fits any still tracks (traffic, the truck's own body) with some
    pitch: with a prior below ``min_chord`` the planar estimate stands."""
    rng = np.random.default_rng(9)
    groups = _correspondences(rng, make_pose(*attitude_motion(0.0, 2.0, np.radians(1.0), 0.0, AXLE_X)))
    config = RansacConfig(sampson_threshold=2.0 / FOCAL_PX, max_attitude_change=np.radians(2.0))
    at_rest = estimate_tractor_motion(groups, AXLE_X, config, chord_prior=0.001)
    assert at_rest.attitude == (0.0, 0.0)
    assert estimate_tractor_motion(groups, AXLE_X, config, chord_prior=2.0).attitude != (0.0, 0.0)


def test_driving_off_after_reversing_takes_its_direction_from_the_tracks() -> None:
    """A truck that reversed, stopped and creeps off forwards (0.3 m) while its body pitches back
    by 0.8 degree: the planar RANSAC takes the backward chord of the prediction (it explains a few
    tracks either way), but the truck could have stopped within the pair (no ``direction``), so
    the attitude search tries both signs of the chord and the tracks decide."""
    rng = np.random.default_rng(3)
    yaw, chord = np.radians(0.3), 0.3
    rotation, translation = attitude_motion(yaw, chord, np.radians(0.8), 0.0, AXLE_X)
    groups = _correspondences(rng, make_pose(rotation, translation))
    total = sum(len(group[0]) for group in groups)
    threshold = 2.0 / FOCAL_PX
    planar = estimate_tractor_motion(groups, AXLE_X, RansacConfig(sampson_threshold=threshold), chord_prior=-chord)
    assert planar.chord_sign < 0.0 and planar.num_inliers < 0.2 * total  # the planar model cannot tell
    config = RansacConfig(sampson_threshold=threshold, max_attitude_change=np.radians(2.0), attitude_fraction=0.6)
    found = estimate_tractor_motion(groups, AXLE_X, config, chord_prior=-chord)
    assert found.status is SolverStatus.SCALE_UNOBSERVABLE and found.chord == pytest.approx(chord)
    assert found.num_inliers > 0.8 * total
    np.testing.assert_allclose(found.T_i_j[:3, 3], translation, atol=0.01)
    held = estimate_tractor_motion(groups, AXLE_X, config, chord_prior=-chord, direction=-1.0)  # at speed: no forward search
    assert held.chord_sign < 0.0 and held.num_inliers < 0.2 * total


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_truck_at_rest_whose_body_pitches_back_is_a_standstill(seed: int) -> None:
    """The suspension's rebound after a stop: the body pitches by 0.3 degree at rest, which moves
    the bearings by 2.6 px (above the standstill parallax of 1.5 px). The planar RANSAC cannot
    measure a chord and its cheirality votes for reversing; the tracks move no more than a pitch
    explains (about the 0.5 px noise once it is taken out), so the truck predicted forwards at a
    speed it could stop from is at rest, not reversing at the prediction's speed."""
    rng = np.random.default_rng(seed)
    groups = _correspondences(rng, make_pose(attitude_rotations(np.radians(0.3), 0.0), np.zeros(3)))
    stacked = as_groups(groups)
    assert median_parallax(stacked) * FOCAL_PX > 2.0
    assert np.median(attitude_compensated_parallax(stacked)) * FOCAL_PX < 1.2
    config = RansacConfig(sampson_threshold=2.0 / FOCAL_PX, standstill_parallax=1.5 / FOCAL_PX, max_attitude_change=np.radians(2.0))
    at_rest = estimate_tractor_motion(groups, AXLE_X, config, chord_prior=0.3)
    assert at_rest.status is SolverStatus.STANDSTILL


def test_the_attitude_compensated_parallax_keeps_what_a_translation_moved() -> None:
    """Creeping 0.08 m straight ahead: the pitch and roll fit takes out almost nothing (within
    10 %) of the translation's parallax, and a pure pitch and roll of the body leaves a fraction
    of a pixel (the cameras sit 1-1.5 m from the body origin: ``|w x c| / depth``)."""
    rng = np.random.default_rng(4)
    creeping = as_groups(_correspondences(rng, make_pose(*attitude_motion(0.0, 0.08, 0.0, 0.0, AXLE_X)), outliers=0.0))
    raw, compensated = median_parallax(creeping), float(np.median(attitude_compensated_parallax(creeping)))
    assert compensated == pytest.approx(raw, rel=0.1)
    pitched = as_groups(_correspondences(rng, make_pose(attitude_rotations(np.radians(0.5), np.radians(-0.3)), np.zeros(3)), noise_px=0.0))
    assert np.median(attitude_compensated_parallax(pitched)) * FOCAL_PX < 0.5
