"""Image formation and moving bodies against independent truth (issue 13): sensor noise (photon
transfer), vignetting (cos^4), auto exposure, rolling shutter and blur in rendered images, traffic
and the trailer box in images and bearing measurements."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import planar_pose
from ampc_vo.io.groundtruth import Trajectory
from ampc_vo.rig import Rig, replace_camera
from ampc_vo.sim.camera_effects import auto_exposure, expose, vignetting_factor
from ampc_vo.sim.camera_settings import CameraSettings, CameraSettingsTable
from ampc_vo.sim.render import Renderer, render_sequence
from ampc_vo.sim.scene import Quad, Scene
from ampc_vo.sim.textures import build_atlas, load_textures
from sim_support import facing_marker


@pytest.fixture(scope="module")
def atlas():
    return build_atlas(load_textures(("asphalt", "marker", "metal", "paint", "wood", "concrete")))


def test_sensor_noise_follows_the_photon_transfer_curve():
    settings = CameraSettings(full_well_e=5000.0, read_noise_e=12.0, max_gain=8.0)
    rng = np.random.default_rng(0)
    for level in (5.0, 40.0, 120.0, 200.0):
        for amplification in (1.0, 2.5):
            flat = np.full((400, 500), level / amplification, np.float32)
            out = expose(flat, amplification, settings, rng)
            gain = amplification  # exposure is already at its nominal maximum (1): the rest is gain
            expected = 255 * gain / 5000 * level + (255 * gain * 12 / 5000) ** 2   # EMVA 1288: K mu + (K sigma_d)^2
            assert out.var() == pytest.approx(expected, rel=0.03), (level, amplification)
            assert out.mean() == pytest.approx(level, abs=0.05)
    bright = expose(np.full((100, 100), 100.0, np.float32), 0.5, settings, rng)  # exposure halved, gain 1
    assert bright.var() == pytest.approx(255 / 5000 * 50 + (255 * 12 / 5000) ** 2, rel=0.05)


def test_vignetting_is_the_cos4_law(default_rig):
    camera = default_rig.camera("front")
    renderer = Renderer(Scene(()), build_atlas(load_textures(("marker",))))
    factor = vignetting_factor(renderer.rays_of(camera).rays_planes[2], 1.0)
    for u, v in ((0, 0), (639, 479), (320, 240), (100, 400)):
        angle = math.atan(math.hypot((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy))
        assert factor[v, u] == pytest.approx(math.cos(angle) ** 4, rel=1e-5)
    half = vignetting_factor(renderer.rays_of(camera).rays_planes[2], 0.5)
    assert half[0, 0] == pytest.approx(1 - 0.5 * (1 - factor[0, 0]), rel=1e-5)


def test_auto_exposure_reacts_to_a_tunnel_with_its_time_constant():
    settings = CameraSettings(auto_exposure=True, target_grey=100.0, exposure_time_constant_s=0.5, max_gain=8.0)
    times = np.arange(60) * 0.1
    brightness = np.where(times < 2.0, 200.0, 25.0)         # unit-exposure brightness drops at 2 s
    amplification = auto_exposure(brightness, times, settings)
    assert amplification[0] == pytest.approx(0.5)
    assert amplification[20] == pytest.approx(0.5)           # frame 20 (t = 2 s) still uses the bright frame 19
    decay = math.exp(-0.1 / 0.5)
    for k in (21, 25, 30):                                   # log error decays by exp(-dt / tau) per frame
        expected = math.exp(math.log(4.0) - (math.log(4.0) - math.log(0.5)) * decay ** (k - 20))
        assert amplification[k] == pytest.approx(expected, rel=1e-9)
    assert amplification[-1] == pytest.approx(4.0, rel=0.01)
    dark = auto_exposure(np.full(5, 1.0), times[:5], settings)
    assert np.all(dark == pytest.approx(8.0))                # limited by max_gain
    assert np.all(auto_exposure(brightness, times, CameraSettings()) == 1.0)


def _marker(centre: np.ndarray, normal: np.ndarray, size: float = 1.2) -> Quad:
    return facing_marker(centre, normal, size)


def _arc_pose(t: np.ndarray, speed: float = 12.0, yaw_rate: float = 0.8) -> np.ndarray:
    radius = speed / yaw_rate
    return np.stack([planar_pose(radius * math.sin(yaw_rate * s), radius * (1 - math.cos(yaw_rate * s)), yaw_rate * s) for s in np.atleast_1d(t)])


def _rolling_shutter_truth(camera, point: np.ndarray, capture: float) -> np.ndarray:
    """Independent fixed point: pixel of ``point`` with the analytic pose at the time of its row."""
    v = camera.height / 2
    for _ in range(20):
        T = _arc_pose(capture + camera.readout_time * v / (camera.height - 1))[0] @ camera.T_body_camera
        R, c = T[:3, :3], T[:3, 3]
        pixel, _ = camera.project((R.T @ (point - c))[None])
        v = pixel[0, 1]
    return pixel[0]


@pytest.mark.parametrize("exposure_ms", [0.0, 6.0])
def test_rolling_shutter_images_show_each_row_at_its_time(default_rig, atlas, tmp_path, exposure_ms):
    """Checker corners in a rolling-shutter image (fast turn) lie where the pose at their row's time
    projects them; a global-shutter projection misses by pixels. With motion blur the corner stays."""
    camera = replace_camera(default_rig.camera("front"), readout_time=0.03)
    rig = Rig(default_rig.bodies, (camera,))
    times = np.arange(0, 0.4, 0.01)
    poses = _arc_pose(times)
    trajectory = Trajectory(times[::10], poses[::10], poses[::10].copy(), np.zeros(4))
    dense = Trajectory(times, poses, poses.copy(), np.zeros(len(times)))
    capture = float(trajectory.timestamps[1]) + 0.004
    T_middle = _arc_pose(capture + 0.015)[0] @ camera.T_body_camera
    corners, quads = [], []
    for u in (0.2, 0.5, 0.8):
        for v in (0.15, 0.5, 0.85):
            ray = camera.unproject(np.array([[u * camera.width, v * camera.height]]))[0]
            corner = T_middle[:3, :3] @ (6.0 * ray) + T_middle[:3, 3]
            corners.append(corner)
            quads.append(_marker(corner, T_middle[:3, 3] - corner))
    scene = Scene(tuple(quads))
    settings = CameraSettingsTable(CameraSettings(exposure_s=exposure_ms / 1000.0, motion_blur_samples=6))
    from ampc_vo.sim.render import RenderOptions

    options = RenderOptions(processes=1, shading=False)
    capture_times = {"front": trajectory.timestamps + 0.004}
    render_sequence(tmp_path, rig, trajectory, scene, options, progress=False, renderer=Renderer(scene, atlas, options),
                    capture_times=capture_times, camera_settings=settings, pose_trajectory=dense)
    image = cv2.imread(str(tmp_path / "images" / "front" / "000001.png"), cv2.IMREAD_GRAYSCALE)
    truth = np.array([_rolling_shutter_truth(camera, corner, capture) for corner in corners])
    global_shutter = []
    for corner in corners:
        T = _arc_pose(capture)[0] @ camera.T_body_camera
        global_shutter.append(camera.project((T[:3, :3].T @ (corner - T[:3, 3]))[None])[0][0])
    assert np.max(np.linalg.norm(np.array(global_shutter) - truth, axis=1)) > 4.0      # the effect is visible
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)
    found = cv2.cornerSubPix(image, truth.astype(np.float32).reshape(-1, 1, 2).copy(), (6, 6), (-1, -1), criteria).reshape(-1, 2)
    errors = np.linalg.norm(found - truth, axis=1)
    assert np.max(errors) < 0.6, errors


def _straight_trajectory(count: int = 40, speed: float = 8.0, rate: float = 10.0) -> Trajectory:
    times = np.arange(count) / rate
    tractor = np.stack([planar_pose(speed * t, 0.0, 0.0) for t in times])
    trailer = np.stack([planar_pose(speed * t, 0.0, 0.0) for t in times])
    return Trajectory(times, tractor, trailer, np.zeros(count), speed=np.full(count, speed), arc_length=speed * times)


def test_traffic_tracks_move_with_their_vehicles(default_rig, repo_root):
    from ampc_vo.sim.config import sim_config_from_dict
    from ampc_vo.sim.scene import route_centerline
    from ampc_vo.sim.simulation import LandmarkSet, simulate_measurements
    from ampc_vo.sim.traffic import build_dynamic_scene

    raw = {"rig": str(repo_root / "configs" / "rigs" / "default.yaml"), "segments": [{"type": "straight", "length": 40}],
           "pixel_noise_px": 0.0, "outlier_fraction": 0.0,
           "traffic": [{"kind": "oncoming", "start_m": 40, "speed_mps": 10, "lateral_m": 3.5},
                       {"kind": "leading", "gap_m": 15, "size": "van"}]}
    config = sim_config_from_dict(raw, repo_root / "configs" / "sim" / "x.yaml")
    trajectory = _straight_trajectory()
    dynamic = build_dynamic_scene(config.traffic, None, trajectory, default_rig, route_centerline(trajectory.T_world_tractor, 60.0),
                                  2.0, np.random.default_rng(1))
    empty = LandmarkSet(np.array([[0.0, 50.0, 0.0]]), np.zeros(1, np.int64))
    m = simulate_measurements(trajectory, default_rig, empty, Scene(()), config, np.random.default_rng(2), dynamic=dynamic)
    body = m.landmark_body[m.landmark_id]
    assert np.sum(body == 0) > 50 and np.sum(body == 1) > 50
    # Truth, independent of the traffic code: the oncoming car's centre is at x = 40 - 10 t, y = 3.5,
    # heading -x; the leading van at x = 8 t + 15 on the path, heading +x.
    for index in (0, 1):
        rows = np.flatnonzero(body == index)
        t = m.timestamps[m.frame[rows]]
        x = 40.0 - 10.0 * t if index == 0 else 8.0 * t + 15.0
        y = 3.5 if index == 0 else 0.0
        heading = math.pi if index == 0 else 0.0
        local = m.landmarks[m.landmark_id[rows]]
        world = np.stack([x + math.cos(heading) * local[:, 0] - math.sin(heading) * local[:, 1],
                          y + math.sin(heading) * local[:, 0] + math.cos(heading) * local[:, 1], local[:, 2]], axis=1)
        for camera_index, camera in enumerate(default_rig.cameras):
            selected = m.camera_index[rows] == camera_index
            if not selected.any():
                continue
            T = trajectory.pose(camera.body)[m.frame[rows[selected]]] @ camera.T_body_camera
            points = np.einsum("nji,nj->ni", T[:, :3, :3], world[selected] - T[:, :3, 3])
            expected, valid = camera.project(points)
            assert valid.all()
            np.testing.assert_allclose(m.pixel_clean[rows[selected]], expected, atol=1e-6)
    # The leading van keeps its distance: its tracks stand still in the front camera while the world moves.
    front = m.camera_names.index("front")
    van = np.flatnonzero((body == 1) & (m.camera_index == front))
    first, second = van[m.frame[van] == 10], van[m.frame[van] == 11]
    _, a, b = np.intersect1d(m.track_id[first], m.track_id[second], return_indices=True)
    assert len(a) > 10 and np.max(np.linalg.norm(m.pixel_clean[first[a]] - m.pixel_clean[second[b]], axis=1)) < 1e-6


def test_trailer_box_is_seen_by_tractor_mirrors_only(repo_root, atlas):
    from ampc_vo.rig import load_rig
    from ampc_vo.sim.config import sim_config_from_dict
    from ampc_vo.sim.scene import route_centerline
    from ampc_vo.sim.simulation import LandmarkSet, simulate_measurements
    from ampc_vo.sim.traffic import TrailerBodySpec, build_dynamic_scene

    rig = load_rig(repo_root / "configs" / "rigs" / "default_mirrors.yaml")
    raw = {"rig": str(repo_root / "configs" / "rigs" / "default_mirrors.yaml"), "segments": [{"type": "straight", "length": 40}],
           "pixel_noise_px": 0.0, "outlier_fraction": 0.0, "trailer_body": True}
    config = sim_config_from_dict(raw, repo_root / "configs" / "sim" / "x.yaml")
    assert config.trailer_body == TrailerBodySpec()
    trajectory = _straight_trajectory(10)
    spec = TrailerBodySpec(length_m=13.4, width_m=2.5, height_m=2.6, front_x_m=0.5, floor_height_m=1.2)
    dynamic = build_dynamic_scene((), spec, trajectory, rig, route_centerline(trajectory.T_world_tractor, 60.0), 2.0, np.random.default_rng(1))
    empty = LandmarkSet(np.array([[0.0, 80.0, 0.0]]), np.zeros(1, np.int64))
    m = simulate_measurements(trajectory, rig, empty, Scene(()), config, np.random.default_rng(2), dynamic=dynamic)
    names = np.array(m.camera_names)[m.camera_index]
    on_box = m.landmark_body[m.landmark_id] == 0
    assert set(names[on_box]) == {"mirror_left", "mirror_right"}
    # Box landmarks are in the trailer frame: their pixels are projections through trailer pose and box offset.
    rows = np.flatnonzero(on_box)[:200]
    box_offset = np.array([0.5 - 6.7, 0.0, 1.2 - rig.hitch_height])
    for row in rows:
        camera = rig.camera(names[row])
        T = trajectory.T_world_tractor[m.frame[row]] @ camera.T_body_camera
        world = trajectory.T_world_trailer[m.frame[row]][:3, :3] @ (m.landmarks[m.landmark_id[row]] + box_offset) + trajectory.T_world_trailer[m.frame[row]][:3, 3]
        pixel, _ = camera.project((T[:3, :3].T @ (world - T[:3, 3]))[None])
        np.testing.assert_allclose(m.pixel_clean[row], pixel[0], atol=1e-6)
    # The rendered mirror image shows the box where it projects (depth of the box side).
    camera = rig.camera("mirror_left")
    renderer = Renderer(Scene(()), atlas)
    side_point = np.array([-6.0, 1.25, 2.5])  # on the box's left side (y = width / 2), trailer frame = world at frame 0
    _, depth = renderer.radiance_and_depth(camera, trajectory.T_world_tractor[0] @ camera.T_body_camera, dynamic.quads_at(0.0, camera))
    T = camera.T_body_camera
    pixel, valid = camera.project((T[:3, :3].T @ (side_point - T[:3, 3]))[None])
    assert valid[0]
    u, v = np.round(pixel[0]).astype(int)
    ray = T[:3, :3] @ camera.unproject(np.array([[u, v]], float))[0]           # the pixel's ray, body frame
    assert depth[v, u] == pytest.approx((1.25 - T[1, 3]) / ray[1], rel=1e-3)    # hits the plane y = 1.25
    assert dynamic.quads_at(0.0, rig.camera("rear")) == []


def test_traffic_and_trailer_sections_are_validated(repo_root):
    from ampc_vo.sim.config import sim_config_from_dict

    base = {"rig": str(repo_root / "configs" / "rigs" / "default.yaml"), "segments": [{"type": "straight", "length": 40}]}
    for extra, message in (({"traffic": [{"kind": "parked"}]}, r"traffic\[0\].kind"), ({"traffic": [{"kind": "leading", "gap": 3}]}, "unknown key"),
                           ({"traffic": [{"kind": "leading", "size": "bus"}]}, "size"), ({"trailer_body": {"length": 3}}, "unknown key"),
                           ({"cameras": {"all": {"jitter_ms": "x"}}}, "jitter_ms")):
        with pytest.raises(ConfigError, match=message):
            sim_config_from_dict({**base, **extra}, repo_root / "configs" / "sim" / "x.yaml")


def test_walls_cast_shadows_of_the_right_length_on_the_ground():
    from ampc_vo.sim.render import shadow_map

    sun = np.array([0.6, 0.0, 0.8])                    # elevation atan(0.8 / 0.6): shadow length = h * 0.75
    wall = Quad(np.array([0.0, -5.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 10.0, 8.0, "facade", "concrete")
    ground = Quad(np.array([-20.0, -20.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 40.0, 40.0, "ground", "grass")
    shadows = shadow_map([ground, wall], sun, resolution=0.1)
    x = np.array([-1.0, -5.5, -6.5, 1.0, -3.0, -3.0], np.float32)   # shadow reaches x = -6 (away from the sun)
    y = np.array([0.0, 0.0, 0.0, 0.0, 4.0, 6.0], np.float32)
    lit = shadows.sample(x, y)
    np.testing.assert_allclose(lit, [0.0, 0.0, 1.0, 1.0, 0.0, 1.0], atol=0.02)


def test_shadowed_ground_renders_darker(default_rig, atlas):
    from ampc_vo.sim.render import RenderOptions

    camera = default_rig.camera("front")
    ground = Quad(np.array([-20.0, -20.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 80.0, 40.0, "road", "asphalt", 4.0)
    wall = Quad(np.array([14.0, 30.0, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0]), 60.0, 30.0, "facade", "concrete")
    T = planar_pose(0.0, 0.0, 0.0) @ camera.T_body_camera
    images = {}
    for shadows in (False, True):
        options = RenderOptions(shadows=shadows, shadow_darkness=0.4, road_markings=False)
        images[shadows], depth = Renderer(Scene((ground, wall)), atlas, options).radiance_and_depth(camera, T)
    ratio = images[True] / np.maximum(images[False], 1e-3)
    road = np.isfinite(depth) & (np.abs(ratio - 1.0) > 1e-3)
    assert road.sum() > 1000 and np.median(ratio[road]) == pytest.approx(0.4, abs=0.02)


def test_worn_asphalt_has_little_texture_but_some_features():
    from ampc_vo.sim.textures import make_texture

    worn = make_texture("worn_asphalt").astype(np.float32) / 255
    textured = make_texture("asphalt").astype(np.float32) / 255
    coarse = lambda image: cv2.resize(image, (64, 64), interpolation=cv2.INTER_AREA)  # noqa: E731 - seen from metres away
    assert coarse(worn).std() < 0.4 * coarse(textured).std()
    assert 0.25 < worn.mean() < 0.4
    corners = cv2.goodFeaturesToTrack(worn, 500, 0.05, 5)
    assert corners is not None and 5 <= len(corners) < 0.5 * len(cv2.goodFeaturesToTrack(textured, 500, 0.05, 5))


def test_auto_exposure_in_rendered_sequences_brings_a_dark_view_to_the_target(default_rig, atlas, tmp_path):
    """Frames 0-9 look at a bright wall, then at a dark one: the first dark frames come out dark,
    then the exposure loop brings the image mean to the target grey (metered on the renderings)."""
    from ampc_vo.sim.render import RenderOptions

    camera = replace_camera(default_rig.camera("front"), width=160, height=120, fx=80.0, fy=80.0, cx=79.5, cy=59.5)
    rig = Rig(default_rig.bodies, (camera,))
    count = 30
    forward = camera.T_body_camera[:3, 2]
    scene_quads = []
    for offset, texture in ((0.0, "paint"), (1000.0, "asphalt")):
        centre = np.array([offset, 0.0, 0.0]) + camera.T_body_camera[:3, 3] + 4.0 * forward
        scene_quads.append(dataclasses_replace(_marker(centre, -forward, size=30.0), texture=texture, kind="facade", texture_scale=2.0))
    tractor = np.stack([planar_pose(0.0 if k < 10 else 1000.0, 0.0, 0.0) for k in range(count)])
    trajectory = Trajectory(np.arange(count) * 0.1, tractor, tractor.copy(), np.zeros(count))
    settings = CameraSettingsTable(CameraSettings(auto_exposure=True, target_grey=110.0, exposure_time_constant_s=0.3, max_gain=8.0))
    options = RenderOptions(processes=1, shading=False, sky_zenith=0.0, sky_horizon=0.0)
    scene = Scene(tuple(scene_quads))
    render_sequence(tmp_path, rig, trajectory, scene, options, progress=False, renderer=Renderer(scene, atlas, options), camera_settings=settings)
    means = [cv2.imread(str(tmp_path / "images" / "front" / f"{k:06d}.png"), cv2.IMREAD_GRAYSCALE).mean() for k in range(count)]
    assert means[5] == pytest.approx(110.0, rel=0.05)                 # converged on the bright wall
    assert means[10] < 0.6 * 110.0                                    # the first dark frame: still the bright exposure
    assert means[11] < means[13] < means[16]                          # recovering with the loop's lag
    assert means[-1] == pytest.approx(110.0, rel=0.05)


def dataclasses_replace(quad: Quad, **changes) -> Quad:
    """A copy of a quad with some fields changed."""
    import dataclasses

    return dataclasses.replace(quad, **changes)


def test_moving_body_textures_stick_to_the_body(default_rig, atlas):
    """A box seen from the same relative pose at two places looks the same (texture moves with it)."""
    from ampc_vo.sim.render import move_prepared, prepare_quads, RenderOptions
    from ampc_vo.sim.traffic import box_faces

    camera = default_rig.camera("front")
    renderer = Renderer(Scene(()), atlas, RenderOptions(shading=True))
    faces = prepare_quads(box_faces(4.5, 1.8, 1.5, "metal"), atlas, renderer.options, seed_offset=10**6)
    images = []
    for x, yaw in ((12.0, 0.0), (40.0, 0.7)):
        T_world_box = planar_pose(x, 2.0, yaw)
        T_world_camera = T_world_box @ np.linalg.inv(planar_pose(10.0, -1.0, 0.2)) @ camera.T_body_camera
        images.append(renderer.radiance_and_depth(camera, T_world_camera, move_prepared(faces, T_world_box))[0])
    hit = images[0] != images[0][0, 0]
    assert hit.sum() > 2000
    np.testing.assert_allclose(images[0][hit], images[1][hit], atol=0.05)
