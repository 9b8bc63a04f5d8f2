"""Camera timing against independent truth (issue 13): poses between samples, per-camera capture
times, rolling-shutter rows and the cross-camera associations a frontend could make."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import planar_pose
from ampc_vo.io.folder import read_dataset
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.io.measurements import load_measurements, save_measurements
from ampc_vo.rig import Rig, replace_camera
from ampc_vo.sim.camera_settings import CameraSettings, camera_settings_from_dict
from ampc_vo.sim.camera_timing import capture_times
from ampc_vo.sim.config import SimulationConfig, load_sim_config
from ampc_vo.sim.motion import sample_poses
from ampc_vo.sim.scene import Scene
from ampc_vo.sim.simulation import LandmarkSet, simulate_measurements

SPEED, YAW_RATE, RADIUS = 10.0, 0.4, 25.0  # a circle: v = 10 m/s, yaw rate 0.4 rad/s


def _circle_pose(t: np.ndarray | float) -> np.ndarray:
    """Analytic pose on a circle of radius v / yaw_rate (the truth; constant twist)."""
    t = np.atleast_1d(np.asarray(t, float))
    radius = SPEED / YAW_RATE
    return np.stack([planar_pose(radius * math.sin(YAW_RATE * s), radius * (1 - math.cos(YAW_RATE * s)), YAW_RATE * s, 0.3) for s in t])


def _circle_trajectory(count: int = 30, rate: float = 10.0) -> Trajectory:
    times = np.arange(count) / rate
    poses = _circle_pose(times)
    return Trajectory(times, poses, poses.copy(), np.zeros(count))


def test_sample_poses_follows_the_screw_motion_between_and_beyond_samples():
    trajectory = _circle_trajectory()
    times = np.array([0.0, 0.05, 0.137, 1.0, 2.3456, 2.9, -0.03, 2.95])  # inside, at samples, before, after
    sampled = sample_poses(trajectory, "tractor", times)
    np.testing.assert_allclose(sampled, _circle_pose(times), atol=1e-9)
    # Linear interpolation of the position would miss the arc by its sagitta (mm): not what we do.
    chord_mid = 0.5 * (trajectory.T_world_tractor[3, :3, 3] + trajectory.T_world_tractor[4, :3, 3])
    assert np.linalg.norm(chord_mid - _circle_pose(0.35)[0, :3, 3]) > 1e-3
    np.testing.assert_array_equal(sample_poses(trajectory, "trailer", trajectory.timestamps[5:6])[0], trajectory.T_world_trailer[5])
    from ampc_vo.sim.motion import PoseSampler

    np.testing.assert_allclose(PoseSampler.of(trajectory, "tractor")(times), _circle_pose(times), atol=1e-9)


def test_capture_times_have_the_configured_offset_and_jitter():
    frame_times = np.arange(2000) * 0.1
    settings = CameraSettings(offset_s=0.023, jitter_s=0.002)
    times = capture_times(frame_times, settings, np.random.default_rng(1))
    delta = times - frame_times
    assert abs(delta.mean() - 0.023) < 3 * 0.002 / math.sqrt(2000)
    assert 0.0019 < delta.std() < 0.0021 and np.max(np.abs(delta - 0.023)) <= 3 * 0.002 + 1e-12
    with pytest.raises(ConfigError, match="reorders"):
        capture_times(np.arange(50) * 0.01, CameraSettings(jitter_s=0.02), np.random.default_rng(1))


def test_camera_settings_section_parses_defaults_overrides_and_rejects_bad_values():
    table = camera_settings_from_dict({"all": {"jitter_ms": 1, "exposure_ms": 8}, "left": {"offset_ms": 23}}, "x.yaml")
    assert table.get("left") == CameraSettings(offset_s=0.023, jitter_s=0.001, exposure_s=0.008)
    assert table.get("front") == CameraSettings(jitter_s=0.001, exposure_s=0.008)
    for bad, message in (({"left": {"offset": 1}}, "unknown camera setting"), ({"left": {"vignetting": 2}}, r"cameras.left.vignetting"),
                         ({"all": {"auto_exposure": 1}}, "true or false"), ({"left": 3}, "mapping")):
        with pytest.raises(ConfigError, match=message):
            camera_settings_from_dict(bad, "x.yaml")


def _single_camera_rig(default_rig, readout: float) -> Rig:
    front = replace_camera(default_rig.camera("front"), readout_time=readout)
    return Rig(default_rig.bodies, (front,))


def _points_ahead(count: int, rng: np.random.Generator) -> LandmarkSet:
    """Points on a wall band around the circle ahead (seen by the front camera)."""
    angle = rng.uniform(0.1, 1.2, count)
    radius = RADIUS + rng.choice([-1, 1], count) * rng.uniform(4.0, 9.0, count)
    points = np.stack([radius * np.sin(angle), RADIUS - radius * np.cos(angle), rng.uniform(0.2, 4.0, count)], axis=1)
    return LandmarkSet(points, np.full(count, -1, np.int64))


def test_rolling_shutter_pixels_are_projections_with_the_pose_at_their_row_time(default_rig):
    readout = 0.03
    rig = _single_camera_rig(default_rig, readout)
    camera = rig.cameras[0]
    trajectory = _circle_trajectory(20)
    landmarks = _points_ahead(3000, np.random.default_rng(2))
    config = SimulationConfig("test", rig_path=None, route=None, pixel_noise_px=0.0, outlier_fraction=0.0, max_range_m=40.0)
    capture = {"front": trajectory.timestamps + 0.017}
    m = simulate_measurements(trajectory, rig, landmarks, Scene(()), config, np.random.default_rng(3), capture)
    np.testing.assert_allclose(m.camera_timestamps[:, 0], capture["front"])
    assert len(m) > 1000
    row_times = m.camera_timestamps[m.frame, 0] + readout * m.pixel_clean[:, 1] / (camera.height - 1)
    poses = _circle_pose(row_times) @ camera.T_body_camera
    points_camera = np.einsum("nji,nj->ni", poses[:, :3, :3], m.landmarks[m.landmark_id] - poses[:, :3, 3])
    expected, valid = camera.project(points_camera)
    assert valid.all()
    np.testing.assert_allclose(m.pixel_clean, expected, atol=1e-5)
    # A global-shutter projection at the capture time is clearly different (the check can fail).
    poses_global = _circle_pose(m.camera_timestamps[m.frame, 0]) @ camera.T_body_camera
    global_camera = np.einsum("nji,nj->ni", poses_global[:, :3, :3], m.landmarks[m.landmark_id] - poses_global[:, :3, 3])
    global_pixels, _ = camera.project(global_camera)
    assert np.percentile(np.linalg.norm(global_pixels - m.pixel_clean, axis=1), 90) > 2.0
    # The observations carry the camera's capture time.
    observations = m.observations(4)
    assert observations.camera_timestamp("front") == pytest.approx(capture["front"][4])


def test_no_landmark_ids_across_cameras_that_do_not_overlap(ci_simulation):
    m = ci_simulation.measurements
    assert m.association_id is not None and np.all(m.association_id == -1)   # default rig: no overlapping views
    for frame in (0, 10):
        for observations in m.observations(frame).cameras.values():
            assert np.all(observations.landmark_ids == -1)


def test_overlapping_cameras_are_associated_in_the_same_frame_only(repo_root, fisheye_rig):
    from ampc_vo.sim.associations import overlapping_pairs
    from ampc_vo.sim.simulation import simulate

    assert overlapping_pairs(fisheye_rig) == [("front", "left"), ("rear", "right")]
    config = load_sim_config(repo_root / "configs" / "sim" / "ci_short.yaml")
    result = simulate(config, fisheye_rig)
    m = result.measurements
    associated = np.flatnonzero(m.association_id >= 0)
    assert len(associated) > 100
    names = np.array(m.camera_names)
    group = {"front": 0, "left": 0, "rear": 1, "right": 1}
    for association in np.unique(m.association_id[associated])[:400]:
        rows = np.flatnonzero(m.association_id == association)
        assert len(set(m.landmark_id[rows])) == 1                      # one physical point
        assert len({group[name] for name in names[m.camera_index[rows]]}) == 1  # one overlapping group
        assert not m.is_outlier[rows].any()
        for frame in np.unique(m.frame[rows]):                          # stereo: two cameras in that frame
            assert len(set(m.camera_index[rows[m.frame[rows] == frame]])) >= 2
    # Landmarks seen by both cameras of a pair in the same frame are all associated.
    rows = np.flatnonzero(~m.is_outlier)
    row_group = np.array([group[name] for name in names[m.camera_index[rows]]])
    key = (m.frame[rows] * 10**7 + m.landmark_id[rows]) * 2 + row_group
    values, counts = np.unique(key, return_counts=True)
    shared = np.isin(key, values[counts >= 2])
    assert np.all(m.association_id[rows[shared]] >= 0) and np.all(m.association_id[rows[~shared]] == -1)


def test_capture_times_reach_frames_csv_and_measurements_npz(tmp_path, repo_root):
    from ampc_vo.sim.simulation import simulate_dataset

    text = (repo_root / "configs" / "sim" / "ci_short.yaml").read_text()
    path = tmp_path / "timed.yaml"
    path.write_text(text.replace("rig: ../rigs/default.yaml", f"rig: {repo_root / 'configs' / 'rigs' / 'default.yaml'}")
                    + "\ncameras:\n  all: {jitter_ms: 1.0}\n  left: {offset_ms: 23}\n  rear: {offset_ms: -11}\n")
    result = simulate_dataset(path, tmp_path / "out", with_images=False)
    dataset = read_dataset(tmp_path / "out")
    for camera in ("front", "left", "rear", "right"):
        np.testing.assert_allclose(dataset.camera_timestamps[camera], result.capture_times[camera])
    offsets = result.capture_times["left"] - result.trajectory.timestamps
    assert abs(np.mean(offsets) - 0.023) < 0.001
    loaded = load_measurements(tmp_path / "out" / "measurements.npz", result.rig)
    np.testing.assert_allclose(loaded.camera_timestamps[:, 1], result.capture_times["left"])
    np.testing.assert_array_equal(loaded.association_id, result.measurements.association_id)
    # The clean pixels are the projections at each camera's own capture time.
    camera_index = 1
    camera = result.rig.cameras[camera_index]
    rows = np.flatnonzero(loaded.camera_index == camera_index)[:500]
    times = loaded.camera_timestamps[loaded.frame[rows], camera_index]
    poses = sample_poses(result.trajectory, camera.body, times) @ camera.T_body_camera
    points = np.einsum("nji,nj->ni", poses[:, :3, :3], loaded.landmarks[loaded.landmark_id[rows]] - poses[:, :3, 3])
    expected, _ = camera.project(points)
    np.testing.assert_allclose(loaded.pixel_clean[rows], expected, atol=1e-6)


def test_older_measurement_files_without_associations_warn(tmp_path, ci_simulation, caplog):
    import dataclasses

    m = dataclasses.replace(ci_simulation.measurements, association_id=None, camera_timestamps=None)
    save_measurements(m, tmp_path / "old.npz")
    with caplog.at_level("WARNING"):
        loaded = load_measurements(tmp_path / "old.npz")
    assert "truth leak" in caplog.text and loaded.association_id is None
