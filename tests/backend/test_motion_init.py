"""MotionInitializer (DESIGN 2.1): a standstill must be physically possible (issue 16)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ampc_vo.backend.motion_init import MotionInitializer
from ampc_vo.backend.smoother import MotionStatus
from ampc_vo.config import VoConfig
from ampc_vo.geometry import make_pose, rot_z
from ampc_vo.observations import CameraObservations, FrameObservations
from ampc_vo.rig import load_rig
from ampc_vo.solvers import ackermann_motion

RIG = load_rig(Path(__file__).resolve().parents[2] / "configs" / "rigs" / "default.yaml")


def _unit(points_camera: np.ndarray) -> np.ndarray:
    return points_camera / np.linalg.norm(points_camera, axis=1, keepdims=True)


def _pair(yaw_change: float, chord: float, rng: np.random.Generator) -> tuple[FrameObservations, FrameObservations]:
    """Frames 0.1 s apart: the front camera sees the world moved by the Ackermann motion, the left
    camera mostly sees something rigidly attached to the tractor (bearings unchanged)."""
    T_i_j = make_pose(*ackermann_motion(yaw_change, chord, RIG.axle_x("tractor")))
    front = RIG.camera("front")
    in_front = np.column_stack([rng.uniform(-8, 8, 60), rng.uniform(-3, 1, 60), rng.uniform(8, 30, 60)])  # camera frame at i
    T_body_front = front.T_body_camera
    points_body_i = in_front @ T_body_front[:3, :3].T + T_body_front[:3, 3]
    T_front_j = np.linalg.inv(T_i_j @ T_body_front)
    in_front_j = points_body_i @ T_front_j[:3, :3].T + T_front_j[:3, 3]
    attached = np.column_stack([rng.uniform(-2, 2, 200), rng.uniform(-1, 1, 200), rng.uniform(3, 8, 200)])  # left camera frame
    first, second = {}, {}
    for name, before, after in (("front", in_front, in_front_j), ("left", attached, attached)):
        ids = np.arange(len(before))
        first[name] = CameraObservations(name, ids, np.zeros((len(ids), 2)), _unit(before))
        second[name] = CameraObservations(name, ids, np.zeros((len(ids), 2)), _unit(after))
    return FrameObservations(0, 0.0, first), FrameObservations(1, 0.1, second)


def test_parallax_standstill_is_overruled_when_the_truck_cannot_have_stopped() -> None:
    """Turning at 5 m/s, the mirror's tracks on the tractor-fixed box have no parallax and make the
    median parallax say 'standstill'; braking from 5 m/s to rest within 0.1 s is impossible, so the
    motion is estimated (the box tracks are outliers of it)."""
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(np.radians(2.0), 0.5, np.random.default_rng(4))
    predicted = make_pose(*ackermann_motion(np.radians(1.5), 0.5, RIG.axle_x("tractor")))
    assert initializer.tractor(first, second, predicted).status is MotionStatus.STANDSTILL  # speed unknown: no gate
    tractor = initializer.tractor(first, second, predicted, speed_before=5.0)
    assert tractor.status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE)
    yaw = np.arctan2(tractor.T_i_j[1, 0], tractor.T_i_j[0, 0])
    assert np.degrees(yaw) == pytest.approx(2.0, abs=0.1)


def test_standstill_stays_when_the_truck_was_slow_enough_to_stop() -> None:
    """The same tracks after creeping at 0.3 m/s (it can stop within the pair): a standstill."""
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(0.0, 0.0, np.random.default_rng(4))
    predicted = make_pose(*ackermann_motion(0.0, 0.03, RIG.axle_x("tractor")))
    assert initializer.tractor(first, second, predicted, speed_before=0.3).status is MotionStatus.STANDSTILL
    assert initializer.tractor(first, second, predicted, speed_before=-0.5).status is MotionStatus.STANDSTILL  # reversing slowly
    assert initializer.tractor(first, second, predicted, speed_before=5.0).status is not MotionStatus.STANDSTILL  # no stop from 5 m/s in 0.1 s


SEMITRAILER = load_rig(Path(__file__).resolve().parents[2] / "configs" / "rigs" / "semitrailer.yaml")
TRAILER_BOX = {"front_x": 0.8, "rear_x": -12.4, "half_width": 1.25, "bottom_z": 0.0, "top_z": 2.7}


def _with_box(rig):
    import dataclasses

    from ampc_vo.rig import BodyBox

    trailer = dataclasses.replace(rig.bodies["trailer"], box=BodyBox(**TRAILER_BOX))
    return dataclasses.replace(rig, bodies={**rig.bodies, "trailer": trailer})


def _observe(rig, body: str, points_i: np.ndarray, points_j: np.ndarray, noise_px: float = 0.0,
             rng: np.random.Generator | None = None, limit: int | None = None) -> tuple[dict, dict]:
    """``body``'s cameras' observations of points given in that body's frame at views i and j (at
    most ``limit`` per camera, with ``noise_px`` of Gaussian pixel noise drawn from ``rng``)."""
    first, second = {}, {}
    for camera in rig.cameras_on(body):
        T_camera_body = np.linalg.inv(camera.T_body_camera)
        pixels_i, seen_i = camera.project(points_i @ T_camera_body[:3, :3].T + T_camera_body[:3, 3])
        pixels_j, seen_j = camera.project(points_j @ T_camera_body[:3, :3].T + T_camera_body[:3, 3])
        seen = np.flatnonzero(seen_i & seen_j)[:limit]
        observed_i, observed_j = pixels_i[seen], pixels_j[seen]
        if noise_px > 0.0:
            observed_i = observed_i + rng.normal(0.0, noise_px, observed_i.shape)
            observed_j = observed_j + rng.normal(0.0, noise_px, observed_j.shape)
        first[camera.name] = CameraObservations(camera.name, seen, observed_i, camera.unproject(observed_i))
        second[camera.name] = CameraObservations(camera.name, seen, observed_j, camera.unproject(observed_j))
    return first, second


def test_tracks_on_the_trailer_box_are_left_out_of_the_tractor_motion() -> None:
    """Reversing a jack-knifed semitrailer (hitch -40 deg), its box fills the mirror cameras and
    moves with the truck, turning only by the hitch's change: the tractor RANSAC took that cluster
    for the truck's motion. With the trailer's box in rig.yaml (``bodies.trailer.box``) the tracks
    whose rays meet it at the window's hitch angle are left out, and the reversing motion (1.2 m
    back, 5 deg yaw) is found."""
    rng = np.random.default_rng(11)
    axle_x = SEMITRAILER.axle_x("tractor")
    T_i_j = make_pose(*ackermann_motion(np.radians(-5.0), -1.2, axle_x))
    theta_i, theta_j = np.radians(-40.0), np.radians(-41.0)
    # static world: walls and ground around the truck; the trailer's box: points on its faces
    world = np.column_stack([rng.uniform(-30, 30, 400), rng.choice([-1.0, 1.0], 400) * rng.uniform(6, 20, 400), rng.uniform(-1.2, 4.0, 400)])
    box = np.column_stack([rng.uniform(-12.4, 0.8, 2500), rng.choice([-1.25, 1.25], 2500), rng.uniform(0.0, 2.7, 2500)])
    world_j = (world - T_i_j[:3, 3]) @ T_i_j[:3, :3]
    box_i, box_j = box @ rot_z(theta_i).T, box @ rot_z(theta_j).T
    first, second = _observe(SEMITRAILER, "tractor", np.concatenate([world, box_i]), np.concatenate([world_j, box_j]))
    frames = FrameObservations(0, 0.0, first), FrameObservations(1, 1.0, second)
    on_box = sum(int(np.count_nonzero(obs.track_ids >= len(world))) for obs in first.values())
    assert on_box > sum(len(obs) for obs in first.values()) / 2  # the box is most of what the tractor cameras see
    predicted = make_pose(*ackermann_motion(np.radians(-4.0), -1.0, axle_x))
    results = {}
    for name, rig in (("box", _with_box(SEMITRAILER)), ("no box", SEMITRAILER)):
        tractor = MotionInitializer(rig, VoConfig()).tractor(*frames, predicted, speed_before=1.2, hitch=theta_i)
        results[name] = (tractor.status, np.degrees(tractor.yaw_change), tractor.T_i_j[0, 3])
    status, yaw, forward = results["box"]
    assert status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE), results
    assert yaw == pytest.approx(-5.0, abs=0.2) and forward < -0.5, results
    status, yaw, forward = results["no box"]
    assert status is MotionStatus.STANDSTILL or abs(yaw + 5.0) > 1.0, results  # what the box's tracks did without it


def test_rebuilding_a_motion_with_another_chord_keeps_its_attitude_change() -> None:
    """The chord fusions rebuild the Ackermann motion from (yaw, chord): a pitch and roll change
    found over a bump (ampc_vo.solvers.attitude) must survive it."""
    from ampc_vo.backend.motion_init import _ackermann_like
    from ampc_vo.solvers.attitude import attitude_motion

    pitched = make_pose(*attitude_motion(0.03, 1.8, np.radians(1.0), np.radians(-0.4), -0.3))
    rebuilt = _ackermann_like(pitched, 0.03, 2.2, -0.3)
    np.testing.assert_allclose(rebuilt[:3, :3], pitched[:3, :3], atol=1e-12)
    np.testing.assert_allclose(rebuilt[:3, 3], make_pose(*attitude_motion(0.03, 2.2, 0.0, 0.0, -0.3))[:3, 3], atol=1e-12)
    np.testing.assert_allclose(_ackermann_like(None, 0.03, 2.2, -0.3), make_pose(*attitude_motion(0.03, 2.2, 0.0, 0.0, -0.3)), atol=1e-12)


@pytest.mark.parametrize("chord, kept", [(0.155, False), (2.4, True), (6.0, False), (2.2, True), (1.5, True), (4.4, True)])
def test_a_ground_chord_the_truck_cannot_have_driven_is_dropped(monkeypatch, chord, kept) -> None:
    """At an estimated 24 m/s a pair of 0.1 s covers 2.4 m, give or take 8 m/s^2 of braking or
    acceleration (2.36-2.44 m), a factor 2 for the estimated speed's own error, and 3 sigma: road
    points on a vehicle driving alongside (the realistic motorway: 0.155 +- 0.08 m, which collapsed
    the window's scale) or a chord far too long are dropped, with a log line; plausible ones are
    kept. Without the speed before (a start) nothing is dropped."""
    from ampc_vo.scale.ground import GroundChord, GroundScaleStatus

    monkeypatch.setattr("ampc_vo.backend.motion_init.ground_plane_chord",
                        lambda *args, **kwargs: GroundChord(GroundScaleStatus.OK, chord, 0.08, (np.ones(9, bool),), 9))
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(np.radians(0.3), 2.4, np.random.default_rng(5))
    predicted = make_pose(*ackermann_motion(np.radians(0.3), 2.4, RIG.axle_x("tractor")))
    tractor = initializer.tractor(first, second, predicted, speed_before=24.0)
    init = initializer.keyframe(first, second, tractor, None, speed_before=24.0)
    assert (init.scale_chord is not None) is kept
    if kept:
        assert init.scale_chord[0] == pytest.approx(chord)
    assert initializer.keyframe(first, second, tractor, None).scale_chord is not None


@pytest.mark.parametrize("chord, unreachable", [(0.3, True), (2.85, False), (2.7, False)])
def test_a_two_point_chord_the_truck_cannot_have_driven_is_not_a_measurement(monkeypatch, chord, unreachable) -> None:
    """At 29 m/s (2.9 m per 0.1 s frame) the 2-point solver near straight returned 'ok' chords of
    0.2-1.4 m with small formal sigmas on the realistic fast motorway's images: the keyframe policy
    read a slow truck, left keyframes out and 17 m gaps between them. A chord the truck cannot have
    driven (:meth:`MotionInitializer._reachable`) is taken as unmeasured: scale unobservable, the
    prediction's chord on the estimate's yaw change. A plausible one stays a measurement."""
    import dataclasses

    import ampc_vo.backend.motion_init as motion_init
    from ampc_vo.solvers import TractorMotionEstimate

    real = motion_init.estimate_tractor_motion

    def spurious(*args, **kwargs):
        estimate = real(*args, **kwargs)
        axle_x = RIG.axle_x("tractor")
        return dataclasses.replace(estimate, status=motion_init.SolverStatus.OK, chord=chord, chord_sigma=0.05,
                                   T_i_j=make_pose(*ackermann_motion(estimate.yaw_change, chord, axle_x)))

    monkeypatch.setattr(motion_init, "estimate_tractor_motion", spurious)
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    first, second = _pair(np.radians(0.1), 2.9, np.random.default_rng(6))
    predicted = make_pose(*ackermann_motion(np.radians(0.1), 2.85, RIG.axle_x("tractor")))
    tractor = initializer.tractor(first, second, predicted, prediction_sigma=0.8, speed_before=28.5)
    assert isinstance(tractor.estimate, TractorMotionEstimate)
    if unreachable:
        assert tractor.status is MotionStatus.SCALE_UNOBSERVABLE and tractor.chord == pytest.approx(2.85, abs=0.01)
    else:
        assert tractor.status is MotionStatus.OK and abs(tractor.chord - 2.85) < 0.2
    assert initializer.tractor(first, second, predicted, prediction_sigma=0.8).status is MotionStatus.OK   # speed unknown: no bound


def _at(frames: tuple[FrameObservations, FrameObservations], start: float, end: float) -> tuple[FrameObservations, FrameObservations]:
    """The same observations at other times (a later keyframe pair)."""
    import dataclasses

    first, second = frames
    return dataclasses.replace(first, timestamp=start), dataclasses.replace(second, timestamp=end)


def test_a_refused_standstill_is_taken_once_the_truck_could_have_stopped_since() -> None:
    """The parallax says standstill, the speed before (3.2 m/s) says the truck cannot stop within
    0.1 s: refused, and the motion is predicted on at 3.2 m/s. Later pairs still measure that stale
    speed; the truck could have braked to rest within the 0.4 s since the first refusal
    (``ransac.max_deceleration_mps2`` 8), so a pair ending 0.9 s after it is a standstill (the
    realistic stop_and_go drove on at 3.2 m/s for 2 s after its last stop). A pair with parallax
    ends the memory: the next refusal counts from itself."""
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    import dataclasses

    still = _pair(0.0, 0.0, np.random.default_rng(4))
    moving = tuple(dataclasses.replace(frame, cameras={"front": frame.cameras["front"]}) for frame in _pair(np.radians(2.0), 0.5, np.random.default_rng(5)))
    predicted = make_pose(*ackermann_motion(0.0, 0.32, RIG.axle_x("tractor")))
    assert initializer.tractor(*_at(still, 10.0, 10.1), predicted, speed_before=3.2).status is not MotionStatus.STANDSTILL
    assert initializer.tractor(*_at(still, 10.5, 10.6), predicted, speed_before=3.2).status is MotionStatus.STANDSTILL
    assert initializer.tractor(*_at(moving, 11.0, 11.1), predicted, speed_before=3.2).status is not MotionStatus.STANDSTILL
    assert initializer.tractor(*_at(still, 12.0, 12.1), predicted, speed_before=3.2).status is not MotionStatus.STANDSTILL


def test_a_speed_not_measured_for_a_while_lets_the_truck_stop(monkeypatch) -> None:
    """The speed before (3.2 m/s) was last measured 0.5 s before the pair and carried on by the
    prediction since (pairs without a measured chord): braking at ``ransac.max_deceleration_mps2``
    (8) the truck may have come to rest meanwhile, so still tracks are a standstill at once; the
    same speed measured just before the pair refuses it. The ground chord's bounds widen the same
    way: a 0.05 m chord at an unmeasured 3.2 m/s is kept, at a measured one dropped."""
    import dataclasses

    from ampc_vo.scale.ground import GroundChord, GroundScaleStatus

    still = _at(_pair(0.0, 0.0, np.random.default_rng(4)), 10.0, 10.1)
    predicted = make_pose(*ackermann_motion(0.0, 0.32, RIG.axle_x("tractor")))
    fresh = MotionInitializer(RIG, VoConfig(mode="tractor_only")).tractor(*still, predicted, speed_before=3.2, speed_age=0.0)
    assert fresh.status is not MotionStatus.STANDSTILL
    stale = MotionInitializer(RIG, VoConfig(mode="tractor_only")).tractor(*still, predicted, speed_before=3.2, speed_age=0.5)
    assert stale.status is MotionStatus.STANDSTILL
    initializer = MotionInitializer(RIG, VoConfig(mode="tractor_only"))
    assert initializer._speed_bounds(-3.2, 0.25) == pytest.approx((1.2, 5.2))
    assert initializer._speed_bounds(3.2, 1.0) == (0.0, pytest.approx(11.2))
    monkeypatch.setattr("ampc_vo.backend.motion_init.ground_plane_chord",
                        lambda *args, **kwargs: GroundChord(GroundScaleStatus.OK, 0.05, 0.005, (np.ones(9, bool),), 9))
    first, second = (dataclasses.replace(frame, cameras={"front": frame.cameras["front"]}) for frame in _pair(np.radians(2.0), 0.5, np.random.default_rng(5)))
    tractor = initializer.tractor(first, second, predicted, speed_before=3.2)
    assert tractor.status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE)
    assert initializer.keyframe(first, second, tractor, None, speed_before=3.2).scale_chord is None
    assert initializer.keyframe(first, second, tractor, None, speed_before=3.2, speed_age=0.5).scale_chord == pytest.approx((0.05, 0.005))


def _still_and_creeping(rig, creep_m: float, noise_px: float, rng: np.random.Generator) -> tuple[FrameObservations, FrameObservations]:
    """The tractor cameras of ``rig`` see a static world 5-40 m around the truck, which moved
    ``creep_m`` forward between the views, with ``noise_px`` of pixel noise per observation."""
    axle_x = rig.axle_x("tractor")
    world = np.column_stack([rng.uniform(-40, 40, 3000), rng.uniform(-40, 40, 3000), rng.uniform(-1.2, 4.0, 3000)])
    world = world[np.hypot(world[:, 0], world[:, 1]) > 5.0]
    T_i_j = make_pose(*ackermann_motion(0.0, creep_m, axle_x))
    world_j = (world - T_i_j[:3, 3]) @ T_i_j[:3, :3]
    first, second = _observe(rig, "tractor", world, world_j, noise_px, rng, limit=60)
    return FrameObservations(0, 0.0, first), FrameObservations(10, 1.0, second)


def test_still_tracks_on_wide_cameras_are_a_standstill_under_pixel_noise() -> None:
    """The semitrailer rig's cameras (f = 320 px) at rest with 0.8 px of tracking noise: the median
    parallax of still points is noise, 1.0-1.2 px (Rayleigh, 1.665 sigma at the image centre), which a
    fixed 0.003 rad (0.96 px there; the realistic stop_and_go's bearings read 0.8-1.0 px at rest
    with 0.5 px and 10 % outliers) takes for motion; the default threshold is that median under the
    configured ``smoother.pixel_sigma`` (1.665 sigma / focal). The fixed threshold took 7 of 20 pairs
    for motion; the pair's own noise (``ransac._noise_standstill``: the median parallax against the
    noise the correspondences measure) now makes them standstills too. Creeping 0.5 m in the pair (a
    keyframe's second at 0.5 m/s; a median parallax of 2.4 px over a world 5-40 m away) still moves;
    0.3 m (1.7 px) sits at the threshold and 0.1 m (1 px) reads as a standstill against that noise."""
    rng = np.random.default_rng(21)
    predicted = make_pose(*ackermann_motion(0.0, 0.0, SEMITRAILER.axle_x("tractor")))
    from ampc_vo.config import config_from_dict

    fixed = config_from_dict({"mode": "tractor_only", "ransac": {"standstill_parallax_px": 0.96}})
    default = config_from_dict({"mode": "tractor_only"})
    statuses = {"default": [], "fixed": []}
    for _ in range(20):
        frames = _still_and_creeping(SEMITRAILER, 0.0, 0.8, rng)
        for name, config in (("default", default), ("fixed", fixed)):
            statuses[name].append(MotionInitializer(SEMITRAILER, config).tractor(*frames, predicted).status)
    assert all(status is MotionStatus.STANDSTILL for status in statuses["default"]), statuses["default"]
    assert all(status is MotionStatus.STANDSTILL for status in statuses["fixed"]), statuses["fixed"]  # 7 of 20 read as motion without the noise test
    creeping = _still_and_creeping(SEMITRAILER, 0.5, 0.8, rng)
    creep = make_pose(*ackermann_motion(0.0, 0.5, SEMITRAILER.axle_x("tractor")))  # the straight chord is not observable: the prediction's
    for config in (default, fixed):
        assert MotionInitializer(SEMITRAILER, config).tractor(*creeping, creep).status is not MotionStatus.STANDSTILL


def test_the_path_driven_is_the_keyframe_motions_chained_backwards() -> None:
    """The ground plane's own lane behind the axle (``_driven_path``): two 2 m straight keyframe
    motions, then a rest, then a 2 m arc turning left by 10 deg put the axle's earlier positions
    behind it and to its left in the newest body frame, the rest adds nothing, and the oldest
    piece is extended straight to ``scale.ground_lane_length_m`` of path."""
    initializer = MotionInitializer(RIG, VoConfig())
    assert initializer._driven_path() is None
    axle_x = RIG.axle_x("tractor")
    straight = make_pose(*ackermann_motion(0.0, 2.0, axle_x))
    turn = make_pose(*ackermann_motion(np.radians(10.0), 2.0, axle_x))
    for motion in (straight, straight, np.eye(4), turn):
        initializer._driven_motions.append(motion)
    path = initializer._driven_path()
    assert path.shape == (5, 2) and np.allclose(path[0], 0.0)
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert np.allclose(steps[:3], 2.0, atol=1e-6)
    assert np.sum(steps) == pytest.approx(VoConfig().scale.ground_lane_length_m)
    assert np.all(path[1:, 0] < 0.0) and np.all(path[1:, 1] > 0.0)  # behind, and to the left


def test_a_chord_counts_as_measured_only_when_something_measured_it() -> None:
    """The speed's age (``OdometryPipeline._speed_age``) restarts at a keyframe whose chord was
    measured: by the 2-point or joint RANSAC (ok), a standstill, the ground plane or stereo
    (``scale_chord``) or the wheels; a scale-unobservable pair that took the prediction's chord did
    not measure it."""
    from ampc_vo.backend.pipeline import _chord_measured
    from ampc_vo.backend.smoother import MotionInit

    assert _chord_measured(MotionInit(np.eye(4), MotionStatus.OK))
    assert _chord_measured(MotionInit(np.eye(4), MotionStatus.STANDSTILL))
    assert not _chord_measured(MotionInit(np.eye(4), MotionStatus.SCALE_UNOBSERVABLE))
    assert not _chord_measured(MotionInit(np.eye(4), MotionStatus.TOO_FEW_TRACKS))
    assert _chord_measured(MotionInit(np.eye(4), MotionStatus.SCALE_UNOBSERVABLE, scale_chord=(1.2, 0.02)))
    assert _chord_measured(MotionInit(np.eye(4), MotionStatus.TOO_FEW_TRACKS, wheel_chord=1.2))


def _drive_off(monkeypatch, ground_chord: tuple[float, float], predicted_chord: float = 0.014):
    """A straight pair whose tracks leave the chord unobservable (the prediction's ``predicted_chord``
    stands in), the ground plane measuring ``ground_chord`` and the trailer's RANSAC finding no
    consensus; returns the initializer, the frames, the tractor motion and the tractor chords the
    trailer's RANSAC was given."""
    from ampc_vo.backend.motion_init import TractorMotion
    from ampc_vo.scale.ground import GroundChord, GroundScaleStatus
    from ampc_vo.solvers import HitchEstimate, TractorMotionEstimate
    from ampc_vo.solvers.status import SolverStatus

    monkeypatch.setattr("ampc_vo.backend.motion_init.ground_plane_chord",
                        lambda *args, **kwargs: GroundChord(GroundScaleStatus.OK, *ground_chord, (np.ones(9, bool),), 9))
    seen = []

    def hitch_angles(pairs, tractor_motion, *args, **kwargs):
        seen.append(float(np.linalg.norm(tractor_motion[1][:2])))
        return HitchEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=[np.zeros(len(pair), bool) for pair in pairs])

    monkeypatch.setattr("ampc_vo.backend.motion_init.estimate_hitch_angles", hitch_angles)
    rng = np.random.default_rng(6)
    first, second = _pair(0.0, ground_chord[0], rng)
    rear = [_unit(np.column_stack([rng.uniform(-5, 5, 40), rng.uniform(-2, 1, 40), rng.uniform(10, 40, 40)])) for _ in range(2)]
    for frame, bearings in zip((first, second), rear):
        frame.cameras["rear"] = CameraObservations("rear", np.arange(40), np.zeros((40, 2)), bearings)
    T_predicted = make_pose(np.eye(3), np.array([predicted_chord, 0.0, 0.0]))
    all_tracks = [np.ones(len(first.cameras[name]), bool) for name in ("front", "left")]
    unmeasured = TractorMotionEstimate(SolverStatus.SCALE_UNOBSERVABLE, 0.0, predicted_chord, T_predicted, all_tracks, 260, yaw_sigma=1e-4)
    tractor = TractorMotion(T_predicted, MotionStatus.SCALE_UNOBSERVABLE, unmeasured, 260)
    return MotionInitializer(RIG, VoConfig()), first, second, tractor, seen


def test_the_trailer_ransac_gets_the_ground_planes_chord_where_the_tracks_fixed_none(monkeypatch) -> None:
    """A drive-off on a straight road: the tracks leave the chord unobservable and the prediction's
    (1.4 cm, from the standstill before) stands in. The trailer's RANSAC must see the chord the
    ground plane measured (0.65 m), not the prediction's, which it read as a standstill: the trailer
    then had no estimate and its cameras no RANSAC verdict (a 0.65 m drive-off came out reversed)."""
    initializer, first, second, tractor, seen = _drive_off(monkeypatch, (0.65, 0.03))
    init = initializer.keyframe(first, second, tractor, 0.0)
    assert seen and seen[0] == pytest.approx(0.65, abs=0.01)
    assert init.scale_chord == pytest.approx((0.65, 0.03)) and np.linalg.norm(init.T_tractor[:2, 3]) == pytest.approx(0.65, abs=0.01)


def test_a_tractor_without_tracks_is_carried_by_the_trailers_cameras() -> None:
    """Reversing from rest into a turn (hitch -20 deg), the tractor's cameras see almost nothing (5
    tracks: a cab camera facing an empty yard, the mirrors gone) and its motion is the prediction,
    at rest. The trailer's cameras measure the trailer's own motion (0.9 m back, 1.5 deg); the
    tractor's initial motion is then the bodies turning together about the king-pin (the hitch held),
    not the prediction's standstill: with that, the smoother dropped the trailer's epipolar factors too
    and a reversing truck's hitch went 6 deg off at a sigma of 1.3 deg."""
    rng = np.random.default_rng(12)
    theta = np.radians(-20.0)
    T_trailer = make_pose(*ackermann_motion(np.radians(1.5), -0.9, SEMITRAILER.axle_x("trailer")))
    world = np.column_stack([rng.uniform(-45, 15, 1500), rng.choice([-1.0, 1.0], 1500) * rng.uniform(4, 25, 1500), rng.uniform(-1.2, 5.0, 1500)])
    world_j = (world - T_trailer[:3, 3]) @ T_trailer[:3, :3]
    first, second = _observe(SEMITRAILER, "trailer", world, world_j, limit=150)
    H = make_pose(rot_z(theta), np.zeros(3))
    tractor_points = world @ H[:3, :3].T  # the same world in the tractor frame (body origins at the king-pin)
    T_tractor_true = H @ T_trailer @ np.linalg.inv(H)  # hitch held: what the carried initial motion should be
    tractor_first, tractor_second = _observe(SEMITRAILER, "tractor", tractor_points, (tractor_points - T_tractor_true[:3, 3]) @ T_tractor_true[:3, :3], limit=5)
    tractor_first, tractor_second = ({"cab_front": observations["cab_front"]} for observations in (tractor_first, tractor_second))
    frames = FrameObservations(0, 0.0, {**first, **tractor_first}), FrameObservations(1, 1.0, {**second, **tractor_second})
    assert sum(len(first[name]) for name in first) > 100 and sum(len(obs) for obs in tractor_first.values()) < VoConfig().keyframes.min_tracks
    initializer = MotionInitializer(SEMITRAILER, VoConfig())
    tractor = initializer.tractor(*frames, np.eye(4), speed_before=0.0, hitch=theta)
    assert tractor.status is MotionStatus.TOO_FEW_TRACKS
    init = initializer.keyframe(*frames, tractor, theta)
    assert init.tractor_status is MotionStatus.TOO_FEW_TRACKS  # not a measurement of the tractor
    assert init.T_trailer is not None
    assert np.degrees(np.arctan2(init.T_trailer[1, 0], init.T_trailer[0, 0])) == pytest.approx(1.5, abs=0.05)
    direction = init.T_trailer[:2, 3] / np.linalg.norm(init.T_trailer[:2, 3])
    assert direction == pytest.approx(T_trailer[:2, 3] / np.linalg.norm(T_trailer[:2, 3]), abs=2e-3)  # backwards, along the measured line
    assert np.degrees(np.arctan2(init.T_tractor[1, 0], init.T_tractor[0, 0])) == pytest.approx(1.5, abs=0.05)
    assert init.T_tractor[:2, 3] / np.linalg.norm(init.T_tractor[:2, 3]) == pytest.approx(T_tractor_true[:2, 3] / np.linalg.norm(T_tractor_true[:2, 3]), abs=2e-3)
    assert np.linalg.norm(init.T_tractor[:2, 3]) >= 2.0 * VoConfig().keyframes.standstill_distance_m
    assert sum(len(ids) for name, ids in init.inlier_tracks.items() if name.startswith("trailer")) > 100
    # a moving prediction (the truck was driving) is kept: it carries the hitch's rate on
    moving = make_pose(*ackermann_motion(np.radians(3.0), -1.0, SEMITRAILER.axle_x("tractor")))
    kept = MotionInitializer(SEMITRAILER, VoConfig()).keyframe(*frames, dataclasses.replace(tractor, T_i_j=moving), theta)
    assert kept.T_trailer is None and kept.T_tractor == pytest.approx(moving)
