"""Road surface (issue 13): grade line with parabolic vertical curves, crown, superelevation, bumps, plane.

Expected values are computed here from the configured numbers (grades, curve lengths, slopes),
not from the module's formulas."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ampc_vo.sim.road import RoadConfig, RoadSurface, SIDE_FRICTION, GRAVITY
from ampc_vo.sim.routes import route_from_list


def _straight_road(config: RoadConfig, length: float = 600.0) -> RoadSurface:
    station = np.arange(-50.0, length, 0.5)
    path = np.column_stack([station, np.zeros_like(station)])
    return config.surface(path, station, np.zeros_like(station), edge_m=6.5)


def test_grade_line_is_linear_on_tangents_and_parabolic_in_vertical_curves():
    road = _straight_road(RoadConfig(start_grade=0.02, grade_changes=((200.0, 0.08), (400.0, -0.06)), vertical_curve_m=100.0))
    station = np.arange(0.0, 550.0, 0.5)
    height = road.height(np.column_stack([station, np.zeros_like(station)]))
    grade = np.gradient(height, station)
    on = lambda low, high: (station > low) & (station < high)  # noqa: E731
    assert np.allclose(grade[on(5, 145)], 0.02, atol=1e-6)           # before the first curve (150..250)
    assert np.allclose(grade[on(255, 345)], 0.08, atol=1e-6)         # between the curves
    assert np.allclose(grade[on(455, 545)], -0.06, atol=1e-6)        # after the second (350..450)
    # inside a vertical curve the grade changes linearly: constant second derivative dg / L
    second = np.gradient(grade, station)
    assert np.allclose(second[on(160, 240)], 0.06 / 100.0, rtol=1e-3)
    assert np.allclose(second[on(360, 440)], -0.14 / 100.0, rtol=1e-3)
    # elevation gained = integral of the grade: 2 % for 150 m, the curve's mean 5 % for 100 m, ...
    expected_250 = 0.02 * 150.0 + 0.05 * 100.0
    assert height[np.argmin(np.abs(station - 250.0))] - height[0] == pytest.approx(expected_250, abs=1e-3)


def test_crown_falls_away_from_the_centre_on_both_sides_and_levels_beyond_the_shoulder():
    road = _straight_road(RoadConfig(crown=0.025))
    lateral = np.array([-6.5, -3.5, -1.0, 0.0, 1.0, 3.5, 6.5, 9.0, 20.0])
    height = road.height(np.column_stack([np.full_like(lateral, 100.0), lateral]))
    assert np.allclose(height, -0.025 * np.minimum(np.abs(lateral), 6.5), atol=1e-9)


def test_superelevation_is_planar_and_lowers_the_inside_of_a_left_curve():
    radius, design_speed, maximum = 100.0, 20.0, 0.06
    route = route_from_list([{"type": "straight", "length": 50}, {"type": "turn", "angle_deg": 90, "radius": radius, "transition": 40},
                             {"type": "straight", "length": 50}], 10.0, "test")
    config = RoadConfig(crown=0.02, max_superelevation=maximum, design_speed=design_speed)
    path, station, curvature = route.design_path((0.0, 0.0), 30.0)
    road = config.surface(path, station, curvature, edge_m=6.5)
    # AASHTO method 1: e proportional to 1/R, e_max at R_min = v^2 / (g (e_max + f))
    minimum_radius = design_speed**2 / (GRAVITY * (maximum + SIDE_FRICTION))
    expected_bank = min(maximum * minimum_radius / radius, maximum)
    middle = np.argmin(np.abs(station - (50.0 + 20.0 + 0.5 * (radius * math.pi / 2.0 - 40.0))))  # middle of the arc
    point, tangent = path[middle], path[middle + 1] - path[middle - 1]
    tangent /= np.linalg.norm(tangent)
    left = np.array([-tangent[1], tangent[0]])
    lateral = np.array([-3.0, -1.0, 1.0, 3.0])
    height = road.height(point + lateral[:, None] * left) - road.height(point[None, :])
    assert expected_bank > 0.02  # steeper than the crown: the whole section is one plane
    assert np.allclose(height, -expected_bank * lateral, atol=2e-4)


def test_bumps_and_potholes_and_the_plane_slope():
    road = _straight_road(RoadConfig(plane_slope=(0.01, -0.02), bumps=((100.0, 0.0, 4.0, 6.0, 0.08), (200.0, -1.5, 1.0, 0.6, -0.05))))
    xy = np.array([[100.0, 0.0], [98.0, 0.0], [200.0, -1.5], [300.0, 5.0]])
    plane = xy @ np.array([0.01, -0.02])
    assert np.allclose(road.height(xy) - plane, [0.08, 0.0, -0.05, 0.0], atol=1e-9)
    normal = road.normal(np.array([[300.0, 5.0]]))[0]
    assert np.allclose(normal, np.array([-0.01, 0.02, 1.0]) / np.linalg.norm([-0.01, 0.02, 1.0]), atol=1e-9)


def test_lane_change_does_not_move_the_road():
    route = route_from_list([{"type": "straight", "length": 40}, {"type": "lane_change", "length": 100, "offset": 3.5},
                             {"type": "straight", "length": 40}], 20.0, "test")
    path, station, _ = route.design_path((0.0, 0.0), 10.0)
    assert np.allclose(path[:, 1], 0.0, atol=1e-9) and path[-1, 0] == pytest.approx(station[-1], abs=1e-9)


def test_lane_slope_follows_the_lane_across_the_crown_after_a_lane_change():
    route = route_from_list([{"type": "straight", "length": 40}, {"type": "lane_change", "length": 100, "offset": 3.5},
                             {"type": "straight", "length": 40}], 20.0, "test")
    slope = RoadConfig(crown=0.025, lane_offset_m=1.75).lane_slope(route.design_curvature, route.lane_change_offset)
    assert slope(20.0, 0.0) == pytest.approx(0.025)     # right lane: the road rises to the left, towards the crown
    assert slope(160.0, 0.0) == pytest.approx(-0.025)   # left lane after the change: it falls to the left
    assert route.lane_change_offset(160.0) == pytest.approx(3.5) and route.lane_change_offset(90.0) == pytest.approx(1.75)
    assert route.design_curvature(60.0) == 0.0 and route.curvature(60.0) != 0.0
    plane = RoadConfig(plane_slope=(0.0, -0.01)).lane_slope(route.design_curvature)
    assert plane(0.0, 0.0) == pytest.approx(-0.01) and plane(0.0, math.pi / 2.0) == pytest.approx(0.0, abs=1e-12)
