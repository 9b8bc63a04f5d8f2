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
