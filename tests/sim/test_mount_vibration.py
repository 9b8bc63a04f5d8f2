"""Camera-mount vibration applied (issue 13, DESIGN 6): the simulated bearings and the rendered images
come from the vibrating mount ``T_world_body T_body_camera R_mount(t)`` at each capture and row time,
checked against an analytic motion and an analytic vibration, independently of the simulator's
pose sampling and projection code; the rig handed to the estimator keeps the nominal mounts."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ampc_vo.geometry import planar_pose, rot_x, rot_y, rot_z
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.rig import Rig, replace_camera
from ampc_vo.sim.config import SimulationConfig
from ampc_vo.sim.render import Renderer, RenderOptions, render_sequence
from ampc_vo.sim.scene import Quad, Scene
from ampc_vo.sim.simulation import LandmarkSet, simulate_measurements
from ampc_vo.sim.textures import build_atlas, load_textures
from sim_support import facing_marker

SPEED, YAW_RATE = 10.0, 0.4
AMPLITUDE = np.radians([0.8, -0.6, 0.3])    # mount roll about camera x, y, z (large: pixels move by ~7 px)
FREQUENCY_HZ = np.array([6.0, 9.0, 4.0])
DENSE_HZ = 2000.0


def _body_pose(t: np.ndarray) -> np.ndarray:
    """Analytic tractor pose on a circle (constant twist), as in test_camera_timing."""
    radius = SPEED / YAW_RATE
    return np.stack([planar_pose(radius * math.sin(YAW_RATE * s), radius * (1 - math.cos(YAW_RATE * s)), YAW_RATE * s, 0.3)
                     for s in np.atleast_1d(t)])


def _mount_rotation(t: np.ndarray) -> np.ndarray:
    """Analytic bracket rotation (N, 3, 3): ``Rz Ry Rx`` of three sinusoids about the camera axes."""
    angles = AMPLITUDE[None, :] * np.sin(2 * np.pi * FREQUENCY_HZ[None, :] * np.atleast_1d(t)[:, None] + np.array([0.3, 1.1, 2.0]))
    return np.stack([rot_z(c) @ rot_y(b) @ rot_x(a) for a, b, c in angles])


def _dense_world(duration: float, rig: Rig) -> tuple[Trajectory, Trajectory, dict[str, np.ndarray]]:
    """Camera-rate trajectory (10 Hz), the same motion at 2 kHz (0.1 s longer: the last capture and
    its rows come after the last frame time) and each camera's sampled vibration."""
    times = np.arange(0.0, duration + 0.1 + 1e-9, 1.0 / DENSE_HZ)
    poses = _body_pose(times)
    dense = Trajectory(times, poses, poses.copy(), np.zeros(len(times)))
    frames = slice(0, int(round(duration * DENSE_HZ)) + 1, int(DENSE_HZ / 10))
    trajectory = Trajectory(times[frames], poses[frames], poses[frames].copy(), np.zeros(len(times[frames])))
    return trajectory, dense, {camera.name: _mount_rotation(times) for camera in rig.cameras}


def _project(camera, T_world_camera: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels of world points (N, 3) from per-point camera poses (N, 4, 4) (NaN where not in the image)."""
    points_camera = np.einsum("nji,nj->ni", T_world_camera[:, :3, :3], points - T_world_camera[:, :3, 3])
    pixels, valid = camera.project(points_camera)
    return np.where(valid[:, None], pixels, np.nan)


def test_bearings_are_projected_from_the_vibrating_mount_at_each_row_time(default_rig):
    readout = 0.03
    camera = replace_camera(default_rig.camera("front"), readout_time=readout)
    rig = Rig(default_rig.bodies, (camera,))
    trajectory, dense, mounts = _dense_world(1.5, rig)
    rng = np.random.default_rng(5)
    angle = rng.uniform(0.1, 1.2, 2000)
    radius = SPEED / YAW_RATE + rng.choice([-1, 1], 2000) * rng.uniform(4.0, 9.0, 2000)
    points = np.stack([radius * np.sin(angle), SPEED / YAW_RATE - radius * np.cos(angle), rng.uniform(0.2, 4.0, 2000)], axis=1)
    config = SimulationConfig("test", rig_path=None, route=None, pixel_noise_px=0.0, outlier_fraction=0.0, max_range_m=40.0)
    capture = {"front": trajectory.timestamps + 0.011}
    m = simulate_measurements(trajectory, rig, LandmarkSet(points, np.full(2000, -1, np.int64)), Scene(()), config,
                              np.random.default_rng(3), capture, pose_trajectory=dense, mount_vibration=mounts)
    assert len(m) > 1000
    np.testing.assert_array_equal(m.rig.camera("front").T_body_camera, default_rig.camera("front").T_body_camera)  # nominal rig
    row_times = m.camera_timestamps[m.frame, 0] + readout * m.pixel_clean[:, 1] / (camera.height - 1)
    vibrating = _body_pose(row_times) @ camera.T_body_camera
    vibrating[:, :3, :3] = vibrating[:, :3, :3] @ _mount_rotation(row_times)
    truth = _project(camera, vibrating, m.landmarks[m.landmark_id])
    inside = np.isfinite(truth[:, 0])                        # all but points within 1e-3 px of the border
    assert inside.mean() > 0.995
    error = np.linalg.norm(truth[inside] - m.pixel_clean[inside], axis=1)
    print(f"max {error.max():.2e} px, median {np.median(error):.2e}")
    assert error.max() < 2e-3
    nominal = _project(camera, _body_pose(row_times) @ camera.T_body_camera, m.landmarks[m.landmark_id])
    assert np.nanpercentile(np.linalg.norm(nominal - m.pixel_clean, axis=1), 50) > 3.0   # the vibration is there


@pytest.fixture(scope="module")
def atlas():
    return build_atlas(load_textures(("marker",)))


def _marker(centre: np.ndarray, normal: np.ndarray, size: float = 0.8) -> Quad:
    return facing_marker(centre, normal, size)


def test_images_are_rendered_from_the_vibrating_mount(default_rig, atlas, tmp_path):
    camera = default_rig.camera("front")
    rig = Rig(default_rig.bodies, (camera,))
    trajectory, dense, mounts = _dense_world(0.3, rig)
    frame = 2
    capture = float(trajectory.timestamps[frame]) + 0.013          # between dense samples: interpolated mount
    T_true = _body_pose(capture)[0] @ camera.T_body_camera
    T_true[:3, :3] = T_true[:3, :3] @ _mount_rotation(capture)[0]
    corners, quads = [], []
    for u in (0.25, 0.5, 0.75):
        for v in (0.3, 0.7):
            ray = camera.unproject(np.array([[u * camera.width, v * camera.height]]))[0]
            corner = T_true[:3, :3] @ (6.0 * ray) + T_true[:3, 3]
            corners.append(corner)
            quads.append(_marker(corner, T_true[:3, 3] - corner))
    scene = Scene(tuple(quads))
    options = RenderOptions(processes=1, shading=False)
    render_sequence(tmp_path, rig, trajectory, scene, options, progress=False, renderer=Renderer(scene, atlas, options),
                    capture_times={"front": trajectory.timestamps + 0.013}, pose_trajectory=dense, mount_vibration=mounts)
    image = cv2.imread(str(tmp_path / "images" / "front" / f"{frame:06d}.png"), cv2.IMREAD_GRAYSCALE)
    corners = np.array(corners)
    truth = _project(camera, np.repeat(T_true[None], len(corners), axis=0), corners)
    nominal_pose = _body_pose(capture)[0] @ camera.T_body_camera
    nominal = _project(camera, np.repeat(nominal_pose[None], len(corners), axis=0), corners)
    assert np.min(np.linalg.norm(nominal - truth, axis=1)) > 3.0
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)
    found = cv2.cornerSubPix(image, truth.astype(np.float32).reshape(-1, 1, 2).copy(), (5, 5), (-1, -1), criteria).reshape(-1, 2)
    assert np.max(np.linalg.norm(found - truth, axis=1)) < 0.3
