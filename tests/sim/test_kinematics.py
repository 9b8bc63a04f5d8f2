"""Tractor-trailer kinematics (DESIGN 6): steady state, non-holonomic trailer axle, joint coincidence."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.errors import ConfigError
from ampc_vo.geometry import rot_z, wrap_angle, yaw_of
from ampc_vo.sim.kinematics import axle_positions, simulate_kinematics, steady_state_hitch_angle
from ampc_vo.sim.routes import route_from_list
from ampc_vo.sim.config import load_sim_config

SIM_CONFIGS = sorted((Path(__file__).resolve().parents[2] / "configs" / "sim").glob("*.yaml"))
S_A, TRAILER_AXLE_X = 0.5, -8.0


@pytest.mark.parametrize("radius, angle_deg", [(20.0, 540.0), (-35.0, -400.0), (60.0, 300.0), (12.5, 720.0)])
def test_hitch_angle_converges_to_analytic_steady_state(radius, angle_deg):
    route = route_from_list([{"type": "turn", "angle_deg": angle_deg, "radius": abs(radius)}], 10.0, "test")
    # Stop 1 s before the end of the turn (the route continues straight after it).
    trajectory = simulate_kinematics(route, 10.0, S_A, TRAILER_AXLE_X, initial_hitch_angle=0.0, duration=route.length / 10.0 - 1.0)
    assert trajectory.arc_length[-1] < route.length
    expected = steady_state_hitch_angle(1.0 / radius, S_A, TRAILER_AXLE_X)
    # Relaxation length is about s_B = 8 m: after >= 250 m the transient is below 1e-8 rad.
    assert abs(trajectory.hitch_angle[-1] - expected) < 1e-6
    assert math.copysign(1.0, expected) == -math.copysign(1.0, radius)  # trailer swings to the outside of its heading


def test_steady_state_is_an_equilibrium_of_the_ode():
    for curvature in (-0.07, -0.01, 0.0, 0.02, 0.075):
        theta = steady_state_hitch_angle(curvature, S_A, TRAILER_AXLE_X)
        v, s_b = 5.0, -TRAILER_AXLE_X
        yaw_rate_b = (-v * math.sin(theta) - v * curvature * S_A * math.cos(theta)) / s_b
        assert abs(yaw_rate_b - v * curvature) < 1e-12


def test_no_steady_state_for_too_tight_turns():
    with pytest.raises(ValueError, match="too tight"):
        steady_state_hitch_angle(1.0 / 5.0, S_A, TRAILER_AXLE_X)


def test_turn_segment_has_exact_heading_change_and_straight_is_straight():
    route = route_from_list([{"type": "straight", "length": 20}, {"type": "turn", "angle_deg": 90, "radius": 25, "transition": 10},
                             {"type": "straight", "length": 20}], 8.0, "test")
    trajectory = simulate_kinematics(route, 100.0, S_A, TRAILER_AXLE_X)
    # Heading change of the whole route: 90 deg (the final frame may overshoot the end by < 1 frame on a straight).
    assert abs(math.degrees(yaw_of(trajectory.T_world_tractor[-1])) - 90.0) < 1e-6
    on_first_straight = trajectory.arc_length < 20.0 - 1e-9
    assert np.allclose(trajectory.T_world_tractor[on_first_straight, 1, 3], 0.0, atol=1e-12)


def test_lane_change_moves_sideways_without_net_heading_change():
    route = route_from_list([{"type": "lane_change", "length": 120, "offset": 3.5}, {"type": "straight", "length": 30}], 20.0, "test")
    trajectory = simulate_kinematics(route, 50.0, S_A, TRAILER_AXLE_X)
    assert abs(yaw_of(trajectory.T_world_tractor[-1])) < 1e-6
    assert abs(trajectory.T_world_tractor[-1, 1, 3] - 3.5) < 0.05


@pytest.mark.parametrize("config_path", SIM_CONFIGS, ids=[path.stem for path in SIM_CONFIGS])
def test_every_route_obeys_the_nonholonomic_constraints_and_the_joint(config_path):
    config = load_sim_config(config_path)
    rig = config.load_rig()
    s_a, trailer_axle_x = rig.axle_x("tractor"), rig.axle_x("trailer")
    trajectory = simulate_kinematics(config.route, 100.0, s_a, trailer_axle_x, config.initial_hitch_angle, config.duration)
    # The hitch point of both bodies coincides and the relative rotation is Rz(hitch_angle).
    assert np.allclose(trajectory.T_world_tractor[:, :3, 3], trajectory.T_world_trailer[:, :3, 3], atol=1e-12)
    relative = np.einsum("fba,fbc->fac", trajectory.T_world_tractor[:, :3, :3], trajectory.T_world_trailer[:, :3, :3])
    expected = np.stack([rot_z(angle) for angle in trajectory.hitch_angle])
    assert np.allclose(relative, expected, atol=1e-12)
    # Lateral velocity of both axle midpoints vanishes (central differences at 100 Hz; the
    # residual is the O(dt^2) difference error, far below a violated constraint's ~v*theta).
    dt = 0.01
    tractor_axle, trailer_axle = axle_positions(trajectory, s_a, trailer_axle_x)
    for axle, poses in ((tractor_axle, trajectory.T_world_tractor), (trailer_axle, trajectory.T_world_trailer)):
        velocity = (axle[2:] - axle[:-2]) / (2.0 * dt)
        lateral = np.einsum("fa,fa->f", velocity, poses[1:-1, :3, 1])
        speed = np.linalg.norm(velocity, axis=1)
        assert np.max(np.abs(lateral)) < 2e-4 * max(speed.max(), 1.0), config_path.stem
    # The trailer really articulates (so the check above is not trivially satisfied).
    if config_path.stem == "yard":
        assert np.max(np.abs(trajectory.hitch_angle)) > math.radians(40.0)


def test_sampling_rate_and_duration():
    route = route_from_list([{"type": "straight", "length": 100}], 10.0, "test")
    trajectory = simulate_kinematics(route, 30.0, S_A, TRAILER_AXLE_X, duration=2.0)
    assert len(trajectory) == 61
    assert np.allclose(np.diff(trajectory.timestamps), 1.0 / 30.0)
    assert abs(trajectory.T_world_tractor[-1, 0, 3] - 20.0) < 1e-9


def test_initial_hitch_angle_decays_on_a_straight():
    route = route_from_list([{"type": "straight", "length": 120}], 5.0, "test")
    trajectory = simulate_kinematics(route, 10.0, S_A, TRAILER_AXLE_X, initial_hitch_angle=math.radians(20.0))
    assert abs(trajectory.hitch_angle[0] - math.radians(20.0)) < 1e-15
    assert abs(trajectory.hitch_angle[-1]) < math.radians(0.01)
    assert np.all(np.abs(wrap_angle(np.diff(trajectory.hitch_angle))) < 0.05)


def test_bad_inputs_raise_config_errors():
    route = route_from_list([{"type": "straight", "length": 10}], 5.0, "test")
    with pytest.raises(ConfigError, match="behind the hitch"):
        simulate_kinematics(route, 10.0, S_A, 2.0)
    with pytest.raises(ConfigError, match="rate_hz"):
        simulate_kinematics(route, 0.0, S_A, TRAILER_AXLE_X)
    with pytest.raises(ConfigError, match="segments\\[0\\].type"):
        route_from_list([{"type": "loop", "length": 10}], 5.0, "route.yaml")
    with pytest.raises(ConfigError, match="route.yaml: segments\\[1\\].radius"):
        route_from_list([{"type": "straight", "length": 10}, {"type": "turn", "angle_deg": 90}], 5.0, "route.yaml")


def test_stop_segment_holds_the_vehicle_still_for_its_duration():
    route = route_from_list([{"type": "straight", "length": 40}, {"type": "stop", "duration": 3},
                             {"type": "turn", "angle_deg": 30, "radius": 40}], 8.0, "test")
    trajectory = simulate_kinematics(route, 10.0, S_A, TRAILER_AXLE_X, initial_hitch_angle=0.1)
    steps = np.linalg.norm(np.diff(trajectory.T_world_tractor[:, :3, 3], axis=0), axis=1)
    still = steps < 1e-12
    assert 29 <= still.sum() <= 31                                   # 3 s at 10 Hz
    assert np.all(np.diff(np.flatnonzero(still)) == 1)               # one contiguous standstill
    assert np.all(trajectory.speed[1:][still] == 0.0)
    assert np.ptp(trajectory.hitch_angle[1:][still]) == 0.0          # the hitch does not move either
    assert abs(trajectory.arc_length[np.flatnonzero(still)[0] + 1] - 40.0) < 0.01
    assert np.max(steps) <= 0.8 + 1e-9 and trajectory.arc_length[-1] >= route.length


def _slip_angles(trajectory, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angle (rad) from each axle's heading to its velocity (central differences), and the trailer
    axle's lateral acceleration estimate |v_B| psi_B' (frames 1..F-2)."""
    tractor, trailer = axle_positions(trajectory, S_A, TRAILER_AXLE_X)
    angles = []
    for positions, poses in ((tractor, trajectory.T_world_tractor), (trailer, trajectory.T_world_trailer)):
        velocity = (positions[2:] - positions[:-2]) * rate_hz / 2.0
        heading = np.array([yaw_of(pose) for pose in poses[1:-1]])
        angles.append(wrap_angle(np.arctan2(velocity[:, 1], velocity[:, 0]) - heading))
    trailer_yaw = np.unwrap([yaw_of(pose) for pose in trajectory.T_world_trailer])
    trailer_speed = np.linalg.norm(trailer[2:] - trailer[:-2], axis=1) * rate_hz / 2.0
    trailer_lateral = trailer_speed * (trailer_yaw[2:] - trailer_yaw[:-2]) * rate_hz / 2.0
    return angles[0], angles[1], trailer_lateral


@pytest.mark.parametrize("radius", [20.0, -30.0])
def test_tyre_slip_turns_each_axles_velocity_outward_by_slip_times_lateral_acceleration(radius):
    """Linear tyre model (module docstring): in a steady turn the tractor axle's velocity points
    outward of its heading by slip * v^2 / R, the trailer axle's by slip * |v_B| psi_B'; the
    trailer still follows (the hitch angle settles) and the route is the axle's path."""
    slip, speed, rate = math.radians(0.5), 8.0, 100.0  # 0.5 deg per m/s^2: 1.6 deg at 3.2 m/s^2
    route = route_from_list([{"type": "turn", "angle_deg": math.copysign(300.0, radius), "radius": abs(radius)}], speed, "test")
    trajectory = simulate_kinematics(route, rate, S_A, TRAILER_AXLE_X, duration=route.length / speed - 1.0, slip=slip)
    tractor_angle, trailer_angle, trailer_lateral = _slip_angles(trajectory, rate)
    settled = slice(len(tractor_angle) // 2, None)
    expected_tractor = -slip * speed**2 / radius
    assert np.allclose(tractor_angle[settled], expected_tractor, rtol=0.01, atol=1e-5)
    assert abs(expected_tractor) > math.radians(1.0)
    assert np.allclose(trailer_angle[settled], -slip * trailer_lateral[settled], rtol=0.02, atol=1e-5)
    assert np.ptp(trajectory.hitch_angle[-200:]) < 1e-4  # settles (the trailer follows)
    ideal = simulate_kinematics(route, rate, S_A, TRAILER_AXLE_X, duration=route.length / speed - 1.0)
    _, ideal_trailer_angle, _ = _slip_angles(ideal, rate)
    assert np.max(np.abs(ideal_trailer_angle)) < 1e-4  # no slip: NH holds


def test_tyre_slip_must_be_small_and_non_negative():
    route = route_from_list([{"type": "straight", "length": 10}], 5.0, "test")
    with pytest.raises(ConfigError, match="tyre slip"):
        simulate_kinematics(route, 10.0, S_A, TRAILER_AXLE_X, slip=-0.01)
