"""Initial relative motion between two keyframes from the minimal-solver RANSAC estimators.

Per keyframe pair (DESIGN section 4): tractor RANSAC with the 2-point Ackermann solver (DESIGN
2.1) on the tractor cameras' shared tracks, then the trailer RANSAC with the 1-point solver
(DESIGN 2.2) given the tractor motion. In mode ``separate`` the trailer's own motion comes from
the same 2-point solver applied to the trailer cameras and the trailer axle (a trailer is a rigid
body with one rigid axle as well). Solver statuses are mapped to :class:`MotionStatus`; when a
motion cannot be estimated the caller's constant-velocity prediction is used. With
``scale.stereo_chord`` (a rig with an overlapping camera pair, KITTI) the tractor's yaw change and
metric chord come from stereo points first (:func:`ampc_vo.scale.stereo.stereo_motion`, seeded
by the prediction; the 2-point RANSAC only when that fails), and the chord becomes the keyframe's
``scale_chord``.
"""
from __future__ import annotations

import collections
import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from ampc_vo.config import VoConfig
from ampc_vo.epipolar import gec_sampson
from ampc_vo.geometry import hitch_transform, invert_pose, make_pose, rays_hit_box, rot_z, yaw_of
from ampc_vo.scale.ground import GroundScaleOptions, axle_displacement, ground_plane_chord
from ampc_vo.observations import FrameObservations, match_tracks
from ampc_vo.rig import BodyBox, Camera, Rig
from ampc_vo.backend.smoother import MotionInit, MotionStatus
from ampc_vo.scale.stereo import StereoMotion, StereoScaleOptions, stereo_motion
from ampc_vo.solvers import RansacConfig as SolverRansacConfig
from ampc_vo.solvers.estimates import STILL_PARALLAX_SIGMAS, as_groups, median_parallax
from ampc_vo.solvers import SolverStatus, TractorMotionEstimate, ackermann_motion, estimate_hitch_angles, estimate_tractor_motion, refine_joint

logger = logging.getLogger(__name__)

# factor by which a measured chord may exceed, or fall short of, what the last keyframes' estimated
# speed allows (MotionInitializer._reachable)
_SPEED_SLACK = 2.0
# yaw-change uncertainty given to the ground-plane chord: floor of the RANSAC's sigma, and the value
# used when it has none (radians)
_MIN_YAW_SIGMA = float(np.radians(0.01))
_DEFAULT_YAW_SIGMA = float(np.radians(0.1))
# the trailer's box in the tractor's cameras (on_trailer_box): grown by this (m), at the window's
# hitch angle +- this (radians; its error between keyframes), or around 0 +- the other before any
_BOX_MARGIN_M = 0.05
# keyframe motions kept for the path driven behind the axle (the ground plane's own lane)
_DRIVEN_MOTIONS = 64
_HITCH_MARGIN = float(np.radians(2.0))
_UNKNOWN_HITCH_MARGIN = float(np.radians(10.0))
# yaw change searched for the stereo motion of a pair without a predicted motion (a sequence that starts
# at speed, perhaps in a turn: a road vehicle turns at up to ~1 rad/s, 10 deg in 0.17 s; stereo_motion)
_STEREO_YAW_SEARCH = float(np.radians(10.0))


@dataclass(frozen=True)
class CameraPairs:
    """Shared tracks of one camera between views i and j: camera-frame and body-frame bearings."""

    camera: Camera
    track_ids: np.ndarray
    bearings_i: np.ndarray
    bearings_j: np.ndarray
    body_bearings_i: np.ndarray
    body_bearings_j: np.ndarray
    times_i: np.ndarray | None = None  # capture time of each observation (s): the camera's image time + its row's readout
    times_j: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.track_ids.shape[0])

    def as_group(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(body_bearings_i, body_bearings_j, center)``, the group the solvers take."""
        return self.body_bearings_i, self.body_bearings_j, self.camera.center

    def subset(self, keep: np.ndarray) -> "CameraPairs":
        """The correspondences where ``keep`` (N,) is true."""
        times = {} if self.times_i is None else {"times_i": self.times_i[keep], "times_j": self.times_j[keep]}
        return CameraPairs(self.camera, self.track_ids[keep], self.bearings_i[keep], self.bearings_j[keep],
                           self.body_bearings_i[keep], self.body_bearings_j[keep], **times)


def on_trailer_box(pair: CameraPairs, box: BodyBox, hitch_angles: np.ndarray, margin: float) -> np.ndarray:
    """Mask (N,) of a tractor camera's correspondences whose ray, in either view, meets the
    trailer's ``box`` (grown by ``margin`` metres) at any of ``hitch_angles`` (radians): the trailer
    seen in a mirror moves with the truck, not with the world (DESIGN 2.3). The hitch is the
    tractor frame's origin and ``R_tractor_trailer = Rz(theta)`` (DESIGN 1)."""
    lower, upper = box.lower() - margin, box.upper() + margin
    hits = np.zeros(len(pair), bool)
    for theta in np.atleast_1d(hitch_angles):
        R_trailer_tractor = rot_z(-float(theta))
        origin = R_trailer_tractor @ pair.camera.center
        for bearings in (pair.body_bearings_i, pair.body_bearings_j):
            hits |= rays_hit_box(origin, bearings @ R_trailer_tractor.T, lower, upper)
    return hits


def camera_pairs(rig: Rig, body: str, first: FrameObservations, second: FrameObservations) -> list[CameraPairs]:
    """Shared tracks of every camera on ``body`` between two frames (cameras without any are skipped)."""
    pairs = []
    for camera in rig.cameras_on(body):
        observations_i = first.cameras.get(camera.name)
        observations_j = second.cameras.get(camera.name)
        if observations_i is None or observations_j is None or len(observations_i) == 0 or len(observations_j) == 0:
            continue
        index_i, index_j = match_tracks(observations_i, observations_j)
        if index_i.size == 0:
            continue
        bearings_i, bearings_j = observations_i.bearings[index_i], observations_j.bearings[index_j]
        R_body_camera = camera.R_body_camera
        times_i = first.camera_timestamp(camera.name) + camera.row_times(observations_i.pixels[index_i])
        times_j = second.camera_timestamp(camera.name) + camera.row_times(observations_j.pixels[index_j])
        pairs.append(CameraPairs(camera, observations_i.track_ids[index_i], bearings_i, bearings_j, bearings_i @ R_body_camera.T, bearings_j @ R_body_camera.T,
                                 times_i, times_j))
    return pairs


def _parallax_summary(pairs: list[CameraPairs]) -> str:
    """Per camera: shared tracks and their median parallax in pixels (for the log)."""
    return ", ".join(f"{pair.camera.name} {len(pair)} tracks {median_parallax(as_groups([pair])) * pair.camera.fx:.1f} px" for pair in pairs)


def _solver_config(config: VoConfig, cameras: list[Camera]) -> SolverRansacConfig:
    """The solvers' RANSAC options from the VO config: the pixel threshold over the mean focal."""
    focal = float(np.mean([0.5 * (camera.fx + camera.fy) for camera in cameras])) if cameras else 500.0
    # null: the median parallax of still points under the configured pixel noise
    standstill_px = config.ransac.standstill_parallax_px
    if standstill_px is None:
        standstill_px = STILL_PARALLAX_SIGMAS * config.smoother.pixel_sigma
    return SolverRansacConfig(
        standstill_parallax=standstill_px / focal,
        sampson_threshold=config.ransac.threshold_px / focal,
        confidence=config.ransac.confidence,
        max_iterations=config.ransac.max_iterations,
        min_inliers=config.ransac.min_inliers,
        min_inlier_fraction=config.ransac.min_inlier_fraction,
        max_attitude_change=float(np.radians(config.ransac.max_attitude_change_deg)),
        attitude_fraction=config.ransac.attitude_fraction,
        min_chord=config.keyframes.standstill_distance_m,
        chord_direction_sigma=np.radians(config.ransac.model_direction_sigma_deg),
        seed=config.ransac.seed,
    )


def _status(solver_status: SolverStatus) -> MotionStatus:
    if solver_status is SolverStatus.OK:
        return MotionStatus.OK
    if solver_status is SolverStatus.SCALE_UNOBSERVABLE:
        return MotionStatus.SCALE_UNOBSERVABLE
    if solver_status is SolverStatus.STANDSTILL:
        return MotionStatus.STANDSTILL
    return MotionStatus.TOO_FEW_TRACKS


def _inlier_tracks(pairs: list[CameraPairs], inlier_masks: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Track ids RANSAC kept, per camera (the observations the smoother may use)."""
    if len(inlier_masks) != len(pairs):
        return {}
    return {pair.camera.name: pair.track_ids[np.asarray(mask, dtype=bool)] for pair, mask in zip(pairs, inlier_masks) if len(mask) == len(pair)}


def _with_full_masks(estimate: TractorMotionEstimate, left_out: list[np.ndarray]) -> TractorMotionEstimate:
    """``estimate`` of the correspondences not ``left_out`` (per camera) with its inlier masks over
    all of them (the left-out ones are no inliers)."""
    if not any(mask.any() for mask in left_out) or len(estimate.inlier_masks) != len(left_out):
        return estimate
    full = []
    for mask, inliers in zip(left_out, estimate.inlier_masks):
        expanded = np.zeros(mask.shape[0], bool)
        expanded[~mask] = inliers
        full.append(expanded)
    return dataclasses.replace(estimate, inlier_masks=full)


def _ackermann_like(T_like: np.ndarray | None, yaw_change: float, chord: float, axle_x: float) -> np.ndarray:
    """The Ackermann motion of ``(yaw_change, chord)`` (DESIGN 2 (NH)) with the attitude change
    (pitch, roll) of ``T_like`` kept: ``R = Rz(phi) Rz(yaw of T_like)^T R_like``."""
    rotation, translation = ackermann_motion(yaw_change, chord, axle_x)
    if T_like is not None:
        rotation = rotation @ rot_z(-yaw_of(T_like)) @ T_like[:3, :3]
    return make_pose(rotation, translation)


def _chord_of(T_i_j: np.ndarray, axle_x: float) -> float:
    """Signed chord of the axle midpoint for an Ackermann motion (DESIGN 2 (NH))."""
    displacement = axle_displacement(T_i_j, axle_x)
    yaw = float(np.arctan2(T_i_j[1, 0], T_i_j[0, 0]))
    return float(np.dot(displacement[:2], [np.cos(0.5 * yaw), np.sin(0.5 * yaw)]))


def straight_motion(chord: float) -> np.ndarray:
    """A straight motion of ``chord`` metres along x (a prediction when nothing better is known)."""
    return make_pose(np.eye(3), np.array([chord, 0.0, 0.0]))


@dataclass(frozen=True)
class TractorMotion:
    """Tractor motion of a frame relative to the last keyframe: what keyframe selection needs."""

    T_i_j: np.ndarray
    status: MotionStatus
    estimate: TractorMotionEstimate
    shared_tracks: int
    scale_chord: tuple[float, float] | None = None  # measured axle chord (stereo_scale): (chord m, sigma m)

    @property
    def chord(self) -> float:
        return float(np.linalg.norm(self.T_i_j[:2, 3]))

    @property
    def yaw_change(self) -> float:
        return float(np.arctan2(self.T_i_j[1, 0], self.T_i_j[0, 0]))


def _least_distance(speed: float, dt: float, deceleration: float) -> float:
    """The least distance (m) a truck at ``speed`` (m/s) covers in ``dt`` seconds braking at
    ``deceleration`` (m/s^2): ``min(v dt - a dt^2 / 2, v^2 / (2 a))`` (it may come to rest)."""
    return min(speed * dt - 0.5 * deceleration * dt**2, speed**2 / (2.0 * deceleration))


class MotionInitializer:
    """Runs the RANSAC estimators between a keyframe and a later frame (module docstring)."""

    def __init__(self, rig: Rig, config: VoConfig) -> None:
        self.rig = rig
        self.config = config
        self._tractor_config = _solver_config(config, rig.cameras_on("tractor"))
        self._trailer_config = _solver_config(config, rig.cameras_on("trailer")) if rig.has_trailer else None
        self._rng = np.random.default_rng(config.ransac.seed)
        # (time, speed m/s) where the parallax first said standstill and the speed before forbade it
        self._standstill_refused: tuple[float, float] | None = None
        # the tractor motions T_prev_k of the last keyframes, newest last: the path driven (_driven_path)
        self._driven_motions: collections.deque[np.ndarray] = collections.deque(maxlen=_DRIVEN_MOTIONS)
        self.use_trailer = rig.has_trailer and config.mode != "tractor_only"
        self._ground_options = GroundScaleOptions(
            ground_z=rig.ground_z, pixel_sigma=config.smoother.pixel_sigma, height_sigma_m=config.scale.ground_height_sigma_m,
            normal_sigma=float(np.radians(config.scale.ground_normal_sigma_deg)), fit_plane=config.scale.ground_plane_fit,
            normal_prior_sigma=float(np.radians(config.scale.ground_normal_prior_sigma_deg)),
            lane_half_width_m=config.scale.ground_lane_half_width_m, lane_length_m=config.scale.ground_lane_length_m)
        self._stereo_options = StereoScaleOptions(pixel_sigma=config.smoother.pixel_sigma, max_depth_m=config.scale.stereo_max_depth_m)

    def tractor(self, first: FrameObservations, second: FrameObservations, predicted: np.ndarray, prediction_sigma: float | None = None,
                speed_before: float | None = None, hitch: float | None = None, speed_age: float = 0.0) -> TractorMotion:
        """Tractor motion ``T_first_second``; ``predicted`` (constant velocity) fills what is unknown:
        the chord in straight driving and everything when there are too few tracks. With
        ``prediction_sigma`` (metres) the RANSAC chord is fused with the predicted one (the 2-point
        chord is weak on gentle curves, DESIGN 2.3; trucks change speed slowly). ``speed_before``
        (m/s, signed, < 0 reversing; measured before the pair; None: unknown): a parallax standstill
        is accepted, and the direction of travel may change, only if the truck could brake from it
        to rest within the pair (``ransac.max_deceleration_mps2``). ``speed_age`` (seconds): how long
        before the pair that speed was last measured (a chord from the tracks, the ground, stereo or
        the wheels); since then it is the prediction's, and the truck may have braked or sped up at
        ``ransac.max_deceleration_mps2`` (:meth:`_speed_bounds`).
        ``hitch`` (radians, the window's; None: unknown): where the trailer's box is in the tractor's
        cameras; tracks on it are left out (rig.yaml ``bodies.trailer.box``)."""
        pairs = camera_pairs(self.rig, "tractor", first, second)
        shared = sum(len(pair) for pair in pairs)
        predicted_chord = float(np.linalg.norm(predicted[:2, 3]))
        if shared >= self.config.keyframes.min_tracks:
            # an overlapping camera pair (scale.stereo_chord) gives metric yaw and chord directly from
            # the constant-velocity guess; the 2-point RANSAC (about 2/3 of the per-frame time) is skipped
            stereo = self._stereo_motion(first, second, predicted, guessed=prediction_sigma is None)
            if stereo is not None:
                return TractorMotion(stereo.T_i_j, MotionStatus.OK, self._stereo_estimate(pairs, stereo), shared, stereo.as_scale_chord())
        # signed: the direction of travel of the prediction (used where the pair's chord is not measured)
        chord_prior = (1.0 if predicted[0, 3] >= 0.0 else -1.0) * max(predicted_chord, 1e-3)
        on_trailer = self._on_trailer(pairs, hitch)
        ego_pairs = [pair.subset(~mask) for pair, mask in zip(pairs, on_trailer)]
        dt = second.timestamp - first.timestamp
        # at speed the direction of travel cannot change within the pair (it must brake to rest first)
        speed_bounds = None if speed_before is None else self._speed_bounds(speed_before, speed_age)
        least_speed = None if speed_bounds is None else speed_bounds[0]
        direction = None if least_speed is None or self._can_stop(least_speed, dt) else float(np.sign(speed_before))
        estimate = estimate_tractor_motion(ego_pairs, self.rig.axle_x("tractor"), self._tractor_config, chord_prior=chord_prior, rng=self._rng,
                                           direction=direction)
        if estimate.status is not SolverStatus.STANDSTILL:
            self._standstill_refused = None
        elif least_speed is not None and not self._may_rest(first.timestamp, second.timestamp, least_speed):
            since, speed = self._standstill_refused
            logger.info("frames %d-%d: parallax says standstill, but the truck cannot stop from %.1f m/s within %.2f s "
                        "(ransac.max_deceleration_mps2): motion estimated without the still tracks (median parallax: %s)",
                        first.frame, second.frame, speed, second.timestamp - since, _parallax_summary(pairs))
            estimate = estimate_tractor_motion(ego_pairs, self.rig.axle_x("tractor"), self._tractor_config,
                                               chord_prior=chord_prior, rng=self._rng, moving=True, direction=direction)
        estimate = _with_full_masks(estimate, on_trailer)
        status = _status(estimate.status)
        if shared < self.config.keyframes.min_tracks:
            status = MotionStatus.TOO_FEW_TRACKS
        if status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE) and estimate.T_i_j is not None:
            stereo = self._stereo_motion(first, second, estimate.T_i_j)   # second chance, from the RANSAC motion
            if stereo is not None:
                return TractorMotion(stereo.T_i_j, MotionStatus.OK, estimate, shared, stereo.as_scale_chord())
        if status is MotionStatus.OK and speed_bounds is not None and estimate.T_i_j is not None \
                and not self._reachable(estimate.chord, estimate.chord_sigma, speed_bounds[0], dt, top_speed=speed_bounds[1]):
            # the 2-point chord is weak near straight (DESIGN 2.3) and its formal sigma can be far too
            # small: at 29 m/s on images, 0.2-1.4 m per frame where the truck drove 2.9 m, which left
            # keyframes out (the policy read a slow truck) and 17 m gaps between them; such a chord is
            # not a measurement of the scale, the prediction's stands in
            logger.debug("frames %d-%d: 2-point chord %.2f +- %.2f m unreachable at %.1f-%.1f m/s in %.2f s: scale taken as unobservable",
                         first.frame, second.frame, estimate.chord, estimate.chord_sigma, *speed_bounds, dt)
            status = MotionStatus.SCALE_UNOBSERVABLE
            estimate = dataclasses.replace(estimate, T_i_j=self._with_chord(estimate.T_i_j, predicted_chord))
        if status is MotionStatus.STANDSTILL:
            T_i_j = np.eye(4)
        elif status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE) and estimate.T_i_j is not None:
            T_i_j = estimate.T_i_j
            if status is MotionStatus.OK and prediction_sigma is not None:
                T_i_j = self._fuse_chord(estimate, predicted_chord, prediction_sigma)
        else:
            status = MotionStatus.TOO_FEW_TRACKS
            T_i_j = predicted
        return TractorMotion(T_i_j, status, estimate, shared)

    def _on_trailer(self, pairs: list[CameraPairs], hitch: float | None) -> list[np.ndarray]:
        """Per tractor camera, the mask of its correspondences on the trailer's box (rig.yaml
        ``bodies.trailer.box``; :func:`on_trailer_box`) at the hitch angle ``hitch`` (the window's;
        None: not known yet, a straight start) +- ``_HITCH_MARGIN``, left out of the tractor's
        motion; none without a box."""
        box = self.rig.bodies["trailer"].box if self.rig.has_trailer else None
        if box is None:
            return [np.zeros(len(pair), bool) for pair in pairs]
        centre = 0.0 if hitch is None else float(hitch)
        margin = _UNKNOWN_HITCH_MARGIN if hitch is None else _HITCH_MARGIN
        angles = centre + np.linspace(-margin, margin, 5)
        return [on_trailer_box(pair, box, angles, _BOX_MARGIN_M) for pair in pairs]

    def _may_rest(self, start: float, end: float, speed_before: float) -> bool:
        """Whether a truck whose parallax says standstill over ``[start, end]`` can be at rest: it
        could brake to rest within the pair (:meth:`_can_stop`), or from the speed before the parallax
        first said so and was refused (``speed_before`` then) before the pair began, braking at
        ``ransac.max_deceleration_mps2``. The speed and time of that first refusal are kept
        while the parallax keeps saying standstill, also once it may rest: the speed estimated since
        is the prediction that the refusal itself made (it held 3.2 m/s for 2 s at the end of the
        realistic stop_and_go, a keyframe every 0.5 s each refused anew)."""
        if self._can_stop(speed_before, end - start):
            return True
        if self._standstill_refused is None:
            self._standstill_refused = (start, speed_before)
            return False
        since, speed = self._standstill_refused
        return start - since >= speed / self.config.ransac.max_deceleration_mps2  # at rest before the pair began

    def _speed_bounds(self, speed_before: float, speed_age: float) -> tuple[float, float]:
        """The least and greatest speed (m/s) of a truck whose speed was ``|speed_before|`` when last
        measured, ``speed_age`` seconds ago, braking or accelerating at most
        ``ransac.max_deceleration_mps2`` since (a speed carried on by the constant-velocity prediction
        through pairs without a measured chord is no evidence that the truck did not stop)."""
        change = self.config.ransac.max_deceleration_mps2 * max(float(speed_age), 0.0)
        return max(abs(float(speed_before)) - change, 0.0), abs(float(speed_before)) + change

    def _can_stop(self, speed: float, dt: float) -> bool:
        """Whether a truck at ``speed`` (m/s) can be at rest within a pair of ``dt`` seconds: braking
        at ``ransac.max_deceleration_mps2`` from ``v0`` it covers at least ``min(v0 dt - a dt^2 / 2,
        v0^2 / (2 a))``, which must stay within the standstill distance."""
        if dt <= 0.0:
            return True
        return _least_distance(speed, dt, self.config.ransac.max_deceleration_mps2) <= self.config.keyframes.standstill_distance_m

    def _reachable(self, chord: float, sigma: float, speed: float, dt: float, top_speed: float | None = None) -> bool:
        """Whether a truck at ``speed`` (m/s; at most ``top_speed`` when its speed was not measured
        lately, :meth:`_speed_bounds`) can cover an axle chord of ``chord`` +- ``sigma`` (m) in
        ``dt`` seconds, braking or accelerating at most ``ransac.max_deceleration_mps2``: at least
        ``min(v dt - a dt^2 / 2, v^2 / (2 a))``, at most ``v dt + a dt^2 / 2``, with 3 sigma of slack
        and a factor :data:`_SPEED_SLACK` either way, since ``speed`` is itself an estimate (its
        scale may drift by several %: a tight bound rejected right chords and kept the drift, on the
        realistic motorway's images 229 of 1000 keyframes). It drops gross outliers: road points on a
        vehicle alongside or the trailer (0.155 m where the truck drove 4.8 m)."""
        if dt <= 0.0:
            return True
        rate = self.config.ransac.max_deceleration_mps2
        least = _least_distance(speed, dt, rate) / _SPEED_SLACK
        most = ((speed if top_speed is None else top_speed) * dt + 0.5 * rate * dt**2) * _SPEED_SLACK
        return least - 3.0 * sigma <= abs(chord) <= most + 3.0 * sigma

    def _stereo_motion(self, first: FrameObservations, second: FrameObservations, T_guess: np.ndarray,
                       guessed: bool = False) -> StereoMotion | None:
        """Tractor yaw change and axle chord from stereo points (:func:`ampc_vo.scale.stereo.stereo_motion`)
        when ``scale.stereo_chord`` is on, the measurement succeeds and the tractor moved (the 2-point
        solver's standstill or unobservable scale in straight driving are overruled), else ``None``."""
        if not self.config.scale.stereo_chord:
            return None
        measured = stereo_motion(self.rig, "tractor", first, second, T_guess, self.rig.axle_x("tractor"), self._stereo_options,
                                 yaw_search=_STEREO_YAW_SEARCH if guessed else 0.0)
        if not measured.ok:
            logger.debug("frames %d-%d: no stereo motion (%s)", first.frame, second.frame, measured.status.value)
            return None
        if abs(measured.chord) < self.config.keyframes.standstill_distance_m:
            return None
        return measured

    def _stereo_estimate(self, pairs: list[CameraPairs], stereo: StereoMotion) -> TractorMotionEstimate:
        """The 2-point RANSAC's result type for a stereo motion: per-camera inliers are the shared
        tracks whose Sampson GEC residual under it is below the RANSAC threshold (DESIGN 2.1)."""
        rotation, translation = stereo.T_i_j[:3, :3], stereo.T_i_j[:3, 3]
        threshold = self._tractor_config.sampson_threshold
        masks = [np.abs(gec_sampson(pair.body_bearings_i, pair.body_bearings_j, rotation, translation, pair.camera.center)) < threshold for pair in pairs]
        count = int(sum(int(np.count_nonzero(mask)) for mask in masks))
        return TractorMotionEstimate(SolverStatus.OK, stereo.yaw_change, stereo.chord, stereo.T_i_j, masks, count, chord_sigma=stereo.chord_sigma)

    def _with_chord(self, T_i_j: np.ndarray, chord: float) -> np.ndarray:
        """The Ackermann motion (DESIGN 2 (NH)) of ``T_i_j``'s yaw change and direction with the axle chord ``chord``."""
        direction = 1.0 if _chord_of(T_i_j, self.rig.axle_x("tractor")) >= 0.0 else -1.0
        return _ackermann_like(T_i_j, yaw_of(T_i_j), direction * chord, self.rig.axle_x("tractor"))

    def _fuse_chord(self, estimate: TractorMotionEstimate, predicted_chord: float, prediction_sigma: float) -> np.ndarray:
        """Inverse-variance fusion of the RANSAC chord with the constant-velocity prediction; the yaw
        change is kept and the motion rebuilt with the Ackermann model (DESIGN 2 (NH))."""
        chord_sigma = estimate.chord_sigma if np.isfinite(estimate.chord_sigma) and estimate.chord_sigma > 0 else np.inf
        weight_measured = 0.0 if not np.isfinite(chord_sigma) else 1.0 / chord_sigma**2
        weight_predicted = 1.0 / prediction_sigma**2
        chord = (weight_measured * abs(estimate.chord) + weight_predicted * predicted_chord) / (weight_measured + weight_predicted)
        chord *= np.sign(estimate.chord) if estimate.chord != 0 else 1.0
        return _ackermann_like(estimate.T_i_j, estimate.yaw_change, chord, self.rig.axle_x("tractor"))

    def keyframe(self, first: FrameObservations, second: FrameObservations, tractor: TractorMotion,
                 hitch_prior: float | None, predicted_trailer: np.ndarray | None = None, speed_before: float | None = None,
                 speed_age: float = 0.0) -> MotionInit:
        """The :class:`MotionInit` of a new keyframe given its tractor motion (see :meth:`tractor`);
        ``speed_before`` (m/s, the last keyframes' signed speed, measured ``speed_age`` seconds
        before the pair) bounds the chord a measurement may give (:meth:`_reachable`)."""
        speed_bounds = None if speed_before is None else self._speed_bounds(speed_before, speed_age)
        tractor_pairs = camera_pairs(self.rig, "tractor", first, second)
        inliers = {}
        if tractor.status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE, MotionStatus.STANDSTILL):
            inliers = _inlier_tracks(tractor_pairs, tractor.estimate.inlier_masks)
        if not self.use_trailer:
            return self._driven(self._with_ground_scale(MotionInit(tractor.T_i_j, tractor.status, inlier_tracks=inliers, scale_chord=tractor.scale_chord),
                                                        tractor_pairs, first, second, tractor.estimate.yaw_sigma, speed_bounds))
        hitch_prev = hitch = None
        trailer_status = MotionStatus.TOO_FEW_TRACKS
        ground = None
        if tractor.status is MotionStatus.SCALE_UNOBSERVABLE:
            # the trailer's RANSAC needs the tractor's chord, which the tracks did not measure here: the
            # prediction's stands in for it, and a drive-off's predicted chord (~0 from the standstill
            # before) read as a standstill left the trailer without an estimate and its cameras without
            # a RANSAC verdict; the ground plane's measurement comes first
            ground = self._with_ground_scale(MotionInit(tractor.T_i_j, tractor.status, inlier_tracks=inliers, scale_chord=tractor.scale_chord),
                                             tractor_pairs, first, second, tractor.estimate.yaw_sigma, speed_bounds)
            tractor = dataclasses.replace(tractor, T_i_j=ground.T_tractor)
        trailer_pairs = camera_pairs(self.rig, "trailer", first, second)
        trailer_axle_x = self.rig.axle_x("trailer")
        T_trailer = None
        if tractor.status is MotionStatus.TOO_FEW_TRACKS and self.config.mode in ("full", "no_trailer_constraint"):
            tractor, T_trailer, carried_inliers = self._carried_by_trailer(tractor, trailer_pairs, hitch_prior)
            inliers.update(carried_inliers)
        if tractor.status is MotionStatus.STANDSTILL:
            trailer_status = MotionStatus.STANDSTILL
        elif tractor.status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE) and sum(len(p) for p in trailer_pairs) >= self.config.keyframes.min_tracks:
            estimate = estimate_hitch_angles(
                trailer_pairs, (tractor.yaw_change, tractor.T_i_j[:3, 3]), trailer_axle_x, self._trailer_config,
                prior_hitch_angle=hitch_prior, rng=self._rng,
            )
            if estimate.ok and self.config.mode in ("full", "no_trailer_constraint"):
                # joint refinement over both bodies (DESIGN 2.3: ~3x better with the trailer constraint);
                # the trailer inliers are then re-classified under the refined tractor motion
                # a straight tractor (chord from the prediction) still gets its scale from the trailer
                # when the hitch angle is not zero: refine from the motion actually used
                seed = dataclasses.replace(tractor.estimate, yaw_change=tractor.yaw_change, chord=_chord_of(tractor.T_i_j, self.rig.axle_x("tractor")), T_i_j=tractor.T_i_j)
                joint = refine_joint(
                    tractor_pairs, trailer_pairs, seed, estimate,
                    self.rig.axle_x("tractor"), trailer_axle_x, self._tractor_config, trailer_nonholonomic=self.config.mode == "full",
                )
                refined_chord = _chord_of(joint.T_i_j, self.rig.axle_x("tractor")) if joint.ok and np.all(np.isfinite(joint.T_i_j)) else float("nan")
                if joint.ok and not (abs(seed.chord) > 1e-9 and 0.5 <= refined_chord / seed.chord <= 2.0):
                    # near-straight with a small hitch angle the trailer's scale is as weak as the
                    # tractor's (DESIGN 2.3): a reversed or far-off chord is a spurious minimum
                    logger.debug("frame %d: joint refinement chord %.2f m against %.2f m: kept the tractor estimate", second.frame, refined_chord, seed.chord)
                elif joint.ok:
                    status = MotionStatus.OK if tractor.status is MotionStatus.SCALE_UNOBSERVABLE else tractor.status
                    tractor = TractorMotion(joint.T_i_j, status, tractor.estimate, tractor.shared_tracks, tractor.scale_chord)
                    estimate = estimate_hitch_angles(
                        trailer_pairs, (tractor.yaw_change, tractor.T_i_j[:3, 3]), trailer_axle_x, self._trailer_config,
                        prior_hitch_angle=hitch_prior, rng=self._rng,
                    )
            if estimate.ok:
                hitch_prev, hitch, trailer_status = estimate.hitch_angle_i, estimate.hitch_angle_j, MotionStatus.OK
                inliers.update(_inlier_tracks(trailer_pairs, estimate.inlier_masks))
        if self.config.mode == "separate":
            predicted = predicted_trailer if predicted_trailer is not None else straight_motion(tractor.chord)
            if tractor.status is MotionStatus.STANDSTILL:
                T_trailer, trailer_status = np.eye(4), MotionStatus.STANDSTILL
            else:
                chord_prior = max(float(np.linalg.norm(predicted[:2, 3])), 1e-3)
                own = estimate_tractor_motion(trailer_pairs, trailer_axle_x, self._trailer_config, chord_prior=chord_prior, rng=self._rng)
                trailer_status = _status(own.status)
                if sum(len(p) for p in trailer_pairs) < self.config.keyframes.min_tracks:
                    trailer_status = MotionStatus.TOO_FEW_TRACKS
                if trailer_status in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE) and own.T_i_j is not None:
                    T_trailer = own.T_i_j
                    inliers.update(_inlier_tracks(trailer_pairs, own.inlier_masks))
                else:
                    trailer_status = MotionStatus.TOO_FEW_TRACKS if trailer_status is not MotionStatus.STANDSTILL else trailer_status
                    T_trailer = predicted
        init = MotionInit(tractor.T_i_j, tractor.status, hitch_prev, hitch, trailer_status, T_trailer, inlier_tracks=inliers, scale_chord=tractor.scale_chord)
        if ground is not None and tractor.T_i_j is ground.T_tractor:  # the motion it measured with (no joint refinement since)
            return self._driven(dataclasses.replace(init, scale_chord=ground.scale_chord))
        return self._driven(self._with_ground_scale(init, tractor_pairs, first, second, tractor.estimate.yaw_sigma, speed_bounds))

    def _carried_by_trailer(self, tractor: TractorMotion, trailer_pairs: list[CameraPairs],
                            hitch_prior: float | None) -> tuple[TractorMotion, np.ndarray | None, dict[str, np.ndarray]]:
        """A tractor whose cameras have too few tracks (a cab camera facing an empty yard or a
        blank dock, a broken camera) and whose predicted motion is a standstill (it was at rest)
        carried by the trailer's cameras: the trailer's own motion from its cameras (the 2-point
        solver at its axle group, DESIGN 2.1), and as the tractor's initial motion the bodies
        turning together about the king-pin (the hitch held, the body origins at the king-pin:
        ``T_tractor = H T_trailer H^-1``, ``H = Rz(theta)``). Returns the tractor
        motion (still ``TOO_FEW_TRACKS``: not measured, the smoother gives it the weak prior and
        takes it from the trailer's cameras through the joint and non-holonomic factors, with their
        uncertainty), the trailer's motion and the trailer's inliers; the tractor unchanged, None
        and no inliers where the prediction moves or the trailer's cameras measure nothing either.

        Without it the tractor's initial motion was the constant-velocity prediction, at rest after a
        stop: every keyframe pair then looked like a standstill to the smoother, which dropped the
        trailer's epipolar factors too, and a reversing truck's hitch went 6 deg off at a sigma of
        1.3 deg (realistic yard without the mirror cameras, bearings). The chord the trailer's solver
        cannot fix (straight, or too little turn) is twice ``keyframes.standstill_distance_m`` (a
        drive-off from rest moves: the trailer's tracks showed parallax); the window's scale comes
        from the priors then. A moving prediction is kept: the constant-velocity motion carries the
        hitch's rate on, which the hitch held does not (check tight_yard without the mirrors: hitch
        RMSE 0.19 deg against 0.34 deg carried on every pair)."""
        least_chord = 2.0 * self.config.keyframes.standstill_distance_m
        if (self._trailer_config is None or float(np.linalg.norm(tractor.T_i_j[:2, 3])) >= least_chord
                or sum(len(pair) for pair in trailer_pairs) < self.config.keyframes.min_tracks):
            return tractor, None, {}
        own = estimate_tractor_motion(trailer_pairs, self.rig.axle_x("trailer"), self._trailer_config, chord_prior=least_chord, rng=self._rng)
        status = _status(own.status)
        if status not in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE, MotionStatus.STANDSTILL) or own.T_i_j is None:
            return tractor, None, {}
        hitch = hitch_transform(hitch_prior if hitch_prior is not None else 0.0)
        T_tractor = hitch @ own.T_i_j @ invert_pose(hitch)
        logger.debug("tractor without tracks carried by the trailer's cameras (%s): chord %.3f m, yaw change %.2f deg", status.value,
                     float(np.linalg.norm(T_tractor[:2, 3])), np.degrees(yaw_of(T_tractor)))
        return dataclasses.replace(tractor, T_i_j=T_tractor), own.T_i_j, _inlier_tracks(trailer_pairs, own.inlier_masks)

    def _driven(self, init: MotionInit) -> MotionInit:
        """``init``, its tractor motion kept as the newest piece of the path driven (:meth:`_driven_path`)."""
        self._driven_motions.append(np.array(init.T_tractor, dtype=float))
        return init

    def _driven_path(self) -> np.ndarray | None:
        """The tractor axle's positions on the path driven up to the newest keyframe, relative to its
        position there in that keyframe's body frame, newest first ((M, 2), metres; None before two
        keyframes): the kept keyframe motions chained backwards until ``scale.ground_lane_length_m``
        of path, the oldest piece extended straight to that length (the road behind a truck that has
        only just started). The ground plane's own lane behind the axle follows it (mirror cameras)."""
        length_m = self.config.scale.ground_lane_length_m
        axle = np.array([self.rig.axle_x("tractor"), 0.0, 0.0])
        points, T_newest_k, travelled = [np.zeros(2)], np.eye(4), 0.0
        for T_prev_k in reversed(self._driven_motions):
            T_newest_k = T_newest_k @ invert_pose(T_prev_k)
            point = (T_newest_k[:3, :3] @ axle + T_newest_k[:3, 3] - axle)[:2]
            step = float(np.linalg.norm(point - points[-1]))
            if step < 1e-3:  # at rest
                continue
            points.append(point)
            travelled += step
            if travelled >= length_m:
                break
        if len(points) < 2:
            return None
        if travelled < length_m:
            heading = (points[-1] - points[-2]) / np.linalg.norm(points[-1] - points[-2])
            points.append(points[-1] + (length_m - travelled) * heading)
        return np.array(points)

    def measured_chord(self, first: FrameObservations, second: FrameObservations, tractor: TractorMotion) -> tuple[float, float] | None:
        """The metric tractor axle chord ``(chord m, sigma m)`` of a motion measured by the ground
        plane (and the stereo pair, if any), ``None`` when neither measures it: what the scale
        bootstrap uses on a straight start (DESIGN 2.3), where the 2-point chord is unobservable."""
        if tractor.status not in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE):
            return None
        pairs = camera_pairs(self.rig, "tractor", first, second)
        init = MotionInit(tractor.T_i_j, tractor.status, inlier_tracks=_inlier_tracks(pairs, tractor.estimate.inlier_masks), scale_chord=tractor.scale_chord)
        return self._with_ground_scale(init, pairs, first, second, tractor.estimate.yaw_sigma).scale_chord

    def _with_ground_scale(self, init: MotionInit, pairs: list[CameraPairs], first: FrameObservations, second: FrameObservations, yaw_sigma: float,
                           speed_bounds: tuple[float, float] | None = None) -> MotionInit:
        """``init`` with ``scale_chord`` from the ground plane (``scale.ground_plane``): the metric
        chord of the tractor axle measured from road points of the tractor cameras
        (:mod:`ampc_vo.scale.ground`), given the final tractor motion's rotation and direction and
        the RANSAC's ``yaw_sigma`` (radians; a side camera's chord is sensitive to yaw errors);
        ``pairs``: the tractor cameras' correspondences of ``first`` and ``second``.
        An existing ``scale_chord`` (stereo) is fused with it (inverse variance); a scale-unobservable
        motion is re-initialised with the measured chord. A chord the truck cannot have driven from
        at a speed within ``speed_bounds`` (m/s, least and greatest: :meth:`_speed_bounds`) within the
        pair is dropped (:meth:`_reachable`)."""
        if not self.config.scale.ground_plane or init.tractor_status not in (MotionStatus.OK, MotionStatus.SCALE_UNOBSERVABLE):
            return init
        correspondences = []
        interval = second.timestamp - first.timestamp
        delays = []
        for pair in pairs:
            inlier_ids = init.inlier_tracks.get(pair.camera.name)
            keep = np.isin(pair.track_ids, inlier_ids) if inlier_ids is not None else np.ones(len(pair), bool)
            # each observation's own capture time (unsynchronised, rolling-shutter cameras): the
            # point's baseline is the keyframes' motion over its own time interval
            time_scale = None if pair.times_i is None or interval <= 0.0 else (pair.times_j[keep] - pair.times_i[keep]) / interval
            correspondences.append((pair.camera, pair.bearings_i[keep], pair.bearings_j[keep], time_scale))
            if time_scale is not None:
                delays.append(0.5 * ((pair.times_i[keep] - first.timestamp) + (pair.times_j[keep] - second.timestamp)))
        yaw_sigma = max(float(yaw_sigma), _MIN_YAW_SIGMA) if np.isfinite(yaw_sigma) else _DEFAULT_YAW_SIGMA
        measured = ground_plane_chord(correspondences, init.T_tractor, self.rig.axle_x("tractor"), self._ground_options, yaw_sigma,
                                      driven=self._driven_path())
        if not measured.ok:
            logger.debug("frame %d: no ground-plane chord (%s, %d candidates)", second.frame, measured.status.value, measured.candidates)
            return init
        logger.debug("frames %d-%d: ground-plane chord %.4f +- %.4f m from %d road points (yaw sigma %.3f deg)",
                     first.frame, second.frame, measured.chord, measured.sigma, measured.inlier_count, np.degrees(yaw_sigma))
        if speed_bounds is not None and not self._reachable(measured.chord, measured.sigma, speed_bounds[0], interval, top_speed=speed_bounds[1]):
            logger.info("frames %d-%d: ground-plane chord %.2f +- %.2f m from %d road points dropped: a truck at %.1f-%.1f m/s cannot "
                        "cover that in %.2f s (ransac.max_deceleration_mps2; road points on traffic or the trailer?)",
                        first.frame, second.frame, measured.chord, measured.sigma, measured.inlier_count, *speed_bounds, interval)
            return init
        chord, sigma = measured.chord, measured.sigma
        # the time after the keyframes at which the road was seen: the chord is that of the path
        # between those times, which a speed change makes differ from the keyframes' (smoother,
        # factors.wheel_speed.capture_chord_error; DESIGN 11, "Capture-time chords")
        delays = np.concatenate(delays) if delays else np.zeros(0)
        delay = float(np.mean(delays)) if delays.size else 0.0
        if init.scale_chord is not None:  # independent measurements of the same chord
            other_chord, other_sigma = init.scale_chord
            weights = np.array([1.0 / sigma**2, 1.0 / other_sigma**2])
            chord, sigma = float(weights @ [chord, other_chord] / weights.sum()), float(1.0 / np.sqrt(weights.sum()))
            delay = float(weights @ [delay, init.scale_chord_delay_s] / weights.sum())
        T_tractor = init.T_tractor
        if init.tractor_status is MotionStatus.SCALE_UNOBSERVABLE:  # a better initial value than the predicted chord
            T_tractor = self._with_chord(T_tractor, chord)
        return dataclasses.replace(init, T_tractor=T_tractor, scale_chord=(chord, sigma), scale_chord_delay_s=delay)

