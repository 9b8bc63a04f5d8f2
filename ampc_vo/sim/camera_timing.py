"""When each camera captures and each image row is exposed (issue 13; DESIGN 5).

- **Capture times**: camera ``c`` captures frame ``k`` at ``t_k + offset_c + jitter_ck`` (the frame
  times ``t_k`` of frames.csv ``timestamp``; ``offset_c`` from the sim config's ``cameras:``
  section; the jitter Gaussian with the camera's ``jitter_s``, clipped at 3 sigma). This is the
  image's capture time that frames.csv ``<camera>_timestamp`` and measurements.npz
  ``camera_timestamps`` state; with rolling shutter it is the time of the first row.
- **Rolling shutter** (rig.yaml ``readout_time``): row ``r`` is exposed at
  ``capture + readout_time * r / (height - 1)`` (DESIGN 5). A world point is seen at the pixel
  ``u = pi(T_camera_world(t(v)) X)`` whose row ``v`` fixes its own time ``t(v)``: solved by the
  fixed-point iteration ``v_{i+1} = pi_v(T(t(v_i)) X)``, which contracts by
  ``readout_time / (height - 1) * |dv/dt|`` (< 0.1 for road vehicles), so a few iterations reach
  1e-6 px (Meingast et al., "Geometric models of rolling-shutter cameras", OMNIVIS 2005).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import invert_pose
from ampc_vo.rig import Camera
from ampc_vo.sim.camera_settings import CameraSettings

__all__ = ["capture_times", "row_time", "project_rolling_shutter", "PoseAt"]

PoseAt = Callable[[np.ndarray], np.ndarray]  # times (N,) -> T_world_camera (N, 4, 4)
_ITERATIONS = 8
_CONVERGED_PX = 1e-7


def capture_times(frame_times: np.ndarray, settings: CameraSettings, rng: np.random.Generator, camera: str = "camera") -> np.ndarray:
    """(F,) capture times of one camera (module docstring); they must increase (jitter well below
    the frame interval), else :class:`ConfigError`."""
    frame_times = np.asarray(frame_times, float)
    jitter = np.clip(rng.standard_normal(len(frame_times)), -3.0, 3.0) * settings.jitter_s if settings.jitter_s > 0 else 0.0
    times = frame_times + settings.offset_s + jitter
    if len(times) > 1 and np.any(np.diff(times) <= 0):
        raise ConfigError(f"cameras.{camera}: jitter_ms {1000 * settings.jitter_s:g} reorders the frames (frame interval "
                          f"{1000 * float(np.min(np.diff(frame_times))):g} ms)")
    return times


def row_time(camera: Camera, capture_time: float | np.ndarray, row: float | np.ndarray) -> np.ndarray:
    """Exposure time of image row ``row`` (continuous: a pixel's ``v``), DESIGN 5."""
    if camera.readout_time <= 0 or camera.height <= 1:
        return np.asarray(capture_time, float) + 0.0 * np.asarray(row, float)
    return np.asarray(capture_time, float) + camera.readout_time * np.clip(np.asarray(row, float), 0.0, camera.height - 1) / (camera.height - 1)


def _project(camera: Camera, T_world_camera: np.ndarray, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels, validity and depth of world points (N, 3) seen from per-point poses (N, 4, 4)."""
    T_camera_world = invert_pose(T_world_camera) if T_world_camera.ndim == 2 else _invert_many(T_world_camera)
    if T_camera_world.ndim == 2:
        points_camera = points_world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    else:
        points_camera = np.einsum("nij,nj->ni", T_camera_world[:, :3, :3], points_world) + T_camera_world[:, :3, 3]
    pixels, valid = camera.project(points_camera)
    return pixels, valid, points_camera[:, 2]


def _invert_many(poses: np.ndarray) -> np.ndarray:
    inverse = np.tile(np.eye(4), (len(poses), 1, 1))
    R_T = np.transpose(poses[:, :3, :3], (0, 2, 1))
    inverse[:, :3, :3] = R_T
    inverse[:, :3, 3] = -(R_T @ poses[:, :3, 3:4])[..., 0]
    return inverse


def project_rolling_shutter(
    camera: Camera, pose_at: PoseAt, points_world: np.ndarray | Callable[[np.ndarray], np.ndarray], capture_time: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (N, 2), validity (N,) and exposure times (N,) of points seen by a rolling-shutter camera.

    ``pose_at(times)`` gives ``T_world_camera`` at each time; ``points_world`` is (N, 3) static
    points or a callable ``times -> (N, 3)`` for moving ones (traffic; it broadcasts a single time
    to all N points). Global shutter
    (``readout_time == 0``): one projection at ``capture_time``. Otherwise the fixed point of the
    module docstring, started at the middle row; a point whose solution leaves the image, or that
    has not converged to 1e-7 px, is invalid.
    """
    moving = callable(points_world)
    count = len(points_world(np.array([capture_time]))) if moving else len(points_world)
    if count == 0:
        return np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0)
    times = np.full(count, float(capture_time))
    if camera.readout_time > 0:
        times += 0.5 * camera.readout_time
    for _ in range(_ITERATIONS if camera.readout_time > 0 else 1):
        points = points_world(times) if moving else points_world
        pixels, valid, _ = _project(camera, pose_at(times), points)
        if camera.readout_time <= 0:
            return pixels, valid, times
        new_times = row_time(camera, capture_time, np.nan_to_num(pixels[:, 1], nan=0.0))
        converged = np.abs(new_times - times) * (camera.height - 1) / camera.readout_time < _CONVERGED_PX
        times = new_times
        if converged.all():
            break
    points = points_world(times) if moving else points_world
    pixels, valid, _ = _project(camera, pose_at(times), points)
    rows_time = row_time(camera, capture_time, np.nan_to_num(pixels[:, 1], nan=0.0))
    valid &= np.abs(rows_time - times) * (camera.height - 1) / camera.readout_time < 1e-4
    valid &= (pixels[:, 1] >= -0.5) & (pixels[:, 1] <= camera.height - 0.5)
    return pixels, valid, times
