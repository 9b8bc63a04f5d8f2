"""Tests of ampc_vo.tools.road_direction: the planar translation from road points, checked on
synthetic road points seen by a forward camera under a known motion with a lateral slip."""
from __future__ import annotations

import numpy as np

from ampc_vo.geometry import rot_z
from ampc_vo.tools.road_direction import planar_translation_from_road

CENTRE = np.array([2.0, 0.3, 2.5])  # a cab camera 3.7 m above the road
ROAD_Z = -1.2


def _views(points: np.ndarray, R_i_j: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame bearings of ``points`` (body frame i) from the camera in views i and j."""
    in_i = points - CENTRE
    in_j = (points - translation) @ R_i_j - CENTRE
    return in_i / np.linalg.norm(in_i, axis=1, keepdims=True), in_j / np.linalg.norm(in_j, axis=1, keepdims=True)


def _road(count: int, rng: np.random.Generator) -> np.ndarray:
    return np.column_stack([rng.uniform(6.0, 28.0, count), rng.uniform(-5.0, 5.0, count), np.full(count, ROAD_Z)])


def _direction_deg(translation_xy: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(translation_xy[1], translation_xy[0])))


def test_the_lateral_slip_is_read_from_exact_road_bearings():
    """A 3.6 m chord (29 m/s at 8 keyframes a second) turning 0.5 degrees with the axle slipping
    0.6 degrees: the direction of travel is half the yaw change plus the slip, 0.85 degrees."""
    rng = np.random.default_rng(0)
    R_i_j = rot_z(np.radians(0.5))
    translation = 3.6 * np.array([np.cos(np.radians(0.85)), np.sin(np.radians(0.85)), 0.0])
    bearings_i, bearings_j = _views(_road(60, rng), R_i_j, translation)
    road = planar_translation_from_road(bearings_i, bearings_j, R_i_j, CENTRE, ROAD_Z)
    assert road is not None and road.road_points == 60
    np.testing.assert_allclose(road.translation_xy, translation[:2], atol=1e-6)


def test_noise_and_points_off_the_road_leave_the_direction_within_a_tenth_of_a_degree():
    """0.5 px of bearing noise on 50 road points and 8 points on a wall 1 m above the road (read
    as farther road points): the Huber loss keeps the direction within 0.1 degrees (the epipolar
    geometry of a forward camera reads it to ~2 degrees per pair at this speed)."""
    rng = np.random.default_rng(1)
    R_i_j = rot_z(np.radians(-0.4))
    translation = 3.6 * np.array([np.cos(np.radians(-0.8)), np.sin(np.radians(-0.8)), 0.0])
    wall = np.column_stack([rng.uniform(8.0, 20.0, 8), np.full(8, 6.0), np.full(8, ROAD_Z + 1.0)])
    bearings_i, bearings_j = _views(np.vstack([_road(50, rng), wall]), R_i_j, translation)
    bearings_j = bearings_j + rng.normal(0.0, 0.5 / 500.0, bearings_j.shape)
    road = planar_translation_from_road(bearings_i, bearings_j, R_i_j, CENTRE, ROAD_Z)
    assert road is not None
    assert abs(_direction_deg(road.translation_xy) - (-0.8)) < 0.1
    assert abs(np.linalg.norm(road.translation_xy) / 3.6 - 1.0) < 0.02


def test_too_few_road_points_give_no_translation():
    """Seven road points, and points above the camera (never on the road): no answer."""
    rng = np.random.default_rng(2)
    sky = np.column_stack([rng.uniform(10.0, 30.0, 20), rng.uniform(-5.0, 5.0, 20), np.full(20, 6.0)])
    bearings_i, bearings_j = _views(np.vstack([_road(7, rng), sky]), np.eye(3), np.array([2.0, 0.0, 0.0]))
    assert planar_translation_from_road(bearings_i, bearings_j, np.eye(3), CENTRE, ROAD_Z) is None
