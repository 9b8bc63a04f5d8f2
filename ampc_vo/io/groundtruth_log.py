"""Ground truth of a recording (issue 15): the tractor's pose from a pose topic of the log
(``nav_msgs/Odometry``, ``geometry_msgs/PoseStamped``: the pose of the tractor body frame, DESIGN
section 1, at header stamps) or from a TUM file (``t x y z qx qy qz qw``), and the hitch angle from a
CSV ``timestamp,hitch_angle`` (radians; further columns ignored, so a ``hitch.csv`` of ours reads
too) when there is one. The trailer pose follows from the hitch (centres coincide):
``T_world_trailer = T_world_tractor (Rz(θ), 0)``.

:func:`truth_at` resamples a ground truth at the estimate's times (poses interpolated, geodesic
rotation), so a pose topic at another rate than the cameras associates exactly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ampc_vo.errors import DatasetError
from ampc_vo.geometry import hitch_transform, pose_from_xyz_quat
from ampc_vo.io.groundtruth import GroundTruth

POSE_TOPIC_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")


def _pose_of(message: object) -> np.ndarray:
    pose = message.pose.pose if hasattr(message.pose, "pose") else message.pose
    p, q = pose.position, pose.orientation
    return pose_from_xyz_quat(np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w]))


def poses_from_log(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    """Header stamps (N,) and poses (N, 4, 4) of a pose topic, sorted by stamp."""
    from ampc_vo.io.bags import topic_messages

    samples = [(stamp, _pose_of(message)) for stamp, message in topic_messages(path, topic, POSE_TOPIC_TYPES, "ground-truth pose")]
    if len(samples) < 2:
        raise DatasetError(f"{path}: {topic}: {len(samples)} pose message(s); ground truth needs at least 2")
    order = np.argsort([stamp for stamp, _ in samples], kind="stable")
    return np.array([samples[i][0] for i in order]), np.array([samples[i][1] for i in order])


def poses_from_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times and poses of a TUM file (``t x y z qx qy qz qw``, ``#`` comments), sorted by time."""
    from ampc_vo.io.outputs import read_tum

    trajectory = read_tum(path)
    if len(trajectory) < 2:
        raise DatasetError(f"{path}: ground truth needs at least 2 poses, got {len(trajectory)}")
    order = np.argsort(trajectory.timestamps, kind="stable")
    return trajectory.timestamps[order], trajectory.poses[order]


def read_hitch_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Times and hitch angles (rad) of a CSV with ``timestamp`` and ``hitch_angle`` columns."""
    from ampc_vo.io.folder import _floats, _read_csv

    path = Path(path)
    header, rows = _read_csv(path)
    if "timestamp" not in header or "hitch_angle" not in header:
        raise DatasetError(f"{path}: needs columns timestamp and hitch_angle (radians), got {','.join(header)}")
    columns = [header.index("timestamp"), header.index("hitch_angle")]
    values = _floats(path, [[row[i] for i in columns] for row in rows], slice(None))
    if len(values) < 2:
        raise DatasetError(f"{path}: at least 2 hitch angles needed")
    order = np.argsort(values[:, 0], kind="stable")
    return values[order, 0], values[order, 1]


def groundtruth_from_poses(timestamps: np.ndarray, T_world_tractor: np.ndarray, hitch: tuple[np.ndarray, np.ndarray] | None = None,
                           trailer_axle_x: float = 0.0) -> GroundTruth:
    """A :class:`GroundTruth` of tractor poses and, given hitch angles (interpolated at the pose
    times), the trailer's (module docstring)."""
    if hitch is None:
        return GroundTruth(timestamps, T_world_tractor, trailer_axle_x=trailer_axle_x)
    angles = np.interp(timestamps, hitch[0], hitch[1])
    trailer = np.array([T @ hitch_transform(angle) for T, angle in zip(T_world_tractor, angles)])
    return GroundTruth(timestamps, T_world_tractor, trailer, angles, trailer_axle_x)


def load_log_groundtruth(source: str | Path, pose_topic: str | None = None, hitch_csv: str | Path | None = None,
                         trailer_axle_x: float = 0.0) -> GroundTruth:
    """Ground truth from a log's ``pose_topic`` or, when ``source`` is not a log, from it as a TUM file."""
    from ampc_vo.io.bags import is_log

    source = Path(source)
    if not is_log(source):
        times, poses = poses_from_tum(source)
    elif pose_topic is None:
        raise DatasetError(f"{source}: a recording's ground truth needs its pose topic (--groundtruth-topic) or a TUM file")
    else:
        times, poses = poses_from_log(source, pose_topic)
    hitch = read_hitch_csv(hitch_csv) if hitch_csv is not None else None
    return groundtruth_from_poses(times, poses, hitch, trailer_axle_x)


def _interpolated(times: np.ndarray, poses: np.ndarray, at: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation, Slerp

    slerp = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))
    result = np.repeat(np.eye(4)[None], len(at), axis=0)
    result[:, :3, :3] = slerp(at).as_matrix()
    for axis in range(3):
        result[:, axis, 3] = np.interp(at, times, poses[:, axis, 3])
    return result


def truth_at(truth: GroundTruth, times: np.ndarray) -> GroundTruth:
    """``truth`` resampled at the ``times`` inside its span (module docstring)."""
    times = np.asarray(times, dtype=float)
    times = times[(times >= truth.timestamps[0]) & (times <= truth.timestamps[-1])]
    if len(times) == 0:
        raise DatasetError(f"no estimate lies in the ground truth's time span [{truth.timestamps[0]:.3f}, {truth.timestamps[-1]:.3f}] s")
    tractor = _interpolated(truth.timestamps, truth.T_world_tractor, times)
    trailer = None if truth.T_world_trailer is None else _interpolated(truth.timestamps, truth.T_world_trailer, times)
    hitch = None if truth.hitch_angles is None else np.interp(times, truth.timestamps, truth.hitch_angles)
    return GroundTruth(times, tractor, trailer, hitch, truth.trailer_axle_x, truth.T_tractor_reference)
