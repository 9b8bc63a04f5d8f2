"""Wheel odometry as a metric scale source: the chord of the tractor's rear-axle midpoint between
two frame times, for :class:`~factors.wheel_speed.WheelSpeedFactor` (DESIGN section 3)."""
from __future__ import annotations

from typing import Callable

import numpy as np


def wheel_odometry_from_poses(timestamps: np.ndarray, T_world_tractor: np.ndarray, axle_x: float, sigma_m: float = 0.0, seed: int = 0) -> Callable[[float, float], float]:
    """A simulated wheel-odometry sensor: the chord of the tractor axle midpoint between two
    frame times from (ground-truth) poses, plus Gaussian noise ``sigma_m`` (for experiments)."""
    axle = T_world_tractor[:, :3, :3] @ np.array([axle_x, 0.0, 0.0]) + T_world_tractor[:, :3, 3]
    rng = np.random.default_rng(seed)

    def chord(t_i: float, t_j: float) -> float:
        i, j = (int(np.argmin(np.abs(timestamps - t))) for t in (t_i, t_j))
        return float(np.linalg.norm(axle[j] - axle[i]) + rng.normal(0.0, sigma_m)) if sigma_m > 0 else float(np.linalg.norm(axle[j] - axle[i]))

    return chord


def wheel_odometry_from_speed(timestamps: np.ndarray, speed: np.ndarray) -> Callable[[float, float], float | None]:
    """Wheel odometry from speed samples (issue 15, ``ampc_vo.io.wheel_speed``): the distance the
    tractor axle midpoint travelled between two times, ``|∫ v dt|`` of the piecewise-linear speed
    (exact trapezoid over the samples, partial intervals at both ends), taken as the chord
    (it exceeds the chord by ``L³κ²/24``: 0.1 mm for a 2 m step on a 30 m radius). ``None`` when a
    time lies outside the samples (no measurement: the factor is left out)."""
    timestamps = np.asarray(timestamps, dtype=float)
    speed = np.asarray(speed, dtype=float)
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(timestamps))])

    def distance_at(t: float) -> float:
        k = int(np.clip(np.searchsorted(timestamps, t, side="right") - 1, 0, len(timestamps) - 2))
        dt = t - timestamps[k]
        slope = (speed[k + 1] - speed[k]) / (timestamps[k + 1] - timestamps[k])
        return float(cumulative[k] + speed[k] * dt + 0.5 * slope * dt * dt)

    def chord(t_i: float, t_j: float) -> float | None:
        if min(t_i, t_j) < timestamps[0] or max(t_i, t_j) > timestamps[-1]:
            return None
        return abs(distance_at(t_j) - distance_at(t_i))

    return chord
