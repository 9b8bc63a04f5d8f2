"""The correspondences' own noise (ampc_vo.solvers.noise): the bearings' sigma, whatever the motion."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.geometry import rot_y
from ampc_vo.sim.two_view import make_two_view_problem, reference_rig
from ampc_vo.solvers.estimates import as_groups
from ampc_vo.solvers.noise import correspondence_noise

FOCAL_PX = 700.0


@pytest.mark.parametrize("noise_px, chord, outliers", [(0.5, 0.0, 0.0), (1.5, 0.0, 0.3), (1.0, 1.2, 0.3), (2.0, 0.4, 0.1)])
def test_the_noise_of_still_and_moving_pitched_pairs_with_outliers(noise_px, chord, outliers):
    """Pixel noise of sigma per bearing gives a robust sigma of sigma / focal, at rest and moving,
    with the body pitched by 0.8 degrees between the views (braking) and up to 30 % outliers;
    broken (no refit, or the planar motion's residuals) it reads the pitch or the outliers."""
    rig = reference_rig()
    estimates = []
    for seed in range(4):
        problem = make_two_view_problem(np.random.default_rng(80 + seed), rig=rig, pixel_noise_px=noise_px, focal_px=FOCAL_PX, chord=chord,
                                        yaw_change=0.02 if chord else 0.0, outlier_fraction=outliers, points_per_body=200)
        pitch = rot_y(np.radians(0.8))
        pitched = [(bearings_i, bearings_j @ pitch.T, center) for bearings_i, bearings_j, center in problem.groups("tractor")]
        estimates.append(correspondence_noise(as_groups(pitched), np.random.default_rng(seed)) * FOCAL_PX)
    # pinhole pixels towards the image edge subtend less angle than 1 / focal: up to 10 % less
    assert np.median(estimates) == pytest.approx(0.95 * noise_px, rel=0.12)
    assert max(estimates) < 1.25 * noise_px


def test_too_few_correspondences_measure_no_noise():
    rng = np.random.default_rng(1)
    problem = make_two_view_problem(rng, rig=reference_rig(), pixel_noise_px=1.0, points_per_body=12)
    assert np.isnan(correspondence_noise(as_groups(problem.groups("tractor")), rng))
