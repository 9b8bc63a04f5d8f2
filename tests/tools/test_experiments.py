"""Robustness-experiment helpers (ampc_vo.tools.experiments): a miscalibrated rig rotates only the named
mounts about their own axes, and the odometry scored on a simulation uses the rig it is given."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ampc_vo.config import VoConfig
from ampc_vo.tools.experiments import miscalibrated_rig, score_on_simulation
from ampc_vo.geometry import rot_x


def test_miscalibrated_rig_rotates_the_named_mounts_about_their_own_axes(default_rig):
    tilted = miscalibrated_rig(default_rig, ("front",), "tilt", 2.0)
    before, after = default_rig.camera("front"), tilted.camera("front")
    np.testing.assert_allclose(after.T_body_camera[:3, :3], before.T_body_camera[:3, :3] @ rot_x(math.radians(2.0)), atol=1e-12)
    np.testing.assert_allclose(after.T_body_camera[:3, 3], before.T_body_camera[:3, 3])
    optical_axis_change = math.degrees(math.acos(np.clip(before.R_body_camera[:, 2] @ after.R_body_camera[:, 2], -1, 1)))
    assert optical_axis_change == pytest.approx(2.0, abs=1e-9)
    for name in default_rig.camera_names:
        if name != "front":
            np.testing.assert_array_equal(tilted.camera(name).T_body_camera, default_rig.camera(name).T_body_camera)
    rolled = miscalibrated_rig(default_rig, ("rear",), "roll", 1.0).camera("rear")
    np.testing.assert_allclose(rolled.R_body_camera[:, 2], default_rig.camera("rear").R_body_camera[:, 2], atol=1e-12)  # roll keeps the optical axis
    with pytest.raises(ValueError, match="no camera"):
        miscalibrated_rig(default_rig, ("roof",), "tilt", 1.0)
    with pytest.raises(ValueError, match="unknown camera axis"):
        miscalibrated_rig(default_rig, ("front",), "yaw", 1.0)


def test_score_on_simulation_runs_with_the_rig_it_is_given(ci_simulation):
    """Exactly calibrated: the issue-7 limits; the rear (trailer) camera panned by 3 degrees biases the
    hitch angle, which only happens if that rig is the one the odometry runs with."""
    exact = score_on_simulation(ci_simulation, VoConfig())
    assert exact.tractor_ate_m < 0.02 * exact.distance_m and exact.hitch_rmse_deg < 0.5
    panned = score_on_simulation(ci_simulation, VoConfig(), miscalibrated_rig(ci_simulation.rig, ("rear",), "pan", 3.0))
    assert panned.hitch_rmse_deg > 2.0 * exact.hitch_rmse_deg, (exact, panned)
