"""Simulated landmarks and tracks agree with the ground truth (DESIGN 2, 6; issue 2)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from ampc_vo.io.folder import read_dataset
from ampc_vo.epipolar import gec_algebraic, gec_sampson
from ampc_vo.errors import DatasetError
from ampc_vo.geometry import invert_pose, relative_pose
from ampc_vo.io.measurements import load_measurements, save_measurements
from ampc_vo.sim.scene import Quad, Scene, swept_path_points
from ampc_vo.sim.simulation import LandmarkSet, _Occluders, occluded, visible_landmarks


def _pairs(measurements, camera_index, frame_i, frame_j):
    rows_i = np.flatnonzero((measurements.frame == frame_i) & (measurements.camera_index == camera_index))
    rows_j = np.flatnonzero((measurements.frame == frame_j) & (measurements.camera_index == camera_index))
    _, a, b = np.intersect1d(measurements.track_id[rows_i], measurements.track_id[rows_j], return_indices=True)
    return rows_i[a], rows_j[b]


def test_noise_free_bearings_satisfy_the_gec(ci_simulation):
    result = ci_simulation
    measurements, trajectory = result.measurements, result.trajectory
    checked = 0
    for camera_index, camera in enumerate(result.rig.cameras):
        poses = trajectory.pose(camera.body)
        for frame_i in range(0, len(trajectory) - 3, 5):
            frame_j = frame_i + 3
            rows_i, rows_j = _pairs(measurements, camera_index, frame_i, frame_j)
            assert len(rows_i) > 20
            f_i = camera.bearings_in_body(measurements.pixel_clean[rows_i])
            f_j = camera.bearings_in_body(measurements.pixel_clean[rows_j])
            T_i_j = relative_pose(poses[frame_i], poses[frame_j])
            residual = gec_algebraic(f_i, f_j, T_i_j[:3, :3], T_i_j[:3, 3], camera.center)
            assert np.max(np.abs(residual)) < 1e-9
            # A wrong motion violates it clearly (the check is not vacuous).
            wrong = gec_algebraic(f_i, f_j, T_i_j[:3, :3], T_i_j[:3, 3] + np.array([0.0, 0.3, 0.0]), camera.center)
            assert np.median(np.abs(wrong)) > 1e-3
            # Measured (noisy) bearings: inliers at the noise level, outliers far off.
            g_i = camera.bearings_in_body(measurements.pixel[rows_i])
            g_j = camera.bearings_in_body(measurements.pixel[rows_j])
            sampson = np.abs(gec_sampson(g_i, g_j, T_i_j[:3, :3], T_i_j[:3, 3], camera.center))
            inlier = ~(measurements.is_outlier[rows_i] | measurements.is_outlier[rows_j])
            assert np.median(sampson[inlier]) < 3.0 * 0.5 / camera.fx
            if np.sum(~inlier) >= 5:
                assert np.median(sampson[~inlier]) > 10.0 * 0.5 / camera.fx
            checked += len(rows_i)
    assert checked > 1000


def test_clean_pixels_are_projections_of_the_landmarks(ci_simulation):
    result = ci_simulation
    m = result.measurements
    for camera_index, camera in enumerate(result.rig.cameras):
        rows = np.flatnonzero(m.camera_index == camera_index)
        T_world_camera = result.trajectory.pose(camera.body)[m.frame[rows]] @ camera.T_body_camera
        T_camera_world = np.stack([invert_pose(pose) for pose in T_world_camera])
        points = np.einsum("rab,rb->ra", T_camera_world[:, :3, :3], m.landmarks[m.landmark_id[rows]]) + T_camera_world[:, :3, 3]
        pixels, valid = camera.project(points)
        assert np.all(valid)
        assert np.max(np.abs(pixels - m.pixel_clean[rows])) < 1e-9
        assert np.all(points[:, 2] >= result.config.min_range_m)
        assert np.all(np.linalg.norm(points, axis=1) <= result.config.max_range_m)


def test_outlier_fraction_and_pixel_noise_as_configured(ci_simulation):
    m, config = ci_simulation.measurements, ci_simulation.config
    assert abs(m.is_outlier.mean() - config.outlier_fraction) < 0.005
    for frame in (0, 20, 40):
        for camera in m.camera_names:
            rows = m.rows(frame, camera)
            assert m.is_outlier[rows].sum() == round(config.outlier_fraction * len(rows))
    error = m.pixel[~m.is_outlier] - m.pixel_clean[~m.is_outlier]
    assert abs(error.std() - config.pixel_noise_px) < 0.05 * config.pixel_noise_px
    assert abs(error.mean()) < 0.02
    outlier_error = np.linalg.norm(m.pixel[m.is_outlier] - m.pixel_clean[m.is_outlier], axis=1)
    assert np.median(outlier_error) > 50.0


def test_tracks_persist_and_are_consistent(ci_simulation):
    m, config = ci_simulation.measurements, ci_simulation.config
    for camera_index in range(len(m.camera_names)):
        rows = m.camera_index == camera_index
        tracks, frames, landmarks = m.track_id[rows], m.frame[rows], m.landmark_id[rows]
        per_frame = np.bincount(frames, minlength=m.frame_count)
        assert per_frame.max() <= config.max_tracks_per_camera
        assert per_frame.min() >= 60
        order = np.lexsort((frames, tracks))
        tracks, frames, landmarks = tracks[order], frames[order], landmarks[order]
        same_track = tracks[1:] == tracks[:-1]
        assert np.all(landmarks[1:][same_track] == landmarks[:-1][same_track])  # one landmark per track
        assert np.all(frames[1:][same_track] - frames[:-1][same_track] == 1)    # contiguous frames
        _, lengths = np.unique(tracks, return_counts=True)
        assert lengths.mean() > 8.0
    # Track ids are unique over cameras too.
    owners = {}
    for track, camera_index in zip(m.track_id.tolist(), m.camera_index.tolist()):
        assert owners.setdefault(track, camera_index) == camera_index


def _wall(x: float, y0: float, width: float, height: float) -> Quad:
    """A vertical wall in the plane x = const, facing -x."""
    return Quad(np.array([x, y0 + width, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), width, height, "facade", "brick")


def test_points_behind_a_wall_are_not_visible(default_rig):
    camera = default_rig.camera("front")
    wall = _wall(10.0, -2.0, 4.0, 5.0)
    far_wall = _wall(30.0, -20.0, 40.0, 10.0)
    scene = Scene((wall, far_wall))
    behind = np.array([[30.0, 0.0, 1.0], [30.0, 0.5, 2.0]])      # hidden by the near wall
    beside = np.array([[30.0, 8.0, 1.0], [30.0, -9.0, 2.0]])     # visible past its edges
    on_wall = wall.points(np.array([[1.0, 1.0], [3.0, 4.0]]))    # on the near wall itself
    points = np.concatenate([behind, beside, on_wall])
    quad_index = np.array([1, 1, 1, 1, 0, 0])
    landmarks = LandmarkSet(points, quad_index)
    from scipy.spatial import cKDTree

    T_world_camera = np.eye(4) @ camera.T_body_camera
    ids, _ = visible_landmarks(camera, T_world_camera, landmarks, cKDTree(points), _Occluders.from_scene(scene), 100.0, 0.5)
    assert sorted(ids.tolist()) == [2, 3, 4, 5]


def _occluded_brute_force(center, point, quads, own):
    """Independent scalar reference: does segment center->point cross any vertical quad but its own?"""
    for index, quad in enumerate(quads):
        if index == own or quad.kind not in ("facade", "box", "pole"):
            continue
        normal = quad.normal
        denominator = normal @ (point - center)
        if abs(denominator) < 1e-12:
            continue
        t = normal @ (quad.origin - center) / denominator
        if not 1e-6 < t < 1 - 1e-6:
            continue
        hit = center + t * (point - center) - quad.origin
        if 0 <= hit @ quad.axis_u <= quad.width and 0 <= hit @ quad.axis_v <= quad.height:
            return True
    return False


def test_visible_landmarks_are_not_occluded_by_any_quad(ci_simulation):
    result = ci_simulation
    m, quads = result.measurements, result.scene.quads
    own = result.landmarks.quad_index
    rng = np.random.default_rng(0)
    for row in rng.choice(len(m), size=150, replace=False):
        camera = result.rig.cameras[m.camera_index[row]]
        center = (result.trajectory.pose(camera.body)[m.frame[row]] @ camera.T_body_camera)[:3, 3]
        landmark = m.landmark_id[row]
        assert not _occluded_brute_force(center, m.landmarks[landmark], quads, own[landmark])
    # And the vectorised test agrees with the reference on random segments through the scene.
    center = result.trajectory.T_world_tractor[10, :3, 3] + np.array([0.0, 0.0, 2.5])
    points = result.landmarks.points[rng.choice(len(result.landmarks.points), size=300, replace=False)]
    hidden = occluded(center, points, _Occluders.from_scene(result.scene))
    reference = np.array([_occluded_brute_force(center, point, quads, -1) for point in points])
    assert np.array_equal(hidden, reference)
    assert 0 < hidden.sum() < len(points)


def test_landmarks_lie_on_their_quads(ci_simulation):
    landmarks, quads = ci_simulation.landmarks, ci_simulation.scene.quads
    for index in np.unique(landmarks.quad_index)[::3]:
        quad = quads[index]
        relative = landmarks.points[landmarks.quad_index == index] - quad.origin
        assert np.max(np.abs(relative @ quad.normal)) < 1e-9
        a, b = relative @ quad.axis_u, relative @ quad.axis_v
        assert np.all((a >= -1e-9) & (a <= quad.width + 1e-9) & (b >= -1e-9) & (b <= quad.height + 1e-9))


def test_scene_keeps_the_swept_path_clear_and_surrounds_start_and_end(ci_simulation):
    result = ci_simulation
    clearance = result.config.scene.clearance
    path = swept_path_points(result.trajectory.T_world_tractor, result.trajectory.T_world_trailer)
    vertical = [quad for quad in result.scene.quads if quad.kind in ("facade", "box", "pole")]
    assert {quad.kind for quad in result.scene.quads} >= {"road", "ground", "facade", "box", "pole"}
    for quad in vertical:
        base = quad.origin[:2] + np.linspace(0.0, quad.width, 20)[:, None] * quad.axis_u[:2]
        distance = np.min(np.linalg.norm(base[:, None, :] - path[None, :, :], axis=2))
        assert distance >= clearance
    # Facades on both sides behind the start (seen by the rear camera) and beyond the end.
    start, end = result.trajectory.T_world_tractor[0], result.trajectory.T_world_tractor[-1]
    for pose, direction in ((start, -1.0), (end, 1.0)):
        sides = set()
        for quad in vertical:
            if quad.kind != "facade":
                continue
            local = invert_pose(pose)[:3, :3] @ (quad.origin + 0.5 * quad.width * quad.axis_u) + invert_pose(pose)[:3, 3]
            if 15.0 < direction * local[0] < 60.0:
                sides.add(np.sign(local[1]))
        assert sides == {-1.0, 1.0}


def test_measurements_save_load_and_observations(tmp_path, ci_simulation):
    m, rig = ci_simulation.measurements, ci_simulation.rig
    path = tmp_path / "measurements.npz"
    save_measurements(m, path)
    loaded = load_measurements(path, rig)
    for name in ("frame", "camera_index", "track_id", "landmark_id", "pixel", "pixel_clean", "is_outlier", "landmarks", "timestamps"):
        assert np.array_equal(getattr(loaded, name), getattr(m, name)), name
    assert loaded.camera_names == m.camera_names
    observations = loaded.observations(7)
    assert observations.frame == 7 and observations.timestamp == pytest.approx(0.7)
    rear = observations.cameras["rear"]
    rows = m.rows(7, "rear")
    assert np.array_equal(rear.track_ids, m.track_id[rows])
    assert np.allclose(rear.bearings, rig.camera("rear").unproject(m.pixel[rows]), atol=0)
    assert sum(1 for _ in loaded.frames()) == m.frame_count


def test_corrupt_measurements_file(tmp_path, ci_simulation):
    path = tmp_path / "measurements.npz"
    path.write_bytes(b"not a zip file")
    with pytest.raises(DatasetError, match="not a readable .npz"):
        load_measurements(path)
    np.savez(path, frame=np.zeros(3, np.int64))
    with pytest.raises(DatasetError, match="missing array"):
        load_measurements(path)
    with pytest.raises(DatasetError, match="not found"):
        load_measurements(tmp_path / "absent.npz")


def test_simulate_sequence_script_writes_a_readable_dataset(tmp_path, repo_root):
    out = tmp_path / "ci"
    completed = subprocess.run(
        [sys.executable, str(repo_root / "scripts" / "simulate_sequence.py"), "--config", str(repo_root / "configs" / "sim" / "ci_short.yaml"),
         "--out", str(out), "--no-images"], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    assert "images not written" in completed.stdout
    dataset = read_dataset(out)
    assert not dataset.has_images
    assert dataset.measurements is not None and dataset.measurements.frame_count == len(dataset)
    assert dataset.groundtruth is not None and len(dataset.groundtruth) == len(dataset)


def test_an_out_path_that_is_a_file_is_an_output_error(tmp_path, repo_root):
    """It used to be a FileExistsError traceback after the simulation."""
    from ampc_vo.errors import OutputError
    from ampc_vo.sim.simulation import simulate_dataset

    (tmp_path / "taken").write_text("x")
    with pytest.raises(OutputError, match="taken: cannot create the dataset folder"):
        simulate_dataset(repo_root / "configs" / "sim" / "ci_short.yaml", tmp_path / "taken", with_images=False)
