"""Stereo scale (ampc_vo.scale.stereo): axle chord and Ackermann motion from points triangulated by an
overlapping camera pair, on a synthetic KITTI-like stereo rig with known motion."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.io.kitti import kitti_rig
from ampc_vo.geometry import invert_pose, make_pose, rot_y
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.solvers import ackermann_motion
from ampc_vo.scale.stereo import StereoScaleOptions, StereoScaleStatus, stereo_chord, stereo_motion, stereo_points

FOCAL, BASELINE = 707.0, 0.54
CALIBRATION = {
    "P0": np.array([[FOCAL, 0, 613.0, 0], [0, FOCAL, 185.0, 0], [0, 0, 1, 0]]),
    "P1": np.array([[FOCAL, 0, 613.0, -FOCAL * BASELINE], [0, FOCAL, 185.0, 0], [0, 0, 1, 0]]),
}
RIG = kitti_rig(CALIBRATION, 1226, 370)
AXLE_X = RIG.axle_x("tractor")


def observe(T_world_body: np.ndarray, points_world: np.ndarray, frame: int, rng: np.random.Generator, pixel_sigma: float,
            wrong_right: float = 0.0) -> FrameObservations:
    """Both cameras' observations of the visible points (landmark id = point index); ``wrong_right``:
    share of right-camera observations given the id of another point (stereo mismatches)."""
    cameras = {}
    for camera in RIG.cameras:
        T_camera_world = invert_pose(T_world_body @ camera.T_body_camera)
        in_camera = points_world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
        pixels, valid = camera.project(in_camera)
        valid &= in_camera[:, 2] > 0.5
        ids = np.flatnonzero(valid)
        pixels = pixels[valid] + rng.normal(0.0, pixel_sigma, (ids.size, 2))
        if camera.name == "right" and wrong_right > 0:
            wrong = rng.random(ids.size) < wrong_right
            ids = ids.copy()
            ids[wrong] = rng.permutation(ids[wrong])
        cameras[camera.name] = CameraObservations(camera.name, ids.astype(np.int64), pixels, camera.unproject(pixels), ids.astype(np.int64))
    return FrameObservations(frame, 0.1 * frame, cameras)


def scene(seed: int, yaw_change: float = 0.02, chord: float = 1.2, pixel_sigma: float = 0.0, wrong_right: float = 0.0):
    rng = np.random.default_rng(seed)
    count = 400
    points = np.column_stack([rng.uniform(4.0, 40.0, count), rng.uniform(-12.0, 12.0, count), rng.uniform(0.0, 4.0, count)])
    T_i_j = make_pose(*ackermann_motion(yaw_change, chord, AXLE_X))
    first = observe(np.eye(4), points, 0, rng, pixel_sigma, wrong_right)
    second = observe(T_i_j, points, 1, rng, pixel_sigma, wrong_right)
    return first, second, T_i_j


def test_points_are_triangulated_at_metric_scale():
    first, _, _ = scene(0)
    points = stereo_points(RIG, "tractor", first)
    assert len(points) > 100
    rng = np.random.default_rng(0)
    truth = np.column_stack([rng.uniform(4.0, 40.0, 400), rng.uniform(-12.0, 12.0, 400), rng.uniform(0.0, 4.0, 400)])
    np.testing.assert_allclose(points.points, truth[points.landmark_ids], atol=1e-6)
    assert np.all(points.depths <= 40.0) and np.all(points.depth_sigmas > 0)


def test_noise_free_chord_and_motion_are_exact():
    first, second, T_i_j = scene(1)
    chord = stereo_chord(RIG, "tractor", first, second, T_i_j, AXLE_X)
    assert chord.ok and chord.chord == pytest.approx(1.2, abs=1e-6)
    assert chord.as_scale_chord()[0] == pytest.approx(1.2, abs=1e-6)
    straight_guess = make_pose(np.eye(3), np.array([1.0, 0.0, 0.0]))   # constant-velocity guess: wrong yaw and scale
    motion = stereo_motion(RIG, "tractor", first, second, straight_guess, AXLE_X)
    assert motion.ok
    assert motion.chord == pytest.approx(1.2, abs=1e-5) and motion.yaw_change == pytest.approx(0.02, abs=1e-6)
    np.testing.assert_allclose(motion.T_i_j, T_i_j, atol=1e-5)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_noisy_chord_with_stereo_mismatches(seed):
    first, second, T_i_j = scene(seed, yaw_change=-0.01, chord=1.2, pixel_sigma=0.5, wrong_right=0.2)
    motion = stereo_motion(RIG, "tractor", first, second, make_pose(np.eye(3), np.array([0.5, 0.0, 0.0])), AXLE_X)
    assert motion.ok
    assert abs(motion.chord - 1.2) < 0.02 * 1.2                 # better than 2 % (KITTI clip: 0.5 % std)
    assert abs(motion.yaw_change + 0.01) < np.radians(0.05)
    assert 0.0 < motion.chord_sigma < 0.05
    # the 20 % wrong stereo pairs would bias a plain least-squares chord by far more
    chord = stereo_chord(RIG, "tractor", first, second, T_i_j, AXLE_X)
    assert chord.ok and abs(chord.chord - 1.2) < 0.02 * 1.2 and chord.inliers < chord.candidates


def test_no_stereo_points_and_no_motion_are_reported():
    first, second, T_i_j = scene(5)
    only_left = [FrameObservations(frame.frame, frame.timestamp, {"left": frame.cameras["left"]}) for frame in (first, second)]
    assert stereo_chord(RIG, "tractor", *only_left, T_i_j, AXLE_X).status is StereoScaleStatus.NO_STEREO_POINTS
    assert stereo_chord(RIG, "tractor", first, second, np.eye(4), AXLE_X).status is StereoScaleStatus.NO_MOTION_DIRECTION
    assert not stereo_motion(RIG, "tractor", *only_left, T_i_j, AXLE_X).ok


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sequence_starting_in_a_turn_finds_its_yaw_by_search(seed):
    """The first pair of a sequence that starts at speed in a turn (KITTI's motorway ramp: 2.6 deg per
    frame) has no predicted motion, only the straight bootstrap guess; with the road points on one
    side, the refinement from that guess lands in another basin (chords of 5-20 m, either sign),
    the yaw search (``yaw_search``) in the right one."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(4.0, 40.0, 400), rng.uniform(2.0, 15.0, 400), rng.uniform(-1.6, 4.0, 400)])
    yaw_change, chord = np.radians(6.0), 1.0
    T_i_j = make_pose(*ackermann_motion(yaw_change, chord, AXLE_X))
    first, second = observe(np.eye(4), points, 0, rng, 0.5, 0.2), observe(T_i_j, points, 1, rng, 0.5, 0.2)
    straight_guess = make_pose(np.eye(3), np.array([0.1, 0.0, 0.0]))
    unsearched = stereo_motion(RIG, "tractor", first, second, straight_guess, AXLE_X)
    assert not unsearched.ok or abs(unsearched.chord - chord) > 0.5 * chord
    searched = stereo_motion(RIG, "tractor", first, second, straight_guess, AXLE_X, yaw_search=np.radians(10.0))
    assert searched.ok
    assert abs(searched.chord - chord) < 0.02 * chord
    assert abs(searched.yaw_change - yaw_change) < np.radians(0.05)


@pytest.mark.parametrize("seed", [6, 7])
def test_pitch_and_vertical_motion_do_not_go_into_the_chord(seed):
    """A body that pitches (0.4 deg) and rises (3 cm) between the views, as on a real road: the 6-DoF
    refinement (``free_attitude``, module docstring "Attitude") measures the axle chord to better than
    1 %; the planar Ackermann motion puts the vertical motion into the chord (several % off)."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(4.0, 30.0, 400), rng.uniform(-8.0, 8.0, 400), rng.uniform(0.0, 3.0, 400)])
    rotation, translation = ackermann_motion(np.radians(2.5), 1.0, AXLE_X)
    rotation = rotation @ rot_y(np.radians(-0.4))
    translation = translation + np.array([0.0, 0.0, 0.03])
    T_i_j = make_pose(rotation, translation)
    true_chord = float(np.linalg.norm(rotation @ np.array([AXLE_X, 0.0, 0.0]) + translation - np.array([AXLE_X, 0.0, 0.0])))
    first, second = observe(np.eye(4), points, 0, rng, 0.3), observe(T_i_j, points, 1, rng, 0.3)
    guess = make_pose(*ackermann_motion(np.radians(2.0), 0.9, AXLE_X))
    free = stereo_motion(RIG, "tractor", first, second, guess, AXLE_X)
    planar = stereo_motion(RIG, "tractor", first, second, guess, AXLE_X, StereoScaleOptions(free_attitude=False))
    assert free.ok and planar.ok
    assert abs(free.chord - true_chord) < 0.01 * true_chord
    assert abs(free.chord - true_chord) < 3.0 * free.chord_sigma
    np.testing.assert_allclose(free.T_i_j, T_i_j, atol=5e-3)
    assert abs(planar.chord - true_chord) > 0.03 * true_chord
