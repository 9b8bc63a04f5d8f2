"""How well the road measures a body's direction of travel (issue 16: the tractor's slip at speed).

At motorway speed a tractor camera's epipolar geometry measures the body's direction of travel to
about 2 degrees per keyframe pair (README, "The hitch in motorway curves follows the arc model
where the tyres slip"): too little to see the 0.5-1 degree tyre slip the arc model misses. Road
points measure it with their depth known: a track below the horizon in view i meets the road plane
``z = road_z`` of the body frame (DESIGN 1), and with the body's rotation between the views given,
its bearing in view j fixes the body's planar translation, lateral component included.
:func:`planar_translation_from_road` solves it; :func:`road_direction_errors` runs it on a dataset
camera's frontend tracks with the true rotations and compares the direction with the truth
(``scripts/measure_road_direction.py``). An instrument: the estimator does not use it (yet).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ampc_vo.config import TrackerConfig
from ampc_vo.errors import DatasetError
from ampc_vo.frontend.tracker import CameraTracker, road_points_of_rays
from ampc_vo.geometry import relative_pose, wrap_angle

MIN_ROAD_POINTS = 8
BELOW_HORIZON = -0.03  # body-frame bearing z: a ray that meets the road within ~80 m of a 2.5 m high camera


@dataclass(frozen=True)
class RoadTranslation:
    """The body's planar translation ``(x, y)`` (m, body frame i) and the road points it rests on."""

    translation_xy: np.ndarray
    road_points: int


def planar_translation_from_road(bearings_i: np.ndarray, bearings_j: np.ndarray, R_i_j: np.ndarray, camera_centre: np.ndarray,
                                 road_z: float, t_z: float = 0.0, focal_px: float = 500.0, max_range_m: float = 30.0) -> RoadTranslation | None:
    """The planar translation of ``T_i_j = (R_i_j, (x, y, t_z))`` from tracks on the road.

    ``bearings_i`` (N, 3) in body frame i and ``bearings_j`` (N, 3) in body frame j of one camera
    at ``camera_centre`` (body frame); a track whose view-i ray falls below the horizon and meets
    the plane ``z = road_z`` within ``max_range_m`` horizontally is a road point ``X = c + lambda f``.
    Its predicted view-j bearing is ``R^T (X - t) - c`` normalised; the residual is its cross product
    with the measured one times ``focal_px`` (about pixels), Huber at 1 px against the points off the
    road. ``None`` with fewer than 8 road points."""
    bearings_i, bearings_j = np.asarray(bearings_i, float), np.asarray(bearings_j, float)
    centre = np.asarray(camera_centre, float)
    points_i = road_points_of_rays(bearings_i, centre, road_z)
    with np.errstate(invalid="ignore"):
        on_road = (bearings_i[:, 2] < BELOW_HORIZON) & (np.linalg.norm(points_i[:, :2] - centre[:2], axis=1) < max_range_m)
    if np.count_nonzero(on_road) < MIN_ROAD_POINTS:
        return None
    points_i = points_i[on_road]
    measured_j = bearings_j[on_road] / np.linalg.norm(bearings_j[on_road], axis=1, keepdims=True)

    def residuals(translation_xy: np.ndarray) -> np.ndarray:
        translation = np.array([translation_xy[0], translation_xy[1], t_z])
        predicted = (points_i - translation) @ R_i_j - centre  # R^T (X - t) - c, row by row
        predicted /= np.linalg.norm(predicted, axis=1, keepdims=True)
        return np.cross(predicted, measured_j).ravel() * focal_px

    solution = least_squares(residuals, np.zeros(2), loss="huber", f_scale=1.0)
    return RoadTranslation(solution.x.copy(), int(np.count_nonzero(on_road)))


@dataclass(frozen=True)
class RoadDirectionErrors:
    """Per frame pair (f - 1, f) of one camera: ``frame`` (the later), ``road_points``, the
    direction of the body's planar translation from the road minus the true one (degrees) and the
    forward translation over the true one."""

    frame: np.ndarray
    road_points: np.ndarray
    direction_error_deg: np.ndarray
    forward_ratio: np.ndarray


def road_direction_errors(dataset, truth, camera_name: str, start: int, stop: int, config: TrackerConfig | None = None) -> RoadDirectionErrors:
    """Track ``camera_name`` of ``dataset`` (``io.folder.Dataset``) over frames ``[start, stop)`` with
    the frontend's tracker and measure each consecutive pair's planar translation from the road
    (:func:`planar_translation_from_road`, the true rotation and height change from ``truth``, an
    ``io.groundtruth.GroundTruth``, interpolated at the camera's capture times) against the truth."""
    from ampc_vo.io.groundtruth_log import truth_at

    rig = dataset.rig
    camera = rig.camera(camera_name)
    tracker = CameraTracker(camera, config, road_z=rig.ground_z)
    frames = range(start, stop)
    capture_times = np.array([dataset.camera_timestamp(frame, camera_name) for frame in frames])
    at_capture = truth_at(truth, capture_times)
    if len(at_capture.timestamps) != len(capture_times):
        raise DatasetError(f"{camera_name}: frames [{start}, {stop}) reach outside the ground truth's time span")
    T_world_body = at_capture.T_world_tractor if camera.body == "tractor" else at_capture.T_world_trailer
    rows, previous = [], None
    for index, frame in enumerate(frames):
        observations = tracker.track(dataset.load_image(frame, camera_name))
        current = (observations.track_ids, observations.bearings @ camera.R_body_camera.T, T_world_body[index])
        if previous is not None:
            _, in_i, in_j = np.intersect1d(previous[0], current[0], return_indices=True)
            T_i_j = relative_pose(previous[2], current[2])
            road = planar_translation_from_road(previous[1][in_i], current[1][in_j], T_i_j[:3, :3], camera.center, rig.ground_z, T_i_j[2, 3])
            true_xy = T_i_j[:2, 3]
            if road is not None and np.linalg.norm(true_xy) > 0.05:
                error = wrap_angle(np.arctan2(road.translation_xy[1], road.translation_xy[0]) - np.arctan2(true_xy[1], true_xy[0]))
                rows.append((frame, road.road_points, np.degrees(error), road.translation_xy[0] / true_xy[0]))
        previous = current
    table = np.array(rows, dtype=float).reshape(-1, 4)
    return RoadDirectionErrors(table[:, 0].astype(int), table[:, 1].astype(int), table[:, 2], table[:, 3])
