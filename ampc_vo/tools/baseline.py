"""A simple peer baseline for rigs with an overlapping stereo pair (KITTI): stereo PnP odometry.

Frame to frame: the left-right matches of :class:`~ampc_vo.frontend.multi_camera.MultiCameraFrontend` are
triangulated at frame k-1 (points in the left camera frame), the same left tracks at frame k give
2D-3D correspondences, and ``cv2.solvePnPRansac`` (then Levenberg-Marquardt on the inliers) gives
the left camera's motion. Poses are chained and converted to the body frame. This is the textbook
stereo VO that the articulated pipeline is compared against; it has no smoothing or keyframes.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Iterable

import cv2
import numpy as np

from ampc_vo.frontend.multi_camera import MultiCameraFrontend
from ampc_vo.config import StereoConfig, TrackerConfig
from ampc_vo.geometry import triangulate_midpoint
from ampc_vo.geometry import invert_pose, make_pose
from ampc_vo.observations import match_tracks
from ampc_vo.rig import Rig

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StereoPnpConfig:
    """Settings of :func:`stereo_pnp_odometry`."""

    left: str = "left"
    right: str = "right"
    reprojection_threshold_px: float = 1.5
    ransac_iterations: int = 200
    min_inliers: int = 12
    max_depth_m: float = 30.0          # far points carry little translation information and bias the scale
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)


@dataclass
class StereoPnpResult:
    """Body poses (N, 4, 4) ``T_world_body`` (world = body at the first frame), inlier counts per
    frame, and the frames where PnP failed (the previous motion was repeated)."""

    timestamps: np.ndarray
    T_world_body: np.ndarray
    inliers: np.ndarray
    failed_frames: list[int]


def stereo_pnp_odometry(
    rig: Rig,
    frames: Iterable[tuple[float, dict[str, np.ndarray | None]]],
    config: StereoPnpConfig | None = None,
) -> StereoPnpResult:
    """Run stereo PnP VO over ``(timestamp, images)`` pairs; see the module docstring."""
    config = config or StereoPnpConfig()
    left = rig.camera(config.left)
    T_body_left = left.T_body_camera
    frontend = MultiCameraFrontend(rig, config.tracker, stereo_pairs=((config.left, config.right),), stereo_config=config.stereo)
    T_left_right = invert_pose(T_body_left) @ rig.camera(config.right).T_body_camera
    timestamps, poses, inlier_counts, failed = [], [], [], []
    T_first_current = np.eye(4)            # left camera at frame k in the left camera frame of frame 0
    T_previous_current = np.eye(4)         # last motion (constant-velocity fallback)
    previous_points: tuple[np.ndarray, np.ndarray] | None = None   # (track ids, points in left frame)
    for index, (timestamp, images) in enumerate(frames):
        result = frontend.process_with_details(index, timestamp, images)
        current_left = result.observations.cameras[config.left]
        inliers = 0
        if previous_points is not None and len(current_left):
            ids, points = previous_points
            shared = np.intersect1d(ids, current_left.track_ids, assume_unique=True, return_indices=True)
            object_points, image_points = points[shared[1]], current_left.pixels[shared[2]]
            motion = _pnp(object_points, image_points, left.K, config) if len(object_points) >= config.min_inliers else None
            if motion is None:
                failed.append(index)
                logger.warning("frame %d: stereo PnP failed (%d 2D-3D matches); repeating the last motion", index, len(object_points))
            else:
                T_previous_current, inliers = motion
            T_first_current = T_first_current @ T_previous_current
        stereo = result.stereo[(config.left, config.right)]
        if len(stereo):
            index_left, index_stereo = match_tracks(current_left, stereo.observations)
            points, depth = triangulate_midpoint(current_left.bearings[index_left], stereo.observations.bearings[index_stereo], T_left_right)
            usable = (depth > 0) & (depth < config.max_depth_m)
            previous_points = (current_left.track_ids[index_left][usable], points[usable])
        else:
            previous_points = None
        timestamps.append(float(timestamp))
        poses.append(T_body_left @ T_first_current @ invert_pose(T_body_left))
        inlier_counts.append(inliers)
    frontend.close()
    return StereoPnpResult(np.array(timestamps), np.array(poses), np.array(inlier_counts), failed)


def _pnp(object_points: np.ndarray, image_points: np.ndarray, K: np.ndarray, config: StereoPnpConfig) -> tuple[np.ndarray, int] | None:
    """``T_previous_current`` of the left camera from 3D points (previous frame) seen at pixels now."""
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        object_points.astype(np.float64), image_points.astype(np.float64), K, None,
        iterationsCount=config.ransac_iterations, reprojectionError=config.reprojection_threshold_px,
        confidence=0.999, flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or inliers is None or len(inliers) < config.min_inliers:
        return None
    inliers = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(object_points[inliers].astype(np.float64), image_points[inliers].astype(np.float64), K, None, rvec, tvec)
    T_current_previous = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
    return invert_pose(T_current_previous), int(len(inliers))
