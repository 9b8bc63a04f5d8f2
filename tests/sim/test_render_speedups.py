"""The renderer's speed-ups against slow reference paths (issue 13: 100 ms per image): tile culling
against brute-force ray casting over every quad."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.geometry import make_pose, rot_x, rot_z
from ampc_vo.rig import replace_camera
from ampc_vo.sim.render import PreparedQuads, Renderer, RenderOptions
from ampc_vo.sim.scene import Quad, Scene
from ampc_vo.sim.textures import build_atlas, load_textures


@pytest.fixture(scope="module")
def atlas():
    return build_atlas(load_textures(("grass", "brick", "metal", "concrete")))


def _brute_force_depth(quads: PreparedQuads, rays: np.ndarray, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit ``(ray distance, quad index)`` per ray (N, 3, camera frame) over every quad, no
    culling (float64; inf and -1 where nothing is hit)."""
    R, position = T_world_camera[:3, :3], T_world_camera[:3, 3]
    depth = np.full(len(rays), np.inf)
    quad_id = np.full(len(rays), -1)
    for index in range(len(quads)):
        origin, axis_u, axis_v, normal = ((vector @ R) for vector in (quads.origin[index] - position, quads.axis_u[index],
                                                                        quads.axis_v[index], quads.normal[index]))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (origin @ normal) / (rays @ normal)
        a, b = t * (rays @ axis_u) - origin @ axis_u, t * (rays @ axis_v) - origin @ axis_v
        hit = (t > 1e-3) & (a >= 0) & (a <= quads.width[index]) & (b >= 0) & (b <= quads.height[index]) & (t < depth)
        depth[hit], quad_id[hit] = t[hit], index
    return depth, quad_id


def _culling_scene() -> Scene:
    """Ground all around the camera (behind the lens too), walls on all sides, poles and a box beside the camera."""
    ground = Quad(np.array([-60.0, -60.0, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 120.0, 120.0, "ground", "grass", 2.0)
    walls = [Quad(np.array([x, y, 0.0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 25.0, 8.0, "facade", "brick", 4.0)
             for x in (-9.0, 11.0) for y in (-40.0, -10.0, 20.0)]
    walls += [Quad(np.array([-20.0, y, 0.0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), 40.0, 10.0, "facade", "concrete", 4.0)
              for y in (-45.0, 45.0)]
    poles = [Quad(np.array([x, y, 0.0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), 0.3, 5.0, "pole", "metal", 1.0)
             for x in (-5.0, 5.0) for y in np.arange(-30.0, 40.0, 7.0)]
    box = [Quad(np.array([1.0, -1.5, 0.0]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), 2.0, 3.0, "box", "metal", 1.0),
           Quad(np.array([1.0, -1.5, 3.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 2.0, 4.0, "box", "metal", 1.0)]
    return Scene(tuple([ground, *walls, *poles, *box]))


@pytest.mark.parametrize("rig_name", ["default_rig", "fisheye_rig"])
def test_tile_culling_finds_every_hit_of_brute_force_ray_casting(request, rig_name, atlas):
    """The depth pass (bounding boxes, tile cones, plane sides, occlusion and batches) hits what
    testing every ray against every quad hits, for pinhole and fisheye cameras at several poses,
    with quads reaching behind the lens."""
    rig = request.getfixturevalue(rig_name)
    renderer = Renderer(_culling_scene(), atlas, RenderOptions())
    for camera_index, camera in enumerate(rig.cameras):
        # a quarter of the focal length too: a fisheye seeing up to 100 deg off its axis in the corners
        focal_scale = 0.375 if camera_index % 2 == 0 or camera.model == "pinhole" else 0.25
        small = replace_camera(camera, width=240, height=180, fx=camera.fx * focal_scale, fy=camera.fy * focal_scale,
                               cx=119.5, cy=89.5)
        rays = renderer.rays_of(small).rays_planes.reshape(3, -1).T.astype(np.float64)
        for heading in (0.3 + 1.7 * camera_index, 2.0 + 1.7 * camera_index):
            # OpenCV camera looking along world +x rotated by ``heading``, 1.8 m up, pitched 15 deg down
            R = rot_z(heading) @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ rot_x(-np.radians(15.0))
            T_world_camera = make_pose(R, np.array([0.5, 0.3, 1.8]))
            visible = renderer.depth_pass(small, T_world_camera)
            truth, truth_id = _brute_force_depth(visible.quads, rays, T_world_camera)
            depth = visible.depth.ravel().astype(np.float64)
            same_hit = np.isfinite(depth) == np.isfinite(truth)
            assert np.mean(same_hit) > 0.9995, (camera.name, heading, np.flatnonzero(~same_hit)[:10])
            both = np.isfinite(depth) & np.isfinite(truth)
            assert np.mean(np.abs(depth[both] - truth[both]) <= 1e-4 * truth[both]) > 0.999
            assert np.mean(visible.quad_id.ravel()[both] == truth_id[both]) > 0.999  # ties at shared edges may differ


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_rolling_shutter_warp_is_exact_to_a_hundredth_of_a_pixel(default_rig, dtype):
    """A camera sliding sideways past a wall whose radiance is a ramp across the image: each row
    shows the wall at its own time, shifted by ``fx v dt / Z`` (blur averages out on a ramp), to
    1/100 px for a float32 or float64 rendering (float64 is interpolated at 1/32 px steps by cv2.remap)."""
    from ampc_vo.sim.camera_effects import form_image
    from ampc_vo.sim.camera_settings import CameraSettings
    from ampc_vo.sim.render import padded_camera

    camera = replace_camera(default_rig.camera("front"), width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5, readout_time=0.03)
    speed, wall_z, ramp = 20.0, 6.0, 3.0  # m/s along the camera's x, m, grey levels per pixel

    def pose_at(times: np.ndarray) -> np.ndarray:
        poses = np.repeat(np.eye(4)[None], len(times), axis=0)
        poses[:, 0, 3] = speed * np.asarray(times)
        return poses

    margins = []

    def render_with_depth(T_world_camera: np.ndarray, time: float, margin: int):
        margins.append(margin)
        padded = padded_camera(camera, margin)
        v, u = np.mgrid[0:padded.height, 0:padded.width]
        rays = padded.unproject(np.stack([u.ravel(), v.ravel()], axis=1).astype(float))
        depth = (wall_z / rays[:, 2]).reshape(u.shape).astype(np.float32)
        return (ramp * u + 10.0).astype(dtype), depth, rays.T.reshape(3, *u.shape).astype(np.float32)

    capture = 0.1
    settings = CameraSettings(exposure_s=0.006, motion_blur_samples=4)
    image, formation = form_image(camera, render_with_depth, pose_at, capture, settings, 1.0, np.random.default_rng(0))
    rows = np.arange(camera.height)[:, None]
    row_time = capture + camera.readout_time * rows / (camera.height - 1) - formation.render_time
    source_column = np.arange(camera.width)[None, :] + camera.fx * speed * row_time / wall_z + margins[0]  # in the padded rendering
    seen_column = (image - 10.0) / ramp
    assert formation.max_shift_px > 5.0                                              # the rolling shutter shows
    # Columns whose points stay in the image over the readout (the warp leaves points leaving it
    # unshifted) and rows up to the motion field's last grid row (beyond, its shift is held).
    rows_on_grid, inside = slice(0, (camera.height - 1) // 4 * 4 + 1), slice(12, camera.width - 12)
    np.testing.assert_allclose(seen_column[rows_on_grid, inside], source_column[rows_on_grid, inside], atol=0.01)


def test_relief_footprint_keeps_every_pixel_of_the_whole_image_relief_test(default_rig, atlas, monkeypatch):
    """Restricting the relief test to the bumps' image footprint changes no pixel: depth and image
    equal those of testing every pixel, for cameras before, over, beside and past a speed bump, a
    pothole and a tall hump (seen from low, its top above the footprint of its base), on a flat road
    and on one of two quads, one slightly tilted."""
    from ampc_vo.sim import render as render_module
    from ampc_vo.sim.road import Bump

    tilted = np.array([0.0, -0.03, 1.0]) / np.linalg.norm([0.0, -0.03, 1.0])
    flat = (Quad(np.array([-20.0, -4.0, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 70.0, 8.0, "road", "grass", 4.0),)
    two = (Quad(np.array([-20.0, -4.0, 0.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 30.0, 8.0, "road", "grass", 4.0),
           Quad(np.array([10.0, -4.0, 0.0]), np.array([1.0, 0, 0]), np.cross(tilted, [1.0, 0.0, 0.0]), 40.0, 8.0, "road", "grass", 4.0))
    bumps = (Bump((6.0, 0.5), 0.0, 1.5, 5.0, 0.07), Bump((14.0, -1.5), 0.3, 0.9, 0.7, -0.06), Bump((32.0, 1.0), 0.0, 1.2, 1.2, 0.4))
    camera = replace_camera(default_rig.camera("front"), width=200, height=150, fx=140.0, fy=140.0, cx=99.5, cy=74.5)
    options = RenderOptions(shading=False, road_markings=False)
    seen = 0
    for roads in (flat, two):
        renderer = Renderer(Scene(roads, bumps), atlas, options)
        for x, z, heading, pitch in ((-15.0, 2.5, 0.0, 10.0), (2.0, 2.5, 0.2, 25.0), (5.0, 2.5, 0.0, 30.0), (6.0, 2.5, 0.0, 60.0),
                                     (9.0, 2.5, np.pi, 30.0), (10.0, 2.5, 1.4, 20.0), (25.0, 2.5, np.pi - 0.2, 15.0),
                                     (6.0, 2.5, 0.5 * np.pi, 5.0), (40.0, 2.5, np.pi, 5.0), (22.0, 0.6, 0.0, 0.0)):
            R = rot_z(heading) @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ rot_x(-np.radians(pitch))
            T_world_camera = make_pose(R, np.array([x, 0.0, z]))
            image, depth = renderer.radiance_and_depth(camera, T_world_camera)
            with monkeypatch.context() as patch:
                patch.setattr(render_module, "relief_footprint", lambda *args: None)
                whole_image, whole_depth = renderer.radiance_and_depth(camera, T_world_camera)
            plane_depth = Renderer(Scene(roads), atlas, options).radiance_and_depth(camera, T_world_camera)[1]
            hit = np.isfinite(plane_depth)
            seen += int(np.sum(np.abs(whole_depth[hit] - plane_depth[hit]) > 1e-4))
            np.testing.assert_array_equal(depth, whole_depth)
            np.testing.assert_array_equal(image, whole_image)
    assert seen > 5000  # the bumps are seen


@pytest.mark.parametrize("width, height, tile_size", [(640, 480, 16), (96, 64, 8), (100, 70, 16)])
def test_tiles_to_image_is_the_gather_through_the_image_order(default_rig, width, height, tile_size):
    """Tile-major buffers become images by a transposed copy where the tiles cover the image
    exactly: the same as gathering every pixel through ``image_order`` (the general path)."""
    from ampc_vo.sim.render import _tiles_to_image, camera_rays

    camera = replace_camera(default_rig.camera("front"), width=width, height=height, cx=width / 2 - 0.5, cy=height / 2 - 0.5)
    rays = camera_rays(camera, tile_size)
    values = np.random.default_rng(3).random(rays.pixel_index.shape).astype(np.float32)
    np.testing.assert_array_equal(_tiles_to_image(values, rays, (height, width)), values.ravel()[rays.image_order].reshape(height, width))
