"""Bumps and potholes in the rendered road (issue 13, DESIGN 6): every pixel that sees the road over
a bump or pothole gets the ray distance of the true surface (plane + raised-cosine relief), checked
against a root of the ray-surface equation found independently (bisection on a fine grid)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.geometry import make_pose, rot_x
from ampc_vo.rig import replace_camera
from ampc_vo.sim.render import Renderer, RenderOptions
from ampc_vo.sim.road import Bump
from ampc_vo.sim.scene import Quad, Scene
from ampc_vo.sim.textures import build_atlas, load_textures

POTHOLE = Bump((6.0, -0.6), 0.1, 1.2, 0.9, -0.06)
BUMP = Bump((9.0, 0.8), 0.0, 0.8, 3.0, 0.05)
PLANE_Z = 0.02


@pytest.fixture(scope="module")
def atlas():
    return build_atlas(load_textures(("asphalt",)))


def _first_hit(origin: np.ndarray, ray: np.ndarray, far: float) -> float:
    """Ray distance of the first point of ``origin + t ray`` at or below the surface
    ``PLANE_Z + pothole + bump`` (a 1 mm grid, then bisection)."""
    def above(t: np.ndarray) -> np.ndarray:
        point = origin + np.multiply.outer(t, ray)
        return point[..., 2] - (PLANE_Z + POTHOLE.height_at(point[..., :2]) + BUMP.height_at(point[..., :2]))

    grid = np.arange(0.0, far, 1e-3)
    index = int(np.argmax(above(grid) <= 0.0))
    low, high = grid[index - 1], grid[index]
    for _ in range(30):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if above(np.array([middle]))[0] > 0.0 else (low, middle)
    return 0.5 * (low + high)


def test_rays_hit_the_bumps_and_potholes_of_the_road(default_rig, atlas):
    camera = replace_camera(default_rig.camera("front"), width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5)
    road = Quad(np.array([-5.0, -4.0, PLANE_Z]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 30.0, 8.0, "road", "asphalt", 4.0)
    # camera 2 m up, looking along +x and 25 deg down (OpenCV axes: z forward, y down)
    R_world_camera = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ rot_x(-np.radians(25.0))
    T_world_camera = make_pose(R_world_camera, np.array([0.0, 0.0, 2.0 + PLANE_Z]))
    options = RenderOptions(shading=False, road_markings=False)
    flat = Renderer(Scene((road,)), atlas, options)
    relief = Renderer(Scene((road,), (POTHOLE, BUMP)), atlas, options)
    flat_image, flat_depth = flat.radiance_and_depth(camera, T_world_camera)
    image, depth = relief.radiance_and_depth(camera, T_world_camera)
    rays = (R_world_camera @ relief.rays_of(camera).rays_planes.reshape(3, -1).astype(float)).T
    seen = np.isfinite(flat_depth)
    difference = np.zeros_like(depth)
    difference[seen] = depth[seen] - flat_depth[seen]
    changed = np.flatnonzero(np.abs(difference).ravel() > 1e-4)
    assert 200 < changed.size < 4000                                    # both features seen, nothing else moved
    rng = np.random.default_rng(0)
    sample = np.concatenate([rng.choice(changed, 150, replace=False),
                             rng.choice(np.flatnonzero(np.isfinite(flat_depth).ravel()), 150, replace=False)])
    truth = np.array([_first_hit(T_world_camera[:3, 3], rays[index], 40.0) for index in sample])
    error = np.abs(depth.ravel()[sample] - truth)
    print(f"depth error max {1e6 * error.max():.1f} um")
    assert error.max() < 2e-3
    assert np.max(difference.ravel()[changed]) > 0.1        # into the pothole (6 cm seen at ~20 deg)
    assert np.min(difference.ravel()[changed]) < -0.1       # onto the bump
    assert np.mean(np.abs(image - flat_image).ravel()[changed]) > 2.0                # the images show them


def test_scene_keeps_bumps_as_relief_and_the_strips_without_them():
    from ampc_vo.sim.road import RoadSurface
    from ampc_vo.sim.scene import build_scene
    from ampc_vo.sim.kinematics import simulate_kinematics
    from ampc_vo.sim.routes import route_from_list

    route = route_from_list([{"type": "straight", "length": 30}], 8.0, "relief")
    trajectory = simulate_kinematics(route, 10.0, 0.3, -8.0)
    road = RoadSurface(bumps=(Bump((10.0, 0.0), 0.0, 1.0, 1.0, -0.05),))
    scene = build_scene(trajectory, np.random.default_rng(0), road=road)
    assert scene.relief == road.bumps
    ground = [quad for quad in scene.quads if quad.kind in ("road", "ground")]
    assert all(abs(quad.normal[2]) > 1 - 1e-12 for quad in ground)     # flat strips: the bump is not in them
