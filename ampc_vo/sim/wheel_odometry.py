"""Simulated wheel odometry (issue 15): the rear-axle speed a truck's CAN bus reports, with the
errors real wheel odometry has: a scale error (the rolling radius differs from the nominal one by
tyre wear, pressure and load: around 1 %) and white noise on each sample (quantisation, vibration).

    v_measured(t_k) = (1 + scale_error) v(t_k) + n_k,    n_k ~ N(0, noise_sigma_mps²)

sampled at the camera rate from the simulated axle speed (``Trajectory.speed``), written as the
dataset folder's ``wheel_speed.csv`` through ``ampc_vo.io.wheel_speed``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.io.wheel_speed import WHEEL_SPEED_FILE, WheelSpeed, write_wheel_speed_csv

SCALE_ERROR = 0.01  # rolling radius 1 % larger than nominal: the speed reads 1 % high
NOISE_SIGMA_MPS = 0.02


def simulate_wheel_speed(trajectory: Trajectory, scale_error: float = SCALE_ERROR, noise_sigma_mps: float = NOISE_SIGMA_MPS, seed: int = 0) -> WheelSpeed:
    """The measured rear-axle speed at the trajectory's times (module docstring); the axle speed
    comes from ``trajectory.speed`` or, when absent, from the axle's arc length differences."""
    if trajectory.speed is not None:
        speed = np.asarray(trajectory.speed, dtype=float)
    else:
        speed = np.gradient(np.asarray(trajectory.arc_length, dtype=float), trajectory.timestamps)
    noise = np.random.default_rng([seed, 15]).normal(0.0, noise_sigma_mps, speed.shape) if noise_sigma_mps > 0 else 0.0
    return WheelSpeed(np.asarray(trajectory.timestamps, dtype=float), (1.0 + scale_error) * speed + noise)


def write_simulated_wheel_speed(out_dir: str | Path, trajectory: Trajectory, seed: int = 0) -> Path:
    """``out_dir/wheel_speed.csv`` with the default scale error and noise; returns its path."""
    path = Path(out_dir) / WHEEL_SPEED_FILE
    write_wheel_speed_csv(path, simulate_wheel_speed(trajectory, seed=seed))
    return path
