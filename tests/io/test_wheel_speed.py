"""Wheel speed (issue 15): CSV and log topics, the chord integrated from speed, the simulator's
wheel odometry with noise and a scale error, and the sources that carry it."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.config import ScaleConfig, VoConfig
from ampc_vo.errors import DatasetError
from ampc_vo.io.wheel_speed import WHEEL_SPEED_FILE, WheelSpeed, load_wheel_speed, read_wheel_speed_csv, write_wheel_speed_csv
from ampc_vo.scale.wheel import wheel_odometry_from_speed

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


def test_the_chord_is_the_integral_of_the_speed():
    # v = 5 + 2 t (exactly linear between samples): distance from t_i to t_j = 5 dt + (t_j² - t_i²)
    times = np.arange(0.0, 10.0001, 0.25)
    chord = wheel_odometry_from_speed(times, 5.0 + 2.0 * times)
    for t_i, t_j in ((0.0, 1.0), (0.13, 0.61), (3.3, 7.95)):
        assert chord(t_i, t_j) == pytest.approx(5.0 * (t_j - t_i) + t_j ** 2 - t_i ** 2, rel=1e-12)
    # a smooth speed profile sampled at 100 Hz: close to the analytic integral of 8 + sin t
    fine = np.arange(0.0, 20.0, 0.01)
    chord = wheel_odometry_from_speed(fine, 8.0 + np.sin(fine))
    assert chord(2.0, 4.5) == pytest.approx(8.0 * 2.5 + np.cos(2.0) - np.cos(4.5), abs=1e-4)
    assert chord(4.5, 2.0) == pytest.approx(chord(2.0, 4.5))
    assert chord(-1.0, 1.0) is None and chord(19.0, 25.0) is None  # no measurement outside the samples


def test_csv_round_trip_and_errors(tmp_path):
    samples = WheelSpeed(np.array([0.0, 0.02, 0.04]), np.array([8.0, 8.1, 8.2]))
    write_wheel_speed_csv(tmp_path / "speed.csv", samples)
    back = read_wheel_speed_csv(tmp_path / "speed.csv")
    np.testing.assert_array_equal(back.timestamps, samples.timestamps)
    np.testing.assert_array_equal(back.speed, samples.speed)
    (tmp_path / "bad.csv").write_text("timestamp,speed\n0.0,8.0\n0.1,fast\n")
    with pytest.raises(DatasetError, match="bad.csv: line 3"):
        read_wheel_speed_csv(tmp_path / "bad.csv")
    (tmp_path / "header.csv").write_text("time,v\n0.0,8.0\n")
    with pytest.raises(DatasetError, match="header must be timestamp,speed"):
        read_wheel_speed_csv(tmp_path / "header.csv")
    (tmp_path / "repeat.csv").write_text("timestamp,speed\n0.0,8.0\n0.0,8.0\n")
    with pytest.raises(DatasetError, match="repeated timestamps"):
        read_wheel_speed_csv(tmp_path / "repeat.csv")
    # a folder's wheel_speed.csv is found by itself; a named CSV wins; a topic needs a log
    folder = tmp_path / "folder"
    folder.mkdir()
    assert load_wheel_speed(None, folder) is None
    write_wheel_speed_csv(folder / WHEEL_SPEED_FILE, samples)
    assert len(load_wheel_speed(None, folder)) == 3
    with pytest.raises(DatasetError, match="is a topic, but the dataset is not a log"):
        load_wheel_speed("/vehicle/speed", folder)


@pytest.mark.parametrize("message_type", ["twist", "odometry"])
def test_a_speed_topic_of_a_log_is_read(tmp_path, message_type, tiny_dataset):
    import dataclasses

    from ampc_vo.io.bag_writer import RecordingContent, write_recording
    from ampc_vo.io.folder import read_dataset
    from ampc_vo.rig import replace_camera

    dataset = read_dataset(tiny_dataset)
    rig = dataclasses.replace(dataset.rig, cameras=tuple(replace_camera(c, topic=f"/{c.name}") for c in dataset.rig.cameras))
    dataset = dataclasses.replace(dataset, rig=rig)
    times = np.arange(0.0, 0.5, 0.02)
    log = write_recording(dataset, tmp_path / "log.bag", "ros1", RecordingContent(wheel_speed=(times, 7.0 + times), wheel_speed_type=message_type))
    speed = load_wheel_speed("/vehicle/wheel_speed", log)
    np.testing.assert_allclose(speed.timestamps, times, atol=1e-9)
    np.testing.assert_allclose(speed.speed, 7.0 + times, atol=1e-12)
    with pytest.raises(DatasetError, match=r"wheel-speed topic '/can/speed' is not in the log .*'/vehicle/wheel_speed'"):
        load_wheel_speed("/can/speed", log)
    with pytest.raises(DatasetError, match="carries sensor_msgs/msg/Image"):
        load_wheel_speed("/front", log)


def test_simulated_wheel_odometry_has_its_scale_error_and_noise(ci_simulation):
    from ampc_vo.sim.wheel_odometry import simulate_wheel_speed

    trajectory = ci_simulation.trajectory
    measured = simulate_wheel_speed(trajectory, scale_error=0.01, noise_sigma_mps=0.05, seed=4)
    residual = measured.speed - 1.01 * trajectory.speed
    assert abs(residual.mean()) < 0.03 and 0.035 < residual.std() < 0.065
    chord = wheel_odometry_from_speed(measured.timestamps, measured.speed)
    travelled = trajectory.arc_length[-1] - trajectory.arc_length[0]
    assert chord(trajectory.timestamps[0], trajectory.timestamps[-1]) == pytest.approx(1.01 * travelled, rel=2e-3)


def test_the_simulator_writes_wheel_speed_and_a_run_uses_it(tmp_path):
    from ampc_vo.frontend.sources import open_sequence
    from ampc_vo.sim.simulation import simulate_dataset
    from ampc_vo.tools.runner import sequence_wheel_odometry

    simulate_dataset(ROOT / "configs" / "sim" / "ci_short.yaml", tmp_path / "ds", with_images=False)
    assert (tmp_path / "ds" / WHEEL_SPEED_FILE).is_file()
    sequence = open_sequence(tmp_path / "ds", VoConfig())
    assert sequence.wheel_speed is not None and len(sequence.wheel_speed) == len(sequence)
    assert sequence_wheel_odometry(sequence, VoConfig()) is None  # off unless asked for
    config = VoConfig(scale=ScaleConfig(wheel_speed=True))
    chord = sequence_wheel_odometry(sequence, config)
    assert chord(sequence.timestamps[0], sequence.timestamps[10]) == pytest.approx(8.0 * 1.01 * 1.0, rel=0.02)
    (tmp_path / "ds" / WHEEL_SPEED_FILE).unlink()
    with pytest.raises(DatasetError, match="scale.wheel_speed is on but there is no wheel speed"):
        sequence_wheel_odometry(open_sequence(tmp_path / "ds", VoConfig()), config)
