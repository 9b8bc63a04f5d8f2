"""Wheel speed sets the metric scale (issue 15): the wheel-speed factor and the scale bootstrap take
the chord integrated from the measured speed, so a wheel odometry with a scale error (and a tight
sigma) shows up in the estimated distance, and a run without it does not."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.backend.pipeline import run_on_frames
from ampc_vo.config import ScaleConfig, VoConfig
from ampc_vo.scale.wheel import wheel_odometry_from_speed
from ampc_vo.sim.wheel_odometry import simulate_wheel_speed


def _polyline(positions: np.ndarray) -> float:
    return float(np.sum(np.linalg.norm(np.diff(positions, axis=0), axis=1)))


def _ratio(estimates, truth) -> float:
    """Estimated over true path length of the hitch between the same keyframes."""
    indices = [int(np.argmin(np.abs(truth.timestamps - estimate.timestamp))) for estimate in estimates]
    return _polyline(np.array([e.T_world_tractor[:3, 3] for e in estimates])) / _polyline(truth.T_world_tractor[indices, :3, 3])


def test_the_wheel_chord_carries_the_scale(ci_simulation, caplog):
    result = ci_simulation
    truth = result.trajectory
    frames = lambda: result.measurements.frames(result.rig)  # noqa: E731
    _, plain = run_on_frames(result.rig, VoConfig(), frames(), total=len(truth))
    # wheel odometry reading 5 % high, trusted to 1 cm per keyframe and taken as calibrated
    # (wheel_scale_sigma null, the default): the run follows it
    measured = simulate_wheel_speed(truth, scale_error=0.05, noise_sigma_mps=0.0)
    odometry = wheel_odometry_from_speed(measured.timestamps, measured.speed)
    config = VoConfig(scale=ScaleConfig(wheel_speed=True, wheel_speed_sigma_m=0.01))
    _, wheel = run_on_frames(result.rig, config, frames(), total=len(truth), wheel_odometry=odometry)
    assert _ratio(plain, truth) == pytest.approx(1.0, abs=0.02)
    assert _ratio(wheel, truth) == pytest.approx(1.05, abs=0.015)
    # with its scale calibrated online (a 3 % prior) the other metric sources find the 5 %
    caplog.set_level("INFO", logger="ampc_vo.backend.pipeline")
    calibrated_config = VoConfig(scale=ScaleConfig(wheel_speed=True, wheel_speed_sigma_m=0.01, wheel_scale_sigma=0.03))
    _, calibrated = run_on_frames(result.rig, calibrated_config, frames(), total=len(truth), wheel_odometry=odometry)
    assert _ratio(calibrated, truth) == pytest.approx(1.0, abs=0.015)
    line = next(record.getMessage() for record in caplog.records if "wheel odometry scale calibrated" in record.getMessage())
    assert float(line.split(": ")[1].split()[0]) == pytest.approx(1.05, abs=0.02)
    sigma = float(line.split("+- ")[1].split()[0])  # the marginal of the last window
    assert 0.0 < sigma < 0.03
    config = calibrated_config
    # a wheel odometry that measures nothing (outside its samples) changes nothing
    _, empty = run_on_frames(result.rig, config, frames(), total=len(truth), wheel_odometry=lambda t_i, t_j: None)
    assert _ratio(empty, truth) == pytest.approx(_ratio(plain, truth), rel=1e-9)
