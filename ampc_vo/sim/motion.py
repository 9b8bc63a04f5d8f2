"""Body poses at any time: SE(3) geodesic interpolation of a sampled trajectory (issue 13).

Cameras fire at their own times (per-camera offsets and jitter), rolling-shutter rows are exposed
one after the other and motion blur integrates the motion over the exposure, so the simulator needs
the bodies' poses between the samples of a trajectory. Between neighbouring samples ``T_a`` (time
``t_a``) and ``T_b`` (``t_b``) the pose follows the constant-twist (screw) motion

    T(t) = T_a exp(f log(T_a^-1 T_b)),   f = (t - t_a) / (t_b - t_a)

(the SE(3) geodesic; Barfoot, *State Estimation for Robotics*, 2017, sec. 7.1.7 for exp/log and the
left Jacobian ``V``). Times before the first or after the last sample extrapolate the first or last
twist (``f < 0`` or ``f > 1``): camera offsets of a few tens of ms reach past the ends of the
trajectory. The trajectory to sample is an argument: the camera-rate one of a simulation, or a dense
(>= 200 Hz) one where the vehicle simulation provides it.

**Camera poses** (:func:`camera_poses`): a camera on a vibrating bracket is at
``T_world_body(t) T_body_camera R_mount(t)`` (``attitude.mount_vibration``: rotations sampled with the
dense trajectory), the bracket's rotation between its samples on the SO(3) geodesic
``R_a exp(f log(R_a^T R_b))`` (:func:`sample_rotations`). The estimator is handed the nominal
``T_body_camera`` only: the vibration is an unmodelled perturbation, as on a real truck.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ampc_vo.errors import ConfigError
from ampc_vo.io.groundtruth import Trajectory

__all__ = ["se3_log", "se3_exp", "interpolate_poses", "sample_poses", "PoseSampler", "sample_rotations", "camera_poses"]

_SMALL_ANGLE = 1e-6


def _skew(vectors: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices of (N, 3) vectors."""
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], axis=1)


def _left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """``V(phi) = I + (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2`` (N, 3, 3), series near 0."""
    theta = np.linalg.norm(rotvec, axis=1)
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    K = _skew(rotvec)
    return np.eye(3)[None] + a[:, None, None] * K + b[:, None, None] * (K @ K)


def se3_log(poses: np.ndarray) -> np.ndarray:
    """Twists (N, 6) = (rho, phi) of poses (N, 4, 4): ``T = exp([rho, phi])`` with ``t = V(phi) rho``."""
    poses = np.asarray(poses, float).reshape(-1, 4, 4)
    phi = Rotation.from_matrix(poses[:, :3, :3]).as_rotvec()
    rho = np.linalg.solve(_left_jacobian(phi), poses[:, :3, 3:4])[..., 0]
    return np.concatenate([rho, phi], axis=1)


def se3_exp(twists: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) of twists (N, 6) = (rho, phi) (inverse of :func:`se3_log`)."""
    twists = np.asarray(twists, float).reshape(-1, 6)
    poses = np.tile(np.eye(4), (len(twists), 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(twists[:, 3:]).as_matrix()
    poses[:, :3, 3] = (_left_jacobian(twists[:, 3:]) @ twists[:, :3, None])[..., 0]
    return poses


def interpolate_poses(T_a: np.ndarray, T_b: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """``T_a exp(f log(T_a^-1 T_b))`` for (N, 4, 4) pose pairs and (N,) fractions (module docstring)."""
    T_a = np.asarray(T_a, float).reshape(-1, 4, 4)
    T_b = np.asarray(T_b, float).reshape(-1, 4, 4)
    fraction = np.asarray(fraction, float).reshape(-1)
    R_a_T = np.transpose(T_a[:, :3, :3], (0, 2, 1))
    relative = np.tile(np.eye(4), (len(T_a), 1, 1))
    relative[:, :3, :3] = R_a_T @ T_b[:, :3, :3]
    relative[:, :3, 3] = (R_a_T @ (T_b[:, :3, 3] - T_a[:, :3, 3])[..., None])[..., 0]
    return T_a @ se3_exp(fraction[:, None] * se3_log(relative))


def sample_poses(trajectory: Trajectory, body: str, times: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses ``T_world_<body>`` of ``trajectory`` at ``times`` (N,) seconds (module docstring).

    ``body`` is ``'tractor'`` or ``'trailer'``. Exactly at a sample time the sample is returned."""
    times = np.asarray(times, float).reshape(-1)
    stamps = np.asarray(trajectory.timestamps, float)
    poses = trajectory.pose(body)
    if len(stamps) == 0:
        raise ConfigError("sample_poses: the trajectory has no samples")
    if len(stamps) == 1:
        return np.repeat(poses[:1], len(times), axis=0)
    if np.any(np.diff(stamps) <= 0):
        raise ConfigError("sample_poses: trajectory timestamps must increase strictly")
    index = np.clip(np.searchsorted(stamps, times, side="right") - 1, 0, len(stamps) - 2)
    fraction = (times - stamps[index]) / (stamps[index + 1] - stamps[index])
    result = interpolate_poses(poses[index], poses[index + 1], fraction)
    exact = fraction == 0.0
    result[exact] = poses[index[exact]]
    return result


@dataclass(frozen=True)
class PoseSampler:
    """:func:`sample_poses` for many calls on one trajectory and body: the twist of every segment
    (``log(T_a^-1 T_b)``) is computed once, each call only exponentiates."""

    timestamps: np.ndarray   # (F,)
    poses: np.ndarray        # (F, 4, 4)
    twists: np.ndarray       # (F - 1, 6)

    @staticmethod
    def of(trajectory: Trajectory, body: str) -> "PoseSampler":
        stamps = np.asarray(trajectory.timestamps, float)
        poses = np.asarray(trajectory.pose(body), float)
        if len(stamps) == 0:
            raise ConfigError("PoseSampler: the trajectory has no samples")
        if np.any(np.diff(stamps) <= 0):
            raise ConfigError("PoseSampler: trajectory timestamps must increase strictly")
        if len(stamps) == 1:
            return PoseSampler(stamps, poses, np.zeros((0, 6)))
        return PoseSampler(stamps, poses, se3_log(np.linalg.solve(poses[:-1], poses[1:])))

    def __call__(self, times: np.ndarray) -> np.ndarray:
        times = np.asarray(times, float).reshape(-1)
        if len(self.timestamps) == 1:
            return np.repeat(self.poses[:1], len(times), axis=0)
        index = np.clip(np.searchsorted(self.timestamps, times, side="right") - 1, 0, len(self.timestamps) - 2)
        fraction = (times - self.timestamps[index]) / (self.timestamps[index + 1] - self.timestamps[index])
        result = self.poses[index] @ se3_exp(fraction[:, None] * self.twists[index])
        exact = fraction == 0.0
        result[exact] = self.poses[index[exact]]
        return result


def sample_rotations(timestamps: np.ndarray, rotations: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations sampled at ``rotations`` (F, 3, 3) over increasing ``timestamps`` (F,),
    at ``times`` (N,): the geodesic ``R_a exp(f log(R_a^T R_b))`` between neighbouring samples, the
    first or last segment extrapolated beyond the ends (module docstring)."""
    timestamps = np.asarray(timestamps, float)
    rotations = np.asarray(rotations, float)
    times = np.asarray(times, float).reshape(-1)
    if len(timestamps) != len(rotations) or len(timestamps) == 0:
        raise ConfigError(f"sample_rotations: {len(rotations)} rotations for {len(timestamps)} timestamps")
    if len(timestamps) == 1:
        return np.repeat(rotations[:1], len(times), axis=0)
    index = np.clip(np.searchsorted(timestamps, times, side="right") - 1, 0, len(timestamps) - 2)
    fraction = (times - timestamps[index]) / (timestamps[index + 1] - timestamps[index])
    first = rotations[index]
    relative = Rotation.from_matrix(np.transpose(first, (0, 2, 1)) @ rotations[index + 1]).as_rotvec()
    return first @ Rotation.from_rotvec(fraction[:, None] * relative).as_matrix()


def camera_poses(T_world_body: np.ndarray, T_body_camera: np.ndarray, R_mount: np.ndarray | None = None) -> np.ndarray:
    """``T_world_camera = T_world_body T_body_camera (R_mount, 0)`` (N, 4, 4) for body poses (N, 4, 4)
    and optional bracket rotations (N, 3, 3) about the camera's own axes (module docstring)."""
    poses = np.asarray(T_world_body, float) @ np.asarray(T_body_camera, float)
    if R_mount is None:
        return poses
    poses = poses.copy()
    poses[:, :3, :3] = poses[:, :3, :3] @ R_mount
    return poses
