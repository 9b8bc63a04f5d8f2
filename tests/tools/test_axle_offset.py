"""Axle offset estimation from ground-truth poses (the (NH) constraint solved for axle_x)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.tools.axle_offset import estimate_axle_x
from ampc_vo.errors import AmpcError
from ampc_vo.sim.kinematics import simulate_kinematics
from ampc_vo.sim.routes import route_from_list


@pytest.mark.parametrize("axle_x", [0.6, -1.1])
def test_recovers_the_simulated_axle_offset(axle_x):
    route = route_from_list(
        [{"type": "straight", "length": 5}, {"type": "turn", "angle_deg": 30, "radius": 30, "transition": 5},
         {"type": "s_curve", "length": 20, "max_curvature": 0.03}], 8.0, "test")
    truth = simulate_kinematics(route, 10.0, axle_x, -8.0)
    for step in (1, 3):
        estimate = estimate_axle_x(truth.T_world_tractor, step=step)
        assert estimate.axle_x == pytest.approx(axle_x, abs=0.01)
        assert estimate.pairs > 10 and estimate.standard_error < 0.03


def test_noisy_poses_give_a_close_estimate_with_an_honest_standard_error():
    route = route_from_list([{"type": "turn", "angle_deg": 60, "radius": 15}], 6.0, "test")
    truth = simulate_kinematics(route, 10.0, 1.0, -8.0)
    poses = truth.T_world_tractor.copy()
    poses[:, :2, 3] += np.random.default_rng(0).normal(scale=0.002, size=(len(poses), 2))
    estimate = estimate_axle_x(poses, step=3)
    assert abs(estimate.axle_x - 1.0) < 3 * estimate.standard_error + 0.02


def test_straight_driving_is_reported_as_unobservable():
    route = route_from_list([{"type": "straight", "length": 20}], 8.0, "test")
    truth = simulate_kinematics(route, 10.0, 1.0, -8.0)
    with pytest.raises(AmpcError, match="not observable"):
        estimate_axle_x(truth.T_world_tractor)
