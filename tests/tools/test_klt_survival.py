"""Tests of the KLT survival check (ampc_vo.tools.klt_survival, issue 6) on synthetic images with known motion."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from ampc_vo.config import TrackerConfig
from ampc_vo.geometry import make_pose, planar_pose, rot_x
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.tools.klt_survival import SurvivalSettings, pair_survival, segment_of_pairs, summarise, true_next_pixels
from ampc_vo.rig import Camera


@pytest.fixture(scope="module")
def camera() -> Camera:
    return Camera("test", "tractor", "pinhole", 320, 240, 200.0, 200.0, 159.5, 119.5)


def _wall_depth(camera: Camera, distance: float) -> np.ndarray:
    """Ray distance image of a fronto-parallel wall at ``distance`` (z) in front of ``camera``."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(float)
    rays = camera.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    return (distance / rays[:, 2]).reshape(camera.height, camera.width).astype(np.float32)


def test_true_next_pixels_follow_a_sideways_move(camera):
    """A wall 10 m away, camera moved 0.5 m along its x axis: every pixel moves by -f 0.5 / 10 = -10 px."""
    depth = _wall_depth(camera, 10.0)
    pixels = np.array([[40.0, 30.0], [160.2, 119.7], [300.0, 200.0]])
    T_second = make_pose(np.eye(3), np.array([0.5, 0.0, 0.0]))
    moved, distance, known = true_next_pixels(camera, pixels, depth, np.eye(4), T_second)
    assert known.all()
    np.testing.assert_allclose(moved, pixels - [10.0, 0.0], atol=0.05)
    assert np.all(distance > 9.9)
    sky = np.full_like(depth, np.inf)
    _, _, known_sky = true_next_pixels(camera, pixels, sky, np.eye(4), T_second)
    assert not known_sky.any()
    behind = make_pose(np.eye(3), np.array([0.0, 0.0, 11.0]))  # camera moved past the wall
    _, _, known_behind = true_next_pixels(camera, pixels, depth, np.eye(4), behind)
    assert not known_behind.any()


def test_pair_survival_counts_trackable_features_only(camera):
    """A textured wall shifted by 12 px: KLT keeps (almost) every feature, features that leave the image
    are excluded from the denominator, and the tracked positions match the truth."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (camera.height, camera.width + 40)).astype(np.float32), (0, 0), 2.0)
    texture = cv2.normalize(texture, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    first, second = texture[:, 20:20 + camera.width], texture[:, 32:32 + camera.width]  # content moves 12 px left
    depth = _wall_depth(camera, 10.0)
    T_second = make_pose(np.eye(3), np.array([0.6, 0.0, 0.0]))  # f 0.6 / 10 = 12 px
    result = pair_survival(camera, np.ascontiguousarray(first), np.ascontiguousarray(second), depth, depth,
                           np.eye(4), T_second, TrackerConfig(), SurvivalSettings())
    assert result.detected >= 100
    assert result.left_image > 0  # features within 22 px of the left border
    assert result.counted + result.left_image == result.detected and result.occluded == 0
    assert result.survival >= 0.95
    assert np.median(result.tracking_error_px) < 0.1
    np.testing.assert_allclose(np.median(result.true_motion_px), 12.0, atol=0.05)
    # A scrambled second image: nothing survives the forward-backward check.
    scrambled = np.ascontiguousarray(rng.permutation(second.ravel()).reshape(second.shape))
    failed = pair_survival(camera, np.ascontiguousarray(first), scrambled, depth, depth, np.eye(4), T_second)
    assert failed.survival < 0.2
    table = summarise([result, failed])
    assert table["all"]["all"] == (result.survived + failed.survived, result.counted + failed.counted)
    assert table["test"]["straight"] == table["all"]["all"]


def test_occluded_features_are_not_counted(camera):
    """A nearer surface covering the second view hides the wall's points: they leave the denominator."""
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (camera.height, camera.width)).astype(np.float32), (0, 0), 2.0).astype(np.uint8)
    far, near = _wall_depth(camera, 10.0), _wall_depth(camera, 3.0)
    result = pair_survival(camera, image, image, far, near, np.eye(4), np.eye(4))
    assert result.counted == 0 and result.occluded > 0.5 * result.detected
    assert result.occluded + result.left_image == result.detected  # the rest: within margin_px of the border


def test_segments_by_yaw_change():
    count = 6
    yaw = np.array([0.0, 0.0, 0.0, 0.05, 0.10, 0.10])  # 0.05 rad = 2.9 deg per frame in pairs 2 and 3
    T_world_tractor = np.stack([planar_pose(float(k), 0.0, float(a)) for k, a in enumerate(yaw)])
    trajectory = Trajectory(np.arange(count) * 0.1, T_world_tractor, T_world_tractor.copy(), np.zeros(count))
    assert segment_of_pairs(trajectory, "tractor", range(count - 1)) == ["straight", "straight", "turn", "turn", "straight"]
    rolled = T_world_tractor.copy()
    rolled[:, :3, :3] = rolled[:, :3, :3] @ rot_x(0.3)  # roll does not count as a turn
    trajectory = Trajectory(np.arange(count) * 0.1, rolled, rolled.copy(), np.zeros(count))
    assert segment_of_pairs(trajectory, "trailer", [0, 1]) == ["straight", "straight"]
