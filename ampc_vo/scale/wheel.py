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
