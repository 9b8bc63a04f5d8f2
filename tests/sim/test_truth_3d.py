"""Ground truth of the realistic worlds (issue 13), checked independently of the code that made it:
finite differences of the dense poses, body-frame contact points against the road surface, the
hitch angle from the rotations, accelerations against the configured limits."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.rig import load_rig
from ampc_vo.sim.attitude import SUSPENSION
from ampc_vo.sim.config import sim_config_from_dict
from ampc_vo.sim.kinematics import AxleGroup, hitch_angle_for_trailer_curvature
from ampc_vo.sim.simulation import decimate, dense_factor, simulate, simulate_truth

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "configs" / "rigs" / "semitrailer.yaml"
WHEELBASE, HALF_TRACK = 3.8, 1.0


def _world(segments, road=None, vehicle=None, driving=None, slip=0.0, speed=8.0):
    raw = {"rig": str(RIG), "rate_hz": 10, "speed": speed, "label": "realistic", "tyre_slip_deg_per_mps2": slip,
           "driving": driving or {"acceleration": 1.0, "deceleration": 2.5},
           "road": road or {}, "vehicle": {"tractor_wheelbase_m": WHEELBASE, "half_track_m": HALF_TRACK, **(vehicle or {})},
           "segments": segments, "scene": {"extension_m": 30, "ground_margin_m": 30}}
    config = sim_config_from_dict(raw, ROOT / "configs" / "sim" / "test_world.yaml")
    rig = load_rig(RIG)
    dense, road_surface, angles = simulate_truth(config, rig)
    return config, rig, dense, road_surface, angles


HILL = {"start_grade_percent": 6.0, "grades": [[70, -4.0]], "vertical_curve_m": 50, "crown_percent": 2.5,
        "max_superelevation_percent": 6.0, "design_speed": 10, "lane_offset_m": 1.75}
HILL_ROUTE = [{"type": "stop", "duration": 1.0}, {"type": "straight", "length": 45},
              {"type": "turn", "angle_deg": 50, "radius": 45, "transition": 20}, {"type": "straight", "length": 30}, {"type": "stop", "duration": 1.0}]


@pytest.fixture(scope="module")
def rigid_hill():
    """Hill with crown, banked curve and a bump; no suspension, no vibration, no slip, single axle."""
    road = dict(HILL, bumps=[{"station": 20, "lateral": -1.75, "length": 2.0, "width": 5.0, "height": 0.04}])
    return _world(HILL_ROUTE, road=road)


@pytest.fixture(scope="module")
def moving_hill():
    """The same hill with suspension, vibration, a tridem and tyre slip."""
    return _world(HILL_ROUTE, road=HILL, slip=0.15,
                  vehicle={"trailer_axles": 3, "suspension": True, "engine_deg": 0.02, "road_deg_per_mps": 0.005})


def _body_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World positions (N, K, 3) of body-frame points (K, 3) over poses (N, 4, 4)."""
    return np.einsum("nij,kj->nki", pose[:, :3, :3], points) + pose[:, None, :3, 3]


def _axle_velocity(trajectory, body: str, axle_x: float) -> tuple[np.ndarray, np.ndarray]:
    """Longitudinal and lateral velocity (N,) of the body's axle point (axle_x, 0, 0), by central differences."""
    pose = trajectory.pose(body)
    position = pose[:, :3, 3] + axle_x * pose[:, :3, 0]
    velocity = np.gradient(position, trajectory.timestamps, axis=0)
    return np.einsum("ij,ij->i", velocity, pose[:, :3, 0]), np.einsum("ij,ij->i", velocity, pose[:, :3, 1])


def test_the_two_bodies_share_the_hitch_point(moving_hill):
    _, _, dense, _, _ = moving_hill
    assert np.abs(dense.T_world_tractor[:, :3, 3] - dense.T_world_trailer[:, :3, 3]).max() < 1e-12
    for pose in (dense.T_world_tractor, dense.T_world_trailer):  # proper rotations
        rotation = pose[:, :3, :3]
        assert np.abs(np.einsum("nji,njk->nik", rotation, rotation) - np.eye(3)).max() < 1e-9
        assert np.allclose(np.linalg.det(rotation), 1.0)


def test_each_axle_contact_point_lies_on_the_road(rigid_hill):
    _, rig, dense, road, _ = rigid_hill
    height = rig.hitch_height
    tractor_x, trailer_x = rig.axle_x("tractor"), rig.axle_x("trailer")
    tractor = _body_points(dense.T_world_tractor, np.array([[tractor_x, HALF_TRACK, -height], [tractor_x, -HALF_TRACK, -height],
                                                            [tractor_x + WHEELBASE, 0.0, -height]]))
    trailer = _body_points(dense.T_world_trailer, np.array([[trailer_x, HALF_TRACK, -height], [trailer_x, -HALF_TRACK, -height]]))
    for contacts in (tractor, trailer):
        gap = contacts[..., 2] - road.height(contacts[..., :2])
        assert np.abs(gap).max() < 1e-4
    # the road under the truck is far from flat here: a flat-road truth would miss by metres
    assert np.ptp(road.height(tractor[:, 0, :2])) > 2.0


def test_without_slip_each_axle_has_no_lateral_velocity(rigid_hill):
    config, rig, dense, _, _ = rigid_hill
    assert config.tyre_slip == 0.0
    for body in ("tractor", "trailer"):
        longitudinal, lateral = _axle_velocity(dense, body, rig.axle_x(body))
        # second-order couplings of pitch rate and roll (bump, vertical curve) stay below 1e-3 |v|
        assert np.all(np.abs(lateral) < 1e-3 * np.abs(longitudinal) + 2e-3), body
        assert np.abs(longitudinal).max() > 7.0


def _steady_turn(dense) -> np.ndarray:
    """Samples in the middle of HILL_ROUTE's constant-radius arc (R 45 m at 8 m/s)."""
    arc_start = 45.0 + 10.0
    arc_length = 45.0 * math.radians(50.0) - 20.0
    return (dense.arc_length > arc_start + 0.3 * arc_length) & (dense.arc_length < arc_start + 0.7 * arc_length)


def test_tyre_slip_and_cross_slope_drift_move_the_tractor_axle_sideways():
    """Linear tyre: the axle's velocity points outward by slip * (v^2 kappa + g dh/dn); on this banked
    left curve (AASHTO method 1: e = e_max min(R_min / R, 1)) the bank's gravity offsets part of it."""
    config, rig, dense, _, _ = _world(HILL_ROUTE, road=HILL, slip=0.15)
    steady = _steady_turn(dense)
    longitudinal, lateral = _axle_velocity(dense, "tractor", rig.axle_x("tractor"))
    minimum_radius = 10.0**2 / (9.81 * (0.06 + 0.15))
    bank = 0.06 * min(minimum_radius / 45.0, 1.0)
    force = 8.0**2 / 45.0 - 9.81 * bank                 # dh/dn = -e in the right lane of a left curve
    expected = -8.0 * math.radians(0.15) * force
    assert np.median(lateral[steady]) == pytest.approx(expected, rel=0.1)


def test_tridem_slides_about_its_effective_axle():
    """Without slip the tridem's centre (the rig's axle_x) moves sideways at psi_B' (L_eq - L) with
    Winkler's L_eq = L + sum(x_i^2) / (n L) (gentle turn)."""
    config, rig, dense, _, _ = _world(HILL_ROUTE, road=HILL, vehicle={"trailer_axles": 3})
    steady = _steady_turn(dense)
    _, lateral = _axle_velocity(dense, "trailer", rig.axle_x("trailer"))
    yaw_rate = np.gradient(np.unwrap(np.arctan2(dense.T_world_trailer[:, 1, 0], dense.T_world_trailer[:, 0, 0])), dense.timestamps)
    distance = -rig.axle_x("trailer")
    shift = 2 * 1.31**2 / (3 * distance)
    assert np.median(np.abs(lateral[steady])) == pytest.approx(np.median(np.abs(yaw_rate[steady])) * shift, rel=0.1)
    assert np.median(np.abs(lateral[steady])) > 0.008  # a single axle: < 1e-3 here (test above)


def test_hitch_angle_is_the_yaw_of_R_tractor_trailer(moving_hill):
    _, _, dense, _, _ = moving_hill
    R_a, R_b = dense.T_world_tractor[:, :3, :3], dense.T_world_trailer[:, :3, :3]
    relative = np.transpose(R_a, (0, 2, 1)) @ R_b
    expected = np.arctan2(relative[:, 1, 0], relative[:, 0, 0])
    assert np.abs(dense.hitch_angle - expected).max() < 1e-12
    assert np.degrees(np.abs(dense.hitch_angle)).max() > 3.0
    # the trailer pitches and rolls relative to the tractor at the fifth wheel
    tilt = np.degrees(np.arccos(np.clip(relative[:, 2, 2], -1.0, 1.0)))
    assert tilt.max() > 0.5


def test_grade_and_crown_as_configured(rigid_hill):
    _, _, dense, _, angles = rigid_hill
    station = dense.arc_length
    straight = (station > 5.0) & (station < 15.0)   # on the 6 % tangent, in the right lane of the crowned road, before the bump
    pitch = np.degrees(angles.tractor_road[straight, 1])
    roll = np.degrees(angles.tractor_road[straight, 0])
    assert np.allclose(pitch, -math.degrees(math.atan(0.06)), atol=0.02)   # nose up uphill
    assert np.allclose(roll, math.degrees(math.atan(0.025)), atol=0.02)    # right side down towards the right edge
    rotation = dense.T_world_tractor[straight, :3, :3]
    assert np.allclose(rotation[:, 2, 0], math.sin(math.atan(0.06)), atol=5e-4)  # x axis rises 6 %
    # king-pin at hitch_height above the road in the body's z direction
    assert np.all(dense.T_world_tractor[:, 2, 3] > 0.9)


def test_standing_start_and_end_at_rest(rigid_hill):
    _, _, dense, _, _ = rigid_hill
    standing = dense.timestamps < 0.95
    assert np.all(dense.speed[standing] == 0.0)
    assert np.abs(dense.T_world_tractor[standing] - dense.T_world_tractor[0]).max() < 1e-12
    assert dense.speed[-1] == 0.0 and np.abs(dense.T_world_tractor[-5:] - dense.T_world_tractor[-1]).max() < 1e-12


def test_dense_trajectory_holds_the_camera_frames(moving_hill):
    config, rig, _, _, _ = moving_hill
    result = simulate(dataclasses.replace(config, duration=4.0), rig)   # up the hill (measurements cost time)
    dense, frames = result.dense_trajectory, result.trajectory
    step = dense_factor(config)
    assert step == 20 and 1.0 / np.median(np.diff(dense.timestamps)) >= 200.0 - 1e-6
    assert len(frames) == 41 and len(dense) == 40 * step + 1
    assert np.allclose(frames.timestamps, dense.timestamps[::step])
    assert np.array_equal(frames.T_world_tractor, result.dense_trajectory.T_world_tractor[::step])
    assert np.allclose(np.diff(frames.timestamps), 0.1)
    assert np.array_equal(decimate(dense, step).T_world_trailer, frames.T_world_trailer)
    # ground landmarks stand on the road surface
    ground = result.landmarks.points[np.isin(result.landmarks.quad_index, [i for i, q in enumerate(result.scene.quads) if q.kind in ("road", "ground")])]
    assert len(ground) > 100
    assert np.abs(ground[:, 2] - result.road.height(ground[:, :2])).max() < 1e-9


def test_accelerations_stay_within_the_truck_limits(rigid_hill):
    _, _, dense, _, _ = rigid_hill
    acceleration = np.gradient(dense.speed, dense.timestamps)
    moving = np.abs(dense.speed) > 0.2
    assert acceleration[moving].max() < 1.0 * 1.02 and acceleration[moving].min() > -2.5 * 1.02
    assert acceleration[moving].max() > 0.95 and acceleration[moving].min() < -2.4   # the limits are used


YARD = [{"type": "stop", "duration": 1.0}, {"type": "straight", "length": 20, "speed": 3.0},
        {"type": "clothoid", "length": 6, "curvature_start": 0.0, "curvature_end": 0.18, "speed": 1.2, "reverse": True},
        {"type": "turn", "angle_deg": 90, "radius": 5.5, "speed": 1.2, "reverse": True},
        {"type": "straight", "length": 4, "speed": 1.0, "reverse": True},
        {"type": "straight", "length": 10, "speed": 2.0}, {"type": "stop", "duration": 1.0}]


@pytest.fixture(scope="module")
def yard():
    return _world(YARD, road={"plane_slope_percent": [0.0, -1.0]}, driving={"acceleration": 0.6, "deceleration": 1.5})


def test_reverse_segments_have_negative_axle_speed(yard):
    config, rig, dense, _, _ = yard
    route = config.route
    reverse = np.array([route.is_reverse(s) for s in dense.arc_length]) & (np.abs(dense.speed) > 0.05)
    forward = ~np.array([route.is_reverse(s) for s in dense.arc_length]) & (np.abs(dense.speed) > 0.05)
    assert reverse.sum() > 100 and forward.sum() > 100
    for body in ("tractor", "trailer"):
        longitudinal, _ = _axle_velocity(dense, body, rig.axle_x(body))
        assert np.all(longitudinal[reverse] < 0.0) and np.all(longitudinal[forward] > 0.0), body
    assert np.all(dense.speed[reverse] < 0.0)
    # two direction changes: forward -> reverse -> forward, with a stop in between
    sign = np.sign(dense.speed[np.abs(dense.speed) > 0.05])
    assert np.count_nonzero(np.diff(sign)) == 2


def test_reversing_controller_swings_the_hitch_past_50_degrees_and_the_trailer_follows(yard):
    config, rig, dense, _, _ = yard
    route = config.route
    assert np.degrees(np.abs(dense.hitch_angle)).max() > 50.0
    # in the constant-curvature part the trailer axle drives the commanded circle (R = 5.5 m)
    trailer = dense.T_world_trailer[:, :2, 3] + rig.axle_x("trailer") * dense.T_world_trailer[:, :2, 0]
    heading = np.unwrap(np.arctan2(dense.T_world_trailer[:, 1, 0], dense.T_world_trailer[:, 0, 0]))
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(trailer, axis=0), axis=1))])
    start = 20.0 + 6.0
    arc = (dense.arc_length > start + 4.0) & (dense.arc_length < start + 5.5 * math.pi / 2.0)  # after the controller settled
    curvature = np.abs(np.gradient(heading[arc]) / np.maximum(np.gradient(travelled[arc]), 1e-9))
    assert np.median(curvature) == pytest.approx(1.0 / 5.5, rel=0.05)
    expected = hitch_angle_for_trailer_curvature(1.0 / 5.5, rig.axle_x("tractor"), rig.axle_x("trailer"))
    assert abs(math.degrees(expected)) > 50.0
    assert np.degrees(np.abs(dense.hitch_angle[arc])).max() == pytest.approx(abs(math.degrees(expected)), abs=3.0)


def test_suspension_roll_and_pitch_follow_the_accelerations_at_the_configured_gains():
    config, _, dense, _, angles = _world([{"type": "stop", "duration": 0.5}, {"type": "turn", "angle_deg": 200, "radius": 50},
                                          {"type": "stop", "duration": 3.0}],
                                         vehicle={"suspension": True, "load": "loaded"}, speed=10.0, driving={"acceleration": 1.0, "deceleration": 2.5})
    gains = SUSPENSION["loaded"]["tractor"]
    steady = (dense.arc_length > 100.0) & (dense.arc_length < 150.0)        # 10 m/s on R 50: a_lat = 2 m/s^2
    assert np.allclose(np.degrees(angles.tractor_body[steady, 0]), gains.roll_gain_deg * 2.0, rtol=0.03)
    braking = (dense.speed > 3.0) & (np.gradient(dense.speed, dense.timestamps) < -2.0)
    later = np.flatnonzero(braking)[len(np.flatnonzero(braking)) // 2:]
    assert np.all(angles.tractor_body[later, 1] > 0.0)                       # nose dives when braking
    assert np.degrees(angles.tractor_body[later, 1]).max() == pytest.approx(gains.pitch_gain_deg * 2.5, rel=0.25)


def test_axle_group_effective_distance_matches_winkler_for_gentle_turns():
    distance = 8.5
    tandem, tridem = AxleGroup(2, 1.31), AxleGroup(3, 1.31)
    # Winkler 1998, equal axles: L_eq = L + sum(x_i^2) / (n L)
    assert tandem.effective_distance(distance, 1e-3)[0] == pytest.approx(distance + 2 * 0.655**2 / (2 * distance), abs=2e-3)
    assert tridem.effective_distance(distance, 1e-3)[0] == pytest.approx(distance + 2 * 1.31**2 / (3 * distance), abs=2e-3)
    # saturating tyres (tanh): the moment balance about the king-pin, solved here with brentq
    from scipy.optimize import brentq

    positions = np.array([-1.31, 0.0, 1.31])
    for curvature in (0.02, 0.1, 1.0 / 6.0):
        moment = lambda l_eq: float(np.sum(np.tanh((l_eq - distance - positions) * curvature / tridem.saturation_rad) * (distance + positions)))  # noqa: E731
        expected = brentq(moment, distance - 1.31, distance + 1.31)
        assert tridem.effective_distance(distance, curvature)[0] == pytest.approx(expected, abs=1e-6)
    moved = tridem.effective_distance(distance, np.array([1e-3, 0.1, 0.2]))
    assert np.ptp(moved) > 0.01  # the effective axle moves with the turn radius
    assert AxleGroup(1).effective_distance(distance, 0.1)[0] == distance


def test_camera_mounts_vibrate_with_speed_and_the_engine():
    from ampc_vo.sim.attitude import VehicleConfig, mount_vibration

    config, rig, dense, _, _ = _world(HILL_ROUTE, road=HILL)
    vehicle = VehicleConfig(engine_deg=0.02, mount_deg_per_mps=0.004)
    mounts = mount_vibration(rig, dense, vehicle, np.random.default_rng(3))
    assert set(mounts) == set(rig.camera_names)
    moving = np.abs(dense.speed) > 7.0
    standing = dense.speed == 0.0
    for camera in rig.cameras:
        rotation = mounts[camera.name]
        angle = np.degrees(np.arccos(np.clip((np.trace(rotation, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
        # RMS per axis 0.004 deg per m/s: ~0.03 deg per axis at 7-8 m/s, sqrt(3) of it in total
        assert 0.02 < np.sqrt(np.mean(angle[moving] ** 2)) < 0.12, camera.name
        if camera.body == "tractor":   # idling engine shakes the cab mounts at standstill
            assert 0.003 < angle[standing].max() < 0.03
        else:
            assert angle[standing].max() < 1e-6


def test_rendered_road_quads_lie_on_the_road_surface(rigid_hill):
    """The images' road is the road the wheels stand on: the carriageway's quads (crowned tangent,
    vertical curves, banked curve; bumps apart, the renderer adds those per pixel) lie on the
    surface, exactly on the tangents and within 3.5 cm where the superelevation twists the road
    under a 2 m piece (one plane across both halves of the crown lay up to 7 cm off). The lane
    markings' across-road coordinates of the two halves meet at the centre line."""
    from ampc_vo.sim.scene import build_scene
    from ampc_vo.sim.config import SceneConfig

    _, _, dense, road_surface, _ = rigid_hill
    flat = dataclasses.replace(road_surface, bumps=())
    scene = build_scene(dense, np.random.default_rng(0), SceneConfig(extension_m=30, ground_margin_m=30), road=flat)
    road_quads = [quad for quad in scene.quads if quad.kind == "road"]
    worst = []
    for quad in road_quads:  # over the quad's own extent (not the 0.6 m overlaps with its neighbours)
        grid = np.stack(np.meshgrid(np.linspace(0.6, quad.width - 0.6, 7), np.linspace(0.0, quad.height, 7)), axis=-1).reshape(-1, 2)
        points = quad.points(grid)
        worst.append(float(np.max(np.abs(points[:, 2] - flat.height(points[:, :2])))))
    assert np.median(worst) < 0.01 and np.percentile(worst, 90) < 0.03 and max(worst) < 0.035
    width = SceneConfig().road_width
    assert {quad.road_width for quad in road_quads} == {width}
    assert {quad.road_across for quad in road_quads} == {0.0, width / 2.0}
    assert all(abs(quad.height - width / 2.0) < 0.01 * width for quad in road_quads)  # across the tilted surface
