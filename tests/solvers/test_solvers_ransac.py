"""Tests of the RANSAC estimators, refinement and degeneracy statuses (DESIGN 2.1-2.3)."""
from __future__ import annotations

import numpy as np
import pytest

from ampc_vo.errors import BearingError
from ampc_vo.rig import Rig, replace_camera
from ampc_vo.solvers import (
    RansacConfig,
    SolverStatus,
    estimate_hitch_angles,
    estimate_tractor_motion,
    refine_joint,
)
from ampc_vo.sim.two_view import make_two_view_problem, reference_rig
from ampc_vo.solvers.estimates import STILL_PARALLAX_SIGMAS, as_groups, median_parallax

DESIGN_2_3 = dict(pixel_noise_px=1.0, focal_px=700.0, points_per_body=100, outlier_fraction=0.1, chord=1.0,
                  yaw_change=(-0.1, 0.1), hitch_angle=(-np.deg2rad(45), np.deg2rad(45)))


@pytest.fixture(scope="module")
def rig() -> Rig:
    return reference_rig()  # s_B = 8 m, rear camera 12.5 m behind the hitch, 700 px focal


def _rig_with_front_camera_above_axle(rig: Rig) -> Rig:
    front = rig.camera("front")
    T = front.T_body_camera.copy()
    T[0, 3] = rig.axle_x("tractor")
    return Rig(rig.bodies, (replace_camera(front, T_body_camera=T), rig.camera("rear")))


def test_hitch_angle_accuracy_with_known_front_motion_matches_design_2_3(rig: Rig) -> None:
    rng = np.random.default_rng(30)
    errors = []
    for _ in range(120):
        problem = make_two_view_problem(rng, rig=rig, **DESIGN_2_3)
        hitch = estimate_hitch_angles(problem.groups("trailer"), (problem.yaw_change, problem.hitch_translation), problem.trailer_axle_x)
        assert hitch.status is SolverStatus.OK
        errors.append(np.rad2deg([hitch.hitch_angle_i - problem.hitch_angle_i, hitch.hitch_angle_j - problem.hitch_angle_j]))
        truth = problem.on("trailer")[0].inliers
        assert np.sum(hitch.inlier_masks[0] & ~truth) <= 2  # outliers rejected
        assert np.sum(hitch.inlier_masks[0] & truth) >= 0.85 * np.sum(truth)
    errors = np.abs(np.array(errors))
    assert np.median(errors[:, 0]) <= 0.15 and np.percentile(errors[:, 0], 90) <= 0.35
    assert np.median(errors[:, 1]) <= 0.15 and np.percentile(errors[:, 1], 90) <= 0.35


def test_tractor_ransac_accuracy_and_inliers(rig: Rig) -> None:
    rng = np.random.default_rng(31)
    yaw_errors, chord_errors = [], []
    for _ in range(40):
        problem = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "yaw_change": (0.03, 0.1)})
        estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
        assert estimate.status is SolverStatus.OK
        truth = problem.on("tractor")[0].inliers
        assert np.sum(estimate.inlier_masks[0] & ~truth) <= 2
        assert estimate.T_i_j.shape == (4, 4) and np.isfinite(estimate.chord_sigma)
        yaw_errors.append(np.rad2deg(abs(estimate.yaw_change - problem.yaw_change)))
        chord_errors.append(abs(estimate.chord - problem.chord))
    assert np.median(yaw_errors) < 0.05
    assert np.median(chord_errors) < 0.06


def test_joint_refinement_with_the_trailer_constraint_beats_refinement_without_it(rig: Rig) -> None:
    rng = np.random.default_rng(32)
    with_nh, without_nh, tractor_only = [], [], []
    while len(with_nh) < 50:
        problem = make_two_view_problem(rng, rig=rig, **DESIGN_2_3)
        tractor = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
        if tractor.status is not SolverStatus.OK:
            continue  # scale unobservable on a near-straight draw: nothing to refine
        hitch = estimate_hitch_angles(problem.groups("trailer"), (tractor.yaw_change, tractor.translation), problem.trailer_axle_x)
        args = (problem.groups("tractor"), problem.groups("trailer"), tractor, hitch, problem.tractor_axle_x, problem.trailer_axle_x)
        joint = refine_joint(*args)
        free = refine_joint(*args, trailer_nonholonomic=False)
        for result, store in ((joint, with_nh), (free, without_nh)):
            store.append([np.rad2deg(abs(result.hitch_angle_i - problem.hitch_angle_i)), abs(result.chord - problem.chord),
                          np.rad2deg(abs(result.yaw_change - problem.yaw_change))])
        tractor_only.append([np.nan, abs(tractor.chord - problem.chord), np.rad2deg(abs(tractor.yaw_change - problem.yaw_change))])
        assert joint.T_trailer_i_j.shape == (4, 4) and joint.covariance.shape == (3, 3)
    with_nh, without_nh, tractor_only = (np.median(np.array(x), axis=0) for x in (with_nh, without_nh, tractor_only))
    assert with_nh[0] < 0.5 * without_nh[0]  # hitch angle (DESIGN 2.3: ~3x)
    assert with_nh[1] < without_nh[1] and with_nh[1] < tractor_only[1]  # chord
    assert with_nh[2] < tractor_only[2]  # yaw change


def test_prior_hitch_angle_keeps_continuity(rig: Rig) -> None:
    problem = make_two_view_problem(np.random.default_rng(33), rig=rig, **{**DESIGN_2_3, "hitch_angle": 0.3})
    motion = (problem.yaw_change, problem.hitch_translation)
    hitch = estimate_hitch_angles(problem.groups("trailer"), motion, problem.trailer_axle_x, prior_hitch_angle=0.3)
    assert hitch.ok and abs(hitch.hitch_angle_i - 0.3) < np.deg2rad(0.5)
    assert np.isfinite(hitch.hitch_angle_sigma) and 0 < hitch.hitch_angle_sigma < np.deg2rad(1)


def test_standstill_gives_a_status_and_holds_the_hitch_angle(rig: Rig) -> None:
    problem = make_two_view_problem(np.random.default_rng(34), rig=rig, **{**DESIGN_2_3, "chord": 0.0, "yaw_change": 0.0})
    tractor = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
    assert tractor.status is SolverStatus.STANDSTILL and tractor.chord == 0.0
    np.testing.assert_array_equal(tractor.T_i_j, np.eye(4))
    hitch = estimate_hitch_angles(problem.groups("trailer"), (0.0, np.zeros(3)), problem.trailer_axle_x, prior_hitch_angle=0.2)
    assert hitch.status is SolverStatus.STANDSTILL and hitch.hitch_angle_i == 0.2 and hitch.hitch_angle_j == 0.2


def test_straight_driving_with_one_camera_above_the_axle_is_scale_unobservable(rig: Rig) -> None:
    rig_above = _rig_with_front_camera_above_axle(rig)
    for straight_rig in (rig_above, rig):
        problem = make_two_view_problem(np.random.default_rng(35), rig=straight_rig, **{**DESIGN_2_3, "yaw_change": 0.0})
        estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
        assert estimate.status is SolverStatus.SCALE_UNOBSERVABLE
        assert np.isnan(estimate.chord) and estimate.T_i_j is None
        assert abs(estimate.yaw_change) < np.deg2rad(0.1) and estimate.chord_sign == 1.0
        with_prior = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, chord_prior=1.0)
        assert with_prior.status is SolverStatus.SCALE_UNOBSERVABLE and with_prior.chord == 1.0
        assert abs(with_prior.T_i_j[0, 3] - 1.0) < 0.01


def test_camera_above_the_axle_uses_the_scale_free_fallback_when_turning(rig: Rig) -> None:
    problem = make_two_view_problem(np.random.default_rng(36), rig=_rig_with_front_camera_above_axle(rig), **{**DESIGN_2_3, "yaw_change": 0.08})
    estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
    assert estimate.status is SolverStatus.SCALE_UNOBSERVABLE and np.isnan(estimate.chord)
    assert abs(estimate.yaw_change - 0.08) < np.deg2rad(0.1)


def test_degenerate_inputs_give_a_status_not_an_exception(rig: Rig) -> None:
    problem = make_two_view_problem(np.random.default_rng(37), rig=rig, **DESIGN_2_3)
    bearings_i, bearings_j, center = problem.groups("tractor")[0]
    axle = problem.tractor_axle_x
    assert estimate_tractor_motion([], axle).status is SolverStatus.TOO_FEW_POINTS
    assert estimate_tractor_motion([(bearings_i[:1], bearings_j[:1], center)], axle).status is SolverStatus.TOO_FEW_POINTS
    assert estimate_tractor_motion([(np.zeros((0, 3)), np.zeros((0, 3)), center)], axle).status is SolverStatus.TOO_FEW_POINTS
    all_nan = np.full_like(bearings_i, np.nan)
    result = estimate_tractor_motion([(all_nan, bearings_j, center)], axle)
    assert result.status is SolverStatus.TOO_FEW_POINTS and result.inlier_masks[0].shape == (100,)
    some_nan = bearings_i.copy()
    some_nan[::4] = np.nan
    some_nan[1] = 0.0
    result = estimate_tractor_motion([(some_nan, bearings_j, center)], axle)
    assert result.status.usable and not result.inlier_masks[0][::4].any() and not result.inlier_masks[0][1]
    noise = np.random.default_rng(0).normal(size=(2, 80, 3))
    assert estimate_tractor_motion([(noise[0], noise[1], center)], axle).status is SolverStatus.NO_CONSENSUS
    trailer = problem.groups("trailer")
    assert estimate_hitch_angles(trailer, (np.nan, np.ones(3)), -8.0).status is SolverStatus.NO_MOTION_PRIOR
    assert estimate_hitch_angles(trailer, (0.1, None), -8.0).status is SolverStatus.NO_MOTION_PRIOR
    assert estimate_hitch_angles([], (0.05, np.array([1.0, 0.0, 0.0])), -8.0).status is SolverStatus.TOO_FEW_POINTS
    assert estimate_hitch_angles([(noise[0], noise[1], trailer[0][2])], (0.05, np.array([1.0, 0.05, 0.0])), -8.0).status is SolverStatus.NO_CONSENSUS
    failed = estimate_tractor_motion([], axle)
    hitch = estimate_hitch_angles(trailer, (problem.yaw_change, problem.hitch_translation), -8.0)
    joint = refine_joint([], trailer, failed, hitch, axle, -8.0)
    assert joint.status is SolverStatus.TOO_FEW_POINTS
    with pytest.raises(BearingError):
        estimate_tractor_motion([(bearings_i[:, :2], bearings_j, center)], axle)


def test_estimates_are_reproducible_with_the_config_seed(rig: Rig) -> None:
    problem = make_two_view_problem(np.random.default_rng(38), rig=rig, **DESIGN_2_3)
    config = RansacConfig(seed=5)
    first = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, config)
    second = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, config)
    assert first.yaw_change == second.yaw_change and first.chord == second.chord


def test_trailer_constraint_recovers_the_scale_in_straight_driving(rig: Rig) -> None:
    """Straight tractor, hitch 0.4 rad: the front camera alone has no scale, but the trailer's turn
    depends on |t| through the trailer constraint (DESIGN 2), so the joint refinement recovers it."""
    rng = np.random.default_rng(39)
    chords = []
    for _ in range(6):
        problem = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "yaw_change": 0.0, "hitch_angle": 0.4})
        tractor = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, chord_prior=1.3)  # wrong prior
        assert tractor.status is SolverStatus.SCALE_UNOBSERVABLE and tractor.chord == 1.3
        hitch = estimate_hitch_angles(problem.groups("trailer"), (tractor.yaw_change, tractor.translation), problem.trailer_axle_x)
        joint = refine_joint(problem.groups("tractor"), problem.groups("trailer"), tractor, hitch, problem.tractor_axle_x, problem.trailer_axle_x)
        assert joint.status is SolverStatus.OK
        chords.append(joint.chord)
    assert abs(np.median(chords) - 1.0) < 0.1


def test_chord_direction_model_error_makes_near_straight_scale_unobservable(rig: Rig) -> None:
    """``chord_direction_sigma`` (RansacConfig): at a 0.1 deg yaw change the 2-point chord hinges on
    the chord direction, so a 0.1 deg model error (curvature transitions, slip) leaves it unobservable;
    at 6 deg the same model error leaves the scale known and accurate."""
    import dataclasses

    rng = np.random.default_rng(40)
    exact, modelled = RansacConfig(), dataclasses.replace(RansacConfig(), chord_direction_sigma=np.deg2rad(0.1))
    near_straight = make_two_view_problem(rng, rig=rig, pixel_noise_px=0.1, yaw_change=np.deg2rad(0.1), chord=2.0)
    assert estimate_tractor_motion(near_straight.groups("tractor"), near_straight.tractor_axle_x, exact).status is SolverStatus.OK
    assert estimate_tractor_motion(near_straight.groups("tractor"), near_straight.tractor_axle_x, modelled).status is SolverStatus.SCALE_UNOBSERVABLE
    turning = make_two_view_problem(rng, rig=rig, pixel_noise_px=0.1, yaw_change=np.deg2rad(6.0), chord=2.0)
    estimate = estimate_tractor_motion(turning.groups("tractor"), turning.tractor_axle_x, modelled)
    assert estimate.status is SolverStatus.OK and abs(estimate.chord - 2.0) < 0.05


def test_tractor_ransac_proposes_only_motions_a_truck_can_drive(rig: Rig) -> None:
    """Moving traffic at a near-standstill makes consensus motions no truck can drive (a 10 degree
    turn within 10 cm). The 2-point samples are kept only within the tightest turn radius (4 m at
    the axle): such a motion is not returned, while a full-lock turn (5.5 m radius) is found."""
    rng = np.random.default_rng(35)
    for _ in range(5):
        tight = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "chord": 0.6, "yaw_change": 0.6 / 5.5})
        estimate = estimate_tractor_motion(tight.groups("tractor"), tight.tractor_axle_x)
        assert estimate.status is SolverStatus.OK
        assert np.rad2deg(abs(estimate.yaw_change - tight.yaw_change)) < 0.2
        spinning = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "chord": 0.1, "yaw_change": np.deg2rad(10.0)})
        estimate = estimate_tractor_motion(spinning.groups("tractor"), spinning.tractor_axle_x)
        assert estimate.status is not SolverStatus.OK or abs(estimate.yaw_change) < 0.5 * spinning.yaw_change


def _mixed(world, traffic) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per tractor camera, the correspondences of two problems on the same rig stacked."""
    return [(np.vstack([a[0], b[0]]), np.vstack([a[1], b[1]]), a[2]) for a, b in zip(world.groups("tractor"), traffic.groups("tractor"))]


def test_a_known_direction_of_travel_rejects_the_reverse_motion_of_traffic(rig: Rig) -> None:
    """Traffic moving with the truck looks like the truck reversing. At speed the direction of
    travel cannot change within a pair: with ``direction=+1`` the static world's forward motion is
    found although the traffic's backward motion has more correspondences."""
    rng = np.random.default_rng(36)
    for _ in range(5):
        world = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "points_per_body": 80, "outlier_fraction": 0.0, "chord": 1.5, "yaw_change": 0.05})
        traffic = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "points_per_body": 120, "outlier_fraction": 0.0, "chord": -1.0, "yaw_change": -0.03})
        either = estimate_tractor_motion(_mixed(world, traffic), world.tractor_axle_x)
        assert either.status in (SolverStatus.OK, SolverStatus.SCALE_UNOBSERVABLE) and either.chord_sign < 0  # the majority wins
        forward = estimate_tractor_motion(_mixed(world, traffic), world.tractor_axle_x, direction=1.0)
        assert forward.status is SolverStatus.OK and forward.chord > 0
        assert abs(forward.chord - world.chord) < 0.15 and np.rad2deg(abs(forward.yaw_change - world.yaw_change)) < 0.1
        assert np.sum(forward.inlier_masks[0][:80]) >= 70 and np.sum(forward.inlier_masks[0][80:]) <= 5


def test_a_motion_that_explains_few_correspondences_is_no_consensus(rig: Rig) -> None:
    """A planar motion fitting a small share of the tracks (a bump's pitch, traffic) is no
    measurement: with ``min_inlier_fraction`` 0.25 a pair of which 20 % fit gives NO_CONSENSUS,
    while the same pair passes on the absolute ``min_inliers`` alone."""
    rng = np.random.default_rng(37)
    for _ in range(5):
        problem = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "outlier_fraction": 0.8, "chord": 1.0, "yaw_change": 0.06})
        loose = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x)
        assert loose.status in (SolverStatus.OK, SolverStatus.SCALE_UNOBSERVABLE)
        assert np.rad2deg(abs(loose.yaw_change - problem.yaw_change)) < 0.3
        strict = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, RansacConfig(min_inlier_fraction=0.25))
        assert strict.status is SolverStatus.NO_CONSENSUS and strict.T_i_j is None


def test_a_truck_predicted_at_rest_that_moves_off_straight_keeps_its_tracks(rig: Rig) -> None:
    """Straight driving leaves the chord unobservable and the prior fills it; a prior near zero (the
    truck was at rest) must not score the tracks as if the truck stood still: the motion stays
    scale-unobservable with most tracks as inliers instead of no consensus."""
    rng = np.random.default_rng(38)
    problem = make_two_view_problem(rng, rig=rig, **{**DESIGN_2_3, "chord": 0.8, "yaw_change": 0.0})
    config = RansacConfig(min_inlier_fraction=0.25)
    estimate = estimate_tractor_motion(problem.groups("tractor"), problem.tractor_axle_x, config, chord_prior=0.001)
    assert estimate.status is SolverStatus.SCALE_UNOBSERVABLE
    assert estimate.num_inliers >= 0.8 * np.sum(problem.on("tractor")[0].inliers)
    assert estimate.chord == pytest.approx(0.001)


def _collapsed_refinement(monkeypatch) -> None:
    """The local optimisation returns its best model with the chord shrunk to 1 mm (what an
    unobservable chord's refinement did on a straight road in a realistic world)."""
    import ampc_vo.solvers.ransac as ransac

    refine = ransac._local_optimization

    def collapsed(*args, **kwargs):
        return [(cost, yaw, 0.001, np.diag([1e-10, 1e-10]), rms, inliers, start)
                for cost, yaw, _, _, rms, inliers, start in refine(*args, **kwargs)]

    monkeypatch.setattr(ransac, "_local_optimization", collapsed)


def test_a_chord_refined_to_nothing_is_no_standstill_where_the_tracks_translated(rig: Rig, monkeypatch) -> None:
    """Straight driving at 1.5 m/s: tracks with translation parallax and a moving prediction make a
    refined chord below ``min_chord`` an unmeasured chord (the prior's), not a standstill; tracks
    that only pitched (a body at rest on its suspension) stay a standstill."""
    from ampc_vo.geometry import rot_y

    _collapsed_refinement(monkeypatch)
    moving = make_two_view_problem(np.random.default_rng(40), rig=rig, **{**DESIGN_2_3, "chord": 1.5, "yaw_change": 0.0})
    estimate = estimate_tractor_motion(moving.groups("tractor"), moving.tractor_axle_x, chord_prior=1.5)
    assert estimate.status is SolverStatus.SCALE_UNOBSERVABLE and estimate.chord == pytest.approx(1.5)
    assert estimate.T_i_j[0, 3] == pytest.approx(1.5, abs=0.05)

    still = make_two_view_problem(np.random.default_rng(41), rig=rig, **{**DESIGN_2_3, "chord": 0.0, "yaw_change": 0.0, "outlier_fraction": 0.0})
    pitch = rot_y(np.radians(0.6))  # the rebound after a stop: 7 px at 700 px, above the standstill parallax
    pitched = [(bearings_i, bearings_j @ pitch.T, center) for bearings_i, bearings_j, center in still.groups("tractor")]
    assert estimate_tractor_motion(pitched, still.tractor_axle_x, chord_prior=1.5).status is SolverStatus.STANDSTILL


def test_a_standstill_is_recognised_under_tracks_noisier_than_configured(rig: Rig) -> None:
    """Tracks with 2 px of noise against a ``standstill_parallax`` for 1 px (still points' median
    parallax 3.3 px against 1.7 px): at rest the motion fitted to the noise explains none of the
    parallax, and the pair's own noise makes it a standstill, even with a moving prediction (the
    scale bootstrap's 1 m/s); moving 0.6 m with the same noise it is not one."""
    config = RansacConfig(standstill_parallax=STILL_PARALLAX_SIGMAS * 1.0 / 700.0, min_inlier_fraction=0.25)
    noisy = {**DESIGN_2_3, "pixel_noise_px": 2.0, "outlier_fraction": 0.1, "yaw_change": 0.0, "points_per_body": 200}
    for seed in range(6):
        still = make_two_view_problem(np.random.default_rng(60 + seed), rig=rig, **{**noisy, "chord": 0.0})
        assert median_parallax(as_groups(still.groups("tractor"))) > 1.5 * config.standstill_parallax
        for prior in (None, 0.5):
            estimate = estimate_tractor_motion(still.groups("tractor"), still.tractor_axle_x, config, chord_prior=prior)
            assert estimate.status is SolverStatus.STANDSTILL, (seed, prior)
        moving = make_two_view_problem(np.random.default_rng(70 + seed), rig=rig, **{**noisy, "chord": 0.6})
        estimate = estimate_tractor_motion(moving.groups("tractor"), moving.tractor_axle_x, config, chord_prior=0.5)
        assert estimate.status in (SolverStatus.OK, SolverStatus.SCALE_UNOBSERVABLE), seed
