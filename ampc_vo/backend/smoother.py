"""Sliding-window smoother over tractor poses, trailer poses and hitch angles (DESIGN section 3).

Variables per keyframe k: ``X(k)`` ``T_world_tractor`` (Pose3), ``Y(k)`` ``T_world_trailer``
(Pose3), ``A(k)`` the hitch angle θ (double), in a ``gtsam.BatchFixedLagSmoother`` whose lag is
in seconds (keys carry their keyframe's timestamp; older keys are marginalised). Optional doubles:
``W(k)`` the wheel odometry's scale (``scale.wheel_scale_sigma``), ``B(k)`` the trailer's crab
angle (``smoother.trailer_crab_sigma_deg``), each a random walk over the keyframes.

Factors added with keyframe k (``j`` < k are the keyframes still in the window):

* GEC (paper eq. (1)): tractor cameras on ``X(j), X(k)``, trailer cameras on ``Y(j), Y(k)``, for
  every pair with ``k - j <= max_pair_gap`` that shares enough tracks and moved (the residual is
  undefined at standstill); with ``scale.cross_camera`` also **cross-camera** blocks: camera a at
  keyframe j and camera b != a of the same body at k, associated by equal
  ``CameraObservations.landmark_ids`` (two-camera / Plücker form, ``c_i != c_j``), which make
  metric scale observable in straight driving (DESIGN 2.3), up to ``cross_camera_max_gap``
  keyframes apart in the joint modes (``max_pair_gap`` in ``tractor_only`` and ``separate``, where
  longer gaps made the scale collapse on the demo route), gated at ``cross_camera_gate_px``. All
  blocks of keyframe k form one :class:`factors.StackedEpipolarFactor` (6 rows per keyframe pair
  for GTSAM, Huber per correspondence inside): one Python call per evaluation (issue 5 timing).
  Each block's camera may turn relative to its body between the views (bracket vibration,
  :meth:`ArticulatedSmoother._mount_sigma`): that rotation is marginalised inside the factor
  (DESIGN 11, "Camera mounts"), so a shaking trailer camera is not read as body pitch and, through
  its lever arm, as metric scale.
  Outliers: an observation is used only if the RANSAC of its keyframe pair (k-1, k) kept it
  (``MotionInit.inlier_tracks``; per-frame outliers otherwise survive into longer pairs and a
  handful of them, through their large Sampson Jacobians, biased the window by metres), then
  gated by its Sampson residual under the initial poses; Huber (Scalar reweighting) on the rest.
* Between consecutive keyframes: non-holonomic (DESIGN (NH)) of the tractor; of the trailer
  (modes ``full``, ``separate``); planar motion of each body; a hitch random walk ``A(k-1) ->
  A(k)`` whose sigma grows with distance and time, so an unobservable θ holds its value with a
  growing sigma.
* ``JointLoopFactor(X(k), Y(k), A(k))`` (paper eqs. (3)-(5)) in modes ``full`` and
  ``no_trailer_constraint``.
* Scale aid: ``SmoothSpeedFactor`` over ``X(k-2), X(k-1), X(k)`` (and the trailer in
  ``separate``), DESIGN 2.3.
* Measured chords of the tractor axle (``MotionInit.scale_chord``: ground plane, stereo; the
  wheel's ``wheel_chord``), Gaussian. A chord whose road points were seen after the keyframe
  times is that of the path between the capture times: a factor of its own at constant speed
  until keyframe k+1 replaces it by the capture-time term over ``X(k-2) .. X(k+1)``
  (:meth:`ArticulatedSmoother._add_scale_chord`, DESIGN 11 "Capture-time chords").
* Recovery: at standstill a tight zero-motion prior; when a body has no motion estimate (too few
  tracks) or an unobservable scale, a weak prior on the predicted motion keeps the system
  well-posed.

The small residuals of keyframe k (planar, non-holonomic, joint loop, scale chord) are terms of
one :class:`factors.stacked.StackedFactor` (same error and linear system as one
factor each); the smooth-speed prior keeps a factor of its own (it reaches back to k-2). Every
Python factor caches its last evaluation (:mod:`factors._custom`), so LM's repeated evaluations
at the same values and the marginals' linearisation cost no numpy work. LM stops after a
relative error decrease below ``lm_relative_error_tol`` or after ``VoConfig.lm_iterations`` steps
(one per update when keyframes are published as they leave the window; the first step is damped,
``lm_lambda_initial`` 1.0, against overshooting along the weakly observable scale).

Modes (issue 5): ``full``; ``tractor_only`` (no Y, A); ``no_trailer_constraint`` (no trailer NH);
``separate`` (no joint loop and no A: each body on its own cameras, θ afterwards from the two
trajectories: the hitch displacement is common to both bodies, so for a keyframe pair
``θ_i = heading(t_tractor) - heading(t_trailer)`` and ``θ_j = θ_i + ψ - φ``).

Every keyframe publishes the poses, θ and its 1-sigma from ``gtsam.Marginals``: at once
(``output.publish: latest``, causal) or when it leaves the window (``lagged``, fully smoothed,
the default). An update that fails (ill-conditioned window) is retried with the new keyframe
anchored to its initial motion, and as a last resort the smoother restarts at that keyframe.
The motion priors are gtsam's ``BetweenFactorPose3`` (``factors.relative_pose.between_prior``, the
same residual as the Python ``RelativePoseFactor``, tested to the identity), also in the recovery anchor.
"""
from __future__ import annotations

import logging
import time
from functools import partial
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Callable

import gtsam
import numpy as np
from gtsam.symbol_shorthand import A, B, W, X, Y

from ampc_vo.config import VoConfig
from ampc_vo.epipolar import gec_sampson
from ampc_vo.errors import first_line
from ampc_vo.geometry import hitch_transform, make_pose, relative_pose, rot_z, wrap_angle, yaw_of
from ampc_vo.observations import CameraObservations, FrameObservations, match_tracks, usable_landmarks
from ampc_vo.rig import Camera, Rig
from factors._custom import POSE, SCALAR
from factors.epipolar import EpipolarBlock, body_correspondences, body_correspondences_per_row
from factors.hitch_limit import HitchLimitFactor
from factors.joint_loop import fifth_wheel_error
from factors.nonholonomic import crabbed_nonholonomic_error, nonholonomic_error
from factors.planar import planar_motion_error, planar_sigmas
from factors.relative_pose import between_prior
from factors.stacked import StackedFactor, Term
from factors.wheel_speed import capture_chord_error, capture_chord_weights, chord_error, scaled_chord_error
from factors.smooth_speed import SmoothSpeedFactor

logger = logging.getLogger(__name__)


class MotionStatus(str, Enum):
    """What is known about a body's motion from the previous keyframe to this one."""

    OK = "ok"
    SCALE_UNOBSERVABLE = "scale_unobservable"  # direction and rotation known, chord predicted
    STANDSTILL = "standstill"
    TOO_FEW_TRACKS = "too_few_tracks"  # motion predicted (constant velocity)
    FIRST = "first"


def planar_twist(T_earlier_later: np.ndarray, dt: float) -> np.ndarray:
    """Constant-velocity twist ``Log(T_earlier_later) / dt`` (GTSAM order ``[omega, v]``, per
    second) kept in the body's plane: yaw rate and horizontal velocity, with the roll and pitch
    rates and the vertical speed set to zero (DESIGN 11, unsynchronised cameras)."""
    twist = gtsam.Pose3.Logmap(gtsam.Pose3(T_earlier_later)) / dt
    twist[[0, 1, 5]] = 0.0
    return twist


def planar_motions(twist: np.ndarray, delays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Exp(twist * delay)`` for each delay (N,) of a planar twist (:func:`planar_twist`: yaw rate
    ``twist[2]``, horizontal velocity ``twist[3:5]``; the other parts are ignored): rotations
    (N, 3, 3) about z by ``a = omega_z delay`` and translations (N, 3) along the constant-velocity
    arc, ``V(a) v delay`` with ``V(a) = [[sin a / a, -(1 - cos a) / a], [(1 - cos a) / a, sin a / a]]``
    (GTSAM's ``Pose3.Expmap`` of a planar twist)."""
    delays = np.asarray(delays, dtype=float)
    angle = twist[2] * delays
    cos, sin = np.cos(angle), np.sin(angle)
    small = np.abs(angle) < 1e-6
    safe = np.where(small, 1.0, angle)
    along = np.where(small, 1.0 - angle * angle / 6.0, sin / safe)  # sin a / a
    across = np.where(small, 0.5 * angle, (1.0 - cos) / safe)      # (1 - cos a) / a
    vx, vy = twist[3] * delays, twist[4] * delays
    translations = np.stack([along * vx - across * vy, across * vx + along * vy, np.zeros_like(angle)], axis=1)
    rotations = np.zeros((delays.shape[0], 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1], rotations[:, 2, 2] = cos, -sin, sin, cos, 1.0
    return rotations, translations


def nonholonomic_sigma(chord_m: float, dt_s: float, yaw_change_rad: float, base_slip_deg: float, slip_deg_per_mps2: float,
                       floor_m: float, correlation_s: float = 0.0) -> float:
    """Sigma (m) of an axle's non-holonomic residual over one keyframe pair (DESIGN 3, "Non-holonomic
    sigma"): the lateral offset from the circular arc that the slip angle the model misses gives
    over the chord, ``hypot(floor_m, chord tan(beta))``, with ``beta = hypot(beta0, k a_y)``: the
    base slip ``base_slip_deg`` (axle groups, cross-slope drift, alignment) and tyre slip of
    ``slip_deg_per_mps2`` per m/s^2 of the pair's lateral acceleration ``a_y = (chord / dt) (yaw
    change / dt)`` (slip angle = lateral force / cornering stiffness = (a_y / g) / CC, a truck
    tyre's cornering coefficient CC ~ 0.1-0.2 per degree, Gillespie, Fundamentals of Vehicle
    Dynamics, ch. 10: ~0.7 degree per m/s^2). Growing with the chord, it lets neither a standing
    start's short chords take any direction nor a long one in a turn none. The slip is one value over
    ``correlation_s`` (it follows the steering and the load), so a pair shorter than that carries
    only its share of the slip's information: ``beta`` grows by ``sqrt(correlation_s / dt)``, and
    the pairs over any ``correlation_s`` seconds tell ``1 / beta^2`` about a shared slip angle
    whatever the keyframe rate (at most 45 degrees; 0: every pair independent)."""
    dt_s = max(dt_s, 1e-3)
    lateral_acceleration = abs(chord_m / dt_s * yaw_change_rad / dt_s)
    correlated = np.sqrt(max(correlation_s / dt_s, 1.0))
    slip_deg = min(correlated * np.hypot(base_slip_deg, slip_deg_per_mps2 * lateral_acceleration), 45.0)
    return float(np.hypot(floor_m, chord_m * np.tan(np.radians(slip_deg))))


@dataclass(frozen=True)
class MotionInit:
    """Initial values for a new keyframe relative to the previous one (from the minimal solvers).

    ``T_tractor`` (4x4): tractor motion ``T_prev_k``. ``hitch_prev``/``hitch`` (θ at the previous
    keyframe and at this one) from the trailer 1-point RANSAC, ``None`` if not estimated.
    ``T_trailer``: the trailer's own motion (mode ``separate``; in the joint modes when it carries a tractor without tracks), ``None`` if not estimated.
    """

    T_tractor: np.ndarray
    tractor_status: MotionStatus
    hitch_prev: float | None = None
    hitch: float | None = None
    trailer_status: MotionStatus = MotionStatus.TOO_FEW_TRACKS
    T_trailer: np.ndarray | None = None
    inlier_tracks: dict[str, np.ndarray] = field(default_factory=dict)  # per camera: RANSAC inliers of (k-1, k)
    wheel_chord: float | None = None  # measured chord of the tractor axle midpoint (wheel odometry), metres
    # visual metric-scale measurement of the same chord (e.g. ground-plane scale): (chord m, sigma m)
    scale_chord: tuple[float, float] | None = None
    # mean time (s) after the keyframe times at which the scale chord's tracks were seen (camera
    # offsets and row readout; over the measuring cameras' inlier tracks, the road points among
    # them): the chord is that of the path between the capture times
    # (factors.wheel_speed.capture_chord_error; 0: at the keyframe times)
    scale_chord_delay_s: float = 0.0


@dataclass(frozen=True)
class KeyframeEstimate:
    """What the smoother publishes for one keyframe (``hitch_*`` and trailer ``None`` when absent)."""

    index: int
    frame: int
    timestamp: float
    T_world_tractor: np.ndarray
    T_world_trailer: np.ndarray | None
    hitch_angle: float | None
    hitch_sigma: float | None
    tractor_status: str
    trailer_status: str


def _with_hitch_of(held: KeyframeEstimate, mover: KeyframeEstimate) -> KeyframeEstimate:
    """``held`` (a keyframe at rest) with the hitch angle and sigma of ``mover`` when those are
    better known (smaller sigma); its trailer pose turned about the hitch (the body origin) by the
    change (``ArticulatedSmoother._release``)."""
    if mover.hitch_angle is None or mover.hitch_sigma is None or held.hitch_angle is None or held.hitch_sigma is None:
        return held
    if mover.hitch_sigma >= held.hitch_sigma:
        return held
    T_world_trailer = held.T_world_trailer
    if T_world_trailer is not None:
        T_world_trailer = T_world_trailer @ hitch_transform(mover.hitch_angle - held.hitch_angle)
    return replace(held, hitch_angle=mover.hitch_angle, hitch_sigma=mover.hitch_sigma, T_world_trailer=T_world_trailer)


@dataclass
class BackendTiming:
    """Seconds spent per keyframe: building factors, the smoother update (optimisation), marginals."""

    factors: float = 0.0
    optimisation: float = 0.0
    marginals: float = 0.0
    residuals: int = 0
    cpu: float = 0.0  # CPU seconds of the backend's thread for the whole update (robust to other load on the machine)
    iterations: int = 0  # LM iterations of the smoother update

    @property
    def total(self) -> float:
        return self.factors + self.optimisation + self.marginals


@dataclass
class _Keyframe:
    index: int
    frame: int
    timestamp: float
    observations: FrameObservations
    init: MotionInit
    chord: float = 0.0  # distance of the hitch from the previous keyframe (initial value)
    dt: float = 0.0
    landmarks: dict = field(default_factory=dict)  # per camera: (usable indices, their landmark ids), computed once
    capture_twists: dict = field(default_factory=dict)  # per body: the twist its epipolar blocks' capture-time extrinsics were built with
    epipolar_factor: object = None  # the keyframe's StackedEpipolarFactor (replaced by _refresh_capture_twists)
    # a scale chord seen after the keyframe times until the next keyframe replaces its constant-speed
    # factor: (that factor, chord m, sigma m, delay s) (ArticulatedSmoother._add_scale_chord)
    capture_chord: tuple[object, float, float, float] | None = None

    def usable_landmarks(self, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """Indices of the camera's observations with a usable landmark id (:func:`match_landmarks`) and the ids."""
        if camera not in self.landmarks:
            observations = self.observations.cameras[camera]
            if observations.landmark_ids is None:
                self.landmarks[camera] = (np.zeros(0, np.int64), np.zeros(0, np.int64))
            else:
                usable = usable_landmarks(observations.landmark_ids)
                self.landmarks[camera] = (usable, np.asarray(observations.landmark_ids, dtype=np.int64)[usable])
        return self.landmarks[camera]


@dataclass
class _Pending:
    """Factors and values of one smoother update."""

    graph: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: gtsam.Values = field(default_factory=gtsam.Values)
    timestamps: dict[int, float] = field(default_factory=dict)
    residuals: int = 0
    terms: list = field(default_factory=list)  # small residuals of one keyframe, stacked into one factor
    removals: list = field(default_factory=list)  # indices of the smoother's factors this update replaces

    def flush_terms(self) -> None:
        """Add the collected terms as one :class:`factors.stacked.StackedFactor` (issue 5 timing)."""
        if self.terms:
            self.graph.add(StackedFactor(self.terms))
            self.terms = []

    def insert(self, key: int, value, timestamp: float) -> None:
        if isinstance(value, float):
            self.values.insert(key, value)
        else:
            self.values.insert(key, gtsam.Pose3(value))
        self.timestamps[key] = timestamp


# capture-time extrinsics rebuilt when the optimised twist moves a camera by more than this (m) or turns
# it by more than this (rad) over its capture delay (ArticulatedSmoother._refresh_capture_twists)
_CAPTURE_SHIFT_M = 0.003
_CAPTURE_TURN_RAD = float(np.radians(0.02))
# a scale chord seen less than this after (or before) the keyframe times is taken at the keyframe times
_MIN_CAPTURE_DELAY_S = 1e-4
# ... and one seen more than this share of the keyframe interval away from them at constant speed
_MAX_CAPTURE_DELAY_SHARE = 0.5


def _pose_sigmas(rotation_rad: float, translation_m: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(_pose_sigma_vector(rotation_rad, translation_m))


def _pose_sigma_vector(rotation_rad: float, translation_m: float) -> np.ndarray:
    """Sigmas of a pose residual in GTSAM tangent order ``[omega, v]``."""
    return np.array([rotation_rad] * 3 + [translation_m] * 3)


_IDENTITY_POSE = gtsam.Pose3()
_HITCH_STOP_NOISE = gtsam.noiseModel.Isotropic.Sigma(1, np.radians(1.0))  # a hard stop: 1 degree


class ArticulatedSmoother:
    """Fixed-lag smoother of the articulated vehicle (module docstring).

    Call :meth:`add_keyframe` with each keyframe's observations and initial relative motion; it
    returns the estimates published by that call (the first keyframe is published together with
    the second, which gives the first hitch angle).
    """

    def __init__(self, rig: Rig, config: VoConfig) -> None:
        self.rig = rig
        self.config = config
        self.mode = config.mode
        self.use_trailer = rig.has_trailer and config.mode != "tractor_only"
        self.joint = self.use_trailer and config.mode in ("full", "no_trailer_constraint")
        self.trailer_nonholonomic = self.use_trailer and config.mode in ("full", "separate")
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(config.lm_iterations)
        params.setlambdaInitial(config.smoother.lm_lambda_initial)
        params.setRelativeErrorTol(config.smoother.lm_relative_error_tol)
        self._params = params
        self._smoother = gtsam.BatchFixedLagSmoother(config.smoother.lag_s, params)
        self._window: dict[int, _Keyframe] = {}
        self._estimate = gtsam.Values()
        self._pending_first: _Keyframe | None = None
        self._count = 0
        self._last_hitch: float | None = None
        self._last_sigma: float | None = None
        self._separate_hitch: dict[int, float] = {}
        self.timings: list[BackendTiming] = []
        self._rng = np.random.default_rng(config.ransac.seed)
        self._last_state: dict[str, str] = {}
        self._marginals: gtsam.Marginals | None = None
        self._last_sigma: float | None = None  # the last hitch sigma the marginals gave (_sigma_of)
        self._held: list[KeyframeEstimate] = []  # lagged: keyframes at rest awaiting the hitch of the drive-off

    # ------------------------------------------------------------------ public
    @property
    def keyframe_count(self) -> int:
        return self._count

    def add_keyframe(self, observations: FrameObservations, init: MotionInit, deferred: bool = False) -> list[KeyframeEstimate]:
        """Add keyframe k with its initial motion from keyframe k-1 and re-optimise the window.
        Returns what it publishes: with ``output.publish: latest`` keyframe k, with ``lagged`` (or
        ``deferred``: keyframes whose publication waited, :meth:`publish_window`) those leaving the
        window."""
        keyframe = _Keyframe(self._count, observations.frame, observations.timestamp, observations, init)
        self._count += 1
        if keyframe.index == 0:
            self._pending_first = keyframe
            return []
        timing = BackendTiming()
        lagged = self.config.output.publish == "lagged" or deferred
        leaving: list[KeyframeEstimate] = []
        if lagged:
            # keyframes the coming update will marginalise: publish their fully smoothed estimate now
            horizon = keyframe.timestamp - self.config.smoother.lag_s
            leaving = self._release([(self._publish(self._window[index], self._sigma_of(index)), self._at_rest(index))
                                     for index in sorted(self._window) if self._window[index].timestamp < horizon])
        started = time.perf_counter()
        cpu_started = time.thread_time()
        pending = _Pending()
        published_indices = []
        try:
            if self._pending_first is not None:
                first = self._pending_first
                self._pending_first = None
                self._add_first(first, init, pending)
                pending.flush_terms()
                published_indices.append(first.index)
            self._add_next(keyframe, pending)
            pending.flush_terms()
            published_indices.append(keyframe.index)
            timing.factors = time.perf_counter() - started
            timing.residuals = pending.residuals

            started = time.perf_counter()
            stamps = gtsam.FixedLagSmootherKeyTimestampMap()
            for key, stamp in pending.timestamps.items():
                stamps.insert((key, stamp))
            try:
                timing.iterations = int(self._smoother.update(pending.graph, pending.values, stamps, pending.removals).getIterations())
            except RuntimeError as error:
                self._recover(keyframe, pending, error)
        except BaseException:
            # interrupted (Ctrl-C, e.g. inside an error function): the keyframes of this update have
            # no estimate; the window keeps only those that do (what a salvage publishes)
            for index in [index for index in self._window if not self._estimate.exists(X(index))]:
                del self._window[index]
            raise
        self._estimate = self._smoother.calculateEstimate()
        if self._refresh_capture_twists(keyframe):
            self._estimate = self._smoother.calculateEstimate()
        timing.optimisation = time.perf_counter() - started
        self._forget_old(keyframe.timestamp)
        if self.use_trailer and not self.joint:
            for index in sorted(self._window):  # refresh θ of mode separate from the smoothed trajectories
                self._separate_hitch_angle(self._window[index])

        started = time.perf_counter()
        self._marginals = self._compute_marginals(keyframe.index)
        sigma = self._sigma_of(keyframe.index)
        timing.marginals = time.perf_counter() - started
        timing.cpu = time.thread_time() - cpu_started
        self.timings.append(timing)
        if lagged:
            return leaving
        return [self._publish(self._window[index], sigma if index == keyframe.index else self._sigma_of(index)) for index in published_indices if index in self._window]

    def _refresh_capture_twists(self, keyframe: _Keyframe) -> bool:
        """The capture-time extrinsics of keyframe k's epipolar blocks (:meth:`_capture_extrinsic`) move
        each unsynchronised camera along its body's twist at k, which comes from k's first guess when
        the factor is built (the newest trailer pose: the tractor's solver motion through the joint
        loop at an initial hitch angle). Once the window has optimised k, the twist is taken again from
        the optimised poses; where it moves some camera by more than ``_CAPTURE_SHIFT_M`` or turns it
        by more than ``_CAPTURE_TURN_RAD`` more over its delay, k's epipolar factor is rebuilt with it
        and replaces the first one (one more smoother update). Returns whether it did (DESIGN 11)."""
        factor = keyframe.epipolar_factor
        if factor is None or keyframe.index not in self._window or not self._estimate.exists(X(keyframe.index)):
            return False
        delay = max((abs(keyframe.observations.camera_timestamp(camera.name) - keyframe.timestamp) for camera in self.rig.cameras), default=0.0)
        if delay < 1e-6:
            return False
        moved = False
        for body, frozen in keyframe.capture_twists.items():
            refreshed = self._body_twist(body, keyframe, _Pending())
            if frozen is None or refreshed is None:
                continue
            change = (refreshed - frozen) * delay
            moved |= bool(np.linalg.norm(change[3:]) > _CAPTURE_SHIFT_M or np.linalg.norm(change[:3]) > _CAPTURE_TURN_RAD)
        if not moved:
            return False
        index = self._factor_index(factor)
        if index is None:
            return False
        pending = _Pending()
        blocks: list[tuple[EpipolarBlock, float, float]] = []
        for body in keyframe.capture_twists:
            self._add_epipolar_factors(body, keyframe, pending, blocks)
        if not blocks:
            # the optimised chord fell below the standstill distance (a stopping truck's last pair
            # whose first guess was the constant-velocity chord): keep the measurements as built, never
            # drop them (without them the hitch of a stop in publish: latest came out at a 3.4 deg sigma)
            logger.debug("frame %d: capture-time extrinsics not rebuilt: no pair moved under the optimised poses", keyframe.frame)
            return False
        keyframe.epipolar_factor = self._add_stacked_epipolar(blocks, pending)
        try:
            self._smoother.update(pending.graph, gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap(), [index])
        except RuntimeError as error:
            logger.warning("frame %d: refreshing the capture-time extrinsics failed (%s)", keyframe.frame, first_line(error))
            return False
        logger.debug("frame %d: capture-time extrinsics rebuilt from the optimised twist", keyframe.frame)
        return True

    def _recover(self, keyframe: _Keyframe, pending: _Pending, error: RuntimeError) -> None:
        """An ill-conditioned window (e.g. a keyframe whose factors were all rejected): anchor the new
        keyframe to its initial values with moderate priors and optimise again (logged)."""
        logger.warning("frame %d: smoother update failed (%s); anchoring the keyframe to its initial motion", keyframe.frame, first_line(error))
        k = keyframe.index
        anchor = gtsam.NonlinearFactorGraph()
        sigmas = _pose_sigma_vector(np.radians(0.5), 0.05)
        keys = [X] + ([Y] if self.use_trailer and not self.joint else [])
        for key in keys:
            T_prior = relative_pose(pending.values.atPose3(key(k - 1)).matrix() if pending.values.exists(key(k - 1)) else self._estimate.atPose3(key(k - 1)).matrix(),
                                    pending.values.atPose3(key(k)).matrix())
            anchor.add(between_prior(key(k - 1), key(k), gtsam.Pose3(T_prior), sigmas))
        if self.joint:
            anchor.add(gtsam.PriorFactorDouble(A(k), pending.values.atDouble(A(k)), gtsam.noiseModel.Isotropic.Sigma(1, np.radians(2.0))))
        try:
            self._smoother.update(anchor, gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap())
        except RuntimeError:
            self._reinitialise(keyframe, pending)

    def _reinitialise(self, keyframe: _Keyframe, pending: _Pending) -> None:
        """Last resort (DESIGN 4: re-initialise instead of crashing): a new smoother whose first
        keyframe is this one, anchored at its initial values; the old window is dropped."""
        logger.warning("frame %d: smoother re-initialised at this keyframe (window dropped)", keyframe.frame)
        config = self.config.smoother
        k = keyframe.index
        self._smoother = gtsam.BatchFixedLagSmoother(config.lag_s, self._params)
        restart = _Pending()
        T_world_tractor = pending.values.atPose3(X(k)).matrix()
        restart.insert(X(k), T_world_tractor, keyframe.timestamp)
        prior = _pose_sigmas(np.radians(config.prior_rotation_sigma_deg), config.prior_translation_sigma_m)
        restart.graph.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(T_world_tractor), prior))
        if self._wheel_scale:
            self._add_scalar_prior(W(k), float(pending.values.atDouble(W(k))), self.config.scale.wheel_scale_sigma, keyframe.timestamp, restart)
        if self.use_trailer:
            T_world_trailer = pending.values.atPose3(Y(k)).matrix()
            restart.insert(Y(k), T_world_trailer, keyframe.timestamp)
            if self._trailer_crab:
                self._add_scalar_prior(B(k), float(pending.values.atDouble(B(k))), self._crab_sigma, keyframe.timestamp, restart)
            if self.joint:
                hitch = pending.values.atDouble(A(k))
                restart.insert(A(k), float(hitch), keyframe.timestamp)
                restart.graph.add(gtsam.PriorFactorDouble(A(k), float(hitch), gtsam.noiseModel.Isotropic.Sigma(1, np.radians(5.0))))
                self._add_joint_loop(k, restart)
                restart.flush_terms()
            else:
                restart.graph.add(gtsam.PriorFactorPose3(Y(k), gtsam.Pose3(T_world_trailer), prior))
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        for key, stamp in restart.timestamps.items():
            stamps.insert((key, stamp))
        self._smoother.update(restart.graph, restart.values, stamps)
        self._window = {k: keyframe}

    def flush(self) -> list[KeyframeEstimate]:
        """End of the stream: with ``output.publish: lagged`` the keyframes still in the window
        (and those held at rest, :meth:`_release`)."""
        if self.config.output.publish != "lagged":
            return []
        return self.publish_window()

    def publish_window(self) -> list[KeyframeEstimate]:
        """Every keyframe in the window with its current estimate, and those held at rest
        (:meth:`_release`): the end of a lagged stream, or of keyframes added ``deferred`` (the
        scale bootstrap's replay in ``latest`` mode, ``pipeline.OdometryPipeline._replay_bootstrap``)."""
        remaining = self._release([(self._publish(self._window[index], self._sigma_of(index)), False) for index in sorted(self._window)])
        held, self._held = self._held, []
        return held + remaining

    def _at_rest(self, index: int) -> bool:
        """Keyframe ``index`` stands still: its motion from the previous keyframe, or the next
        keyframe's motion from it (the first keyframe of a standing start), is a standstill."""
        following = self._window.get(index + 1)
        return self._window[index].init.tractor_status is MotionStatus.STANDSTILL or (
            following is not None and following.init.tractor_status is MotionStatus.STANDSTILL)

    def _release(self, leaving: list[tuple[KeyframeEstimate, bool]]) -> list[KeyframeEstimate]:
        """Lagged publication across a standstill (issue 16, DESIGN 11): the bodies cannot turn
        relative to each other at rest, so every keyframe of a standstill has the hitch angle the
        truck drives off with. A standstill longer than the lag leaves the window before any
        motion has measured it (a standing start: the prior's tens of degrees, or a guess from a
        first step), so keyframes at rest (``(estimate, at_rest)``) are held back and published
        with the first moving keyframe that leaves the window, taking its hitch and sigma where
        that sigma is the smaller (after a stop in traffic the hitch measured before the stop
        stays); the trailer pose turns about the hitch with it. Publication order is kept."""
        published: list[KeyframeEstimate] = []
        for estimate, at_rest in leaving:
            if at_rest and estimate.hitch_sigma is not None:
                self._held.append(estimate)
                continue
            if self._held:
                published += [_with_hitch_of(held, estimate) for held in self._held]
                self._held = []
            published.append(estimate)
        return published

    def hitch_sigma(self, index: int) -> float | None:
        """1-sigma (rad) of θ at keyframe ``index`` of the window from the last marginals
        (:meth:`_sigma_of`); ``None`` without a joint hitch or with marginals off."""
        return self._sigma_of(index)

    def estimate(self, index: int) -> KeyframeEstimate:
        """Current (smoothed) estimate of a keyframe still in the window."""
        return self._publish(self._window[index], None)

    def window_indices(self) -> list[int]:
        return sorted(self._window)

    # ------------------------------------------------------------------ keyframes
    def _add_first(self, first: _Keyframe, next_init: MotionInit, pending: _Pending) -> None:
        config = self.config.smoother
        self._window[first.index] = first
        T_world_tractor = np.eye(4)
        pending.insert(X(first.index), T_world_tractor, first.timestamp)
        prior = _pose_sigmas(np.radians(config.prior_rotation_sigma_deg), config.prior_translation_sigma_m)
        pending.graph.add(gtsam.PriorFactorPose3(X(first.index), gtsam.Pose3(T_world_tractor), prior))
        if self._wheel_scale:
            self._add_scalar_prior(W(first.index), 1.0, self.config.scale.wheel_scale_sigma, first.timestamp, pending)
        if not self.use_trailer:
            return
        hitch = next_init.hitch_prev if next_init.hitch_prev is not None else 0.0
        T_world_trailer = T_world_tractor @ hitch_transform(hitch)
        pending.insert(Y(first.index), T_world_trailer, first.timestamp)
        if self._trailer_crab:
            self._add_scalar_prior(B(first.index), 0.0, self._crab_sigma, first.timestamp, pending)
        if self.joint:
            pending.insert(A(first.index), float(hitch), first.timestamp)
            pending.graph.add(gtsam.PriorFactorDouble(A(first.index), float(hitch), gtsam.noiseModel.Isotropic.Sigma(1, np.radians(config.hitch_prior_sigma_deg))))
            self._add_hitch_limit(first.index, pending)
            self._add_joint_loop(first.index, pending)
        else:
            pending.graph.add(gtsam.PriorFactorPose3(Y(first.index), gtsam.Pose3(T_world_trailer), prior))
            self._separate_hitch[first.index] = hitch

    def _pose(self, key: int, pending: _Pending) -> np.ndarray:
        if pending.values.exists(key):
            return pending.values.atPose3(key).matrix()
        return self._estimate.atPose3(key).matrix()

    def _double(self, key: int, pending: _Pending) -> float:
        if pending.values.exists(key):
            return pending.values.atDouble(key)
        return self._estimate.atDouble(key)

    def _add_next(self, keyframe: _Keyframe, pending: _Pending) -> None:
        k, previous = keyframe.index, keyframe.index - 1
        init = keyframe.init
        config = self.config.smoother
        previous_keyframe = self._window[previous]
        keyframe.dt = keyframe.timestamp - previous_keyframe.timestamp
        self._window[k] = keyframe
        T_world_tractor = self._pose(X(previous), pending) @ init.T_tractor
        keyframe.chord = float(np.linalg.norm(init.T_tractor[:3, 3]))
        pending.insert(X(k), T_world_tractor, keyframe.timestamp)
        self._complete_capture_chord(keyframe, pending)
        self._add_wheel_scale(keyframe, pending)
        self._add_crab(keyframe, pending)
        self._log_state("tractor", init.tractor_status, keyframe)
        if self.use_trailer:
            self._log_state("trailer", init.trailer_status, keyframe)
            if self.joint:
                hitch = self._initial_hitch(keyframe, pending)
                pending.insert(A(k), hitch, keyframe.timestamp)
                pending.insert(Y(k), T_world_tractor @ hitch_transform(hitch), keyframe.timestamp)
                self._add_joint_loop(k, pending)
                self._add_hitch_limit(k, pending)
                sigma = self._hitch_step_sigma(keyframe)
                pending.graph.add(gtsam.BetweenFactorDouble(A(previous), A(k), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma)))
            else:
                T_trailer = init.T_trailer if init.T_trailer is not None else self._predicted_motion("trailer", keyframe, pending)
                pending.insert(Y(k), self._pose(Y(previous), pending) @ T_trailer, keyframe.timestamp)

        bodies = ["tractor"] + (["trailer"] if self.use_trailer else [])
        standstill = init.tractor_status is MotionStatus.STANDSTILL
        epipolar_blocks: list[tuple[EpipolarBlock, float, float]] = []
        for body in bodies:
            key = X if body == "tractor" else Y
            # in the joint modes the trailer pose follows from X and A (joint loop): no own motion priors
            own_motion = body == "tractor" or not self.joint
            status = init.tractor_status if body == "tractor" else init.trailer_status
            pair = (key(previous), key(k))
            # planar motion of both bodies: the trailer's pitch is free at the fifth wheel
            pending.terms.append(Term(pair, (POSE, POSE), planar_motion_error, self._planar_sigmas(key, keyframe, pending)))
            if standstill:
                if own_motion:
                    tight = _pose_sigma_vector(np.radians(config.standstill_rotation_sigma_deg), config.standstill_translation_sigma_m)
                    pending.graph.add(between_prior(*pair, _IDENTITY_POSE, tight))
                continue
            if body == "trailer" and self._trailer_crab:
                pending.terms.append(Term(pair + (B(k),), (POSE, POSE, SCALAR), partial(crabbed_nonholonomic_error, axle_x=self.rig.axle_x(body)),
                                          np.array([self._nonholonomic_sigma(body, keyframe, pending)]), config.huber_k))
            elif body == "tractor" or self.trailer_nonholonomic:
                pending.terms.append(Term(pair, (POSE, POSE), partial(nonholonomic_error, axle_x=self.rig.axle_x(body)),
                                          np.array([self._nonholonomic_sigma(body, keyframe, pending)]), config.huber_k))
            linked = self._add_epipolar_factors(body, keyframe, pending, epipolar_blocks)
            if own_motion:
                # weak prior on the initial motion when it was not estimated; a 3x weaker regulariser
                # otherwise (keeps the system well-posed when the scale is unobservable, DESIGN 2.3)
                inflation = 1.0 if (status is not MotionStatus.OK or not linked) else 3.0
                weak = _pose_sigma_vector(inflation * np.radians(config.weak_motion_rotation_sigma_deg), inflation * config.weak_motion_translation_sigma_m)
                T_prior = gtsam.Pose3(relative_pose(self._pose(key(previous), pending), self._pose(key(k), pending)))
                pending.graph.add(between_prior(*pair, T_prior, weak))
                self._add_smooth_speed(key, keyframe, pending)
            axle_x = self.rig.axle_x("tractor")
            if body == "tractor" and self.config.scale.wheel_speed and init.wheel_chord is not None:
                wheel_sigma = np.array([self.config.scale.wheel_speed_sigma_m])
                if self._wheel_scale:
                    pending.terms.append(Term(pair + (W(k),), (POSE, POSE, SCALAR),
                                              partial(scaled_chord_error, axle_x=axle_x, chord_length=float(init.wheel_chord)), wheel_sigma))
                else:
                    pending.terms.append(Term(pair, (POSE, POSE), partial(chord_error, axle_x=axle_x, chord_length=float(init.wheel_chord)), wheel_sigma))
            if body == "tractor" and init.scale_chord is not None:
                self._add_scale_chord(keyframe, pending)
        keyframe.epipolar_factor = self._add_stacked_epipolar(epipolar_blocks, pending)

    def _add_scale_chord(self, keyframe: _Keyframe, pending: _Pending) -> None:
        """The measured metric chord of the tractor axle from keyframe k-1 to k (ground plane,
        stereo: ``MotionInit.scale_chord``). Gaussian: gross outliers are dropped before
        (MotionInitializer._reachable); under a Huber kernel every chord of the window could be
        given up at once (DESIGN 11, "Measured chords").

        Its points were seen ``MotionInit.scale_chord_delay_s`` after the keyframe times (camera
        offsets, row readout), so it is the chord of the path between those times
        (:func:`factors.wheel_speed.capture_chord_error`, DESIGN 11 "Capture-time chords"), which
        needs the speed at k and so the path after k: until the next keyframe the constant-speed
        chord goes in as a factor of its own, which that keyframe replaces
        (:meth:`_complete_capture_chord`)."""
        k = keyframe.index
        chord, sigma = (float(value) for value in keyframe.init.scale_chord)
        delay = keyframe.init.scale_chord_delay_s if self.config.scale.capture_time_chords else 0.0
        term = Term((X(k - 1), X(k)), (POSE, POSE), partial(chord_error, axle_x=self.rig.axle_x("tractor"), chord_length=chord), np.array([sigma]))
        if abs(delay) < _MIN_CAPTURE_DELAY_S:
            pending.terms.append(term)
            return
        factor = StackedFactor([term])
        pending.graph.add(factor)
        keyframe.capture_chord = (factor, chord, sigma, delay)

    def _factor_index(self, factor: object) -> int | None:
        """Index of ``factor`` (the object added) in the smoother's graph; None once it has left
        the window (marginalised with its oldest key)."""
        graph = self._smoother.getFactors()
        return next((i for i in range(graph.size()) if graph.exists(i) and graph.at(i) is factor), None)

    def _complete_capture_chord(self, keyframe: _Keyframe, pending: _Pending) -> None:
        """Keyframe l has come: the previous keyframe k's chord seen after (or before) the keyframe
        times (:meth:`_add_scale_chord`) replaces its constant-speed factor by the capture-time term
        over k-2 (when still in the window), k-1, k and l, removed and added in this update. Nothing
        when that factor has left the window with its oldest pose."""
        previous = self._window.get(keyframe.index - 1)
        if previous is None or previous.capture_chord is None:
            return
        (factor, chord, sigma, delay), previous.capture_chord = previous.capture_chord, None
        index = self._factor_index(factor)
        if index is None:
            return
        k = previous.index
        start = self._window.get(k - 1)  # the pair's first keyframe; its dt: the interval from k-2
        with_before = k - 2 in self._window and self._estimate.exists(X(k - 2)) and start is not None and start.dt > 0.0
        intervals = [previous.dt, keyframe.dt] + ([start.dt] if with_before else [])
        if abs(delay) > _MAX_CAPTURE_DELAY_SHARE * min(intervals):
            # the speed's parabola is a first-order model of a delay short against the keyframe
            # intervals; a camera that much later is more likely a clock problem: the chord stays as measured
            logger.debug("frame %d: scale chord seen %.0f ms after the keyframe times, keyframes %.0f ms apart: taken at constant speed",
                         previous.frame, 1e3 * delay, 1e3 * min(intervals))
            return
        keys = tuple(X(i) for i in range(k - 2 if with_before else k - 1, keyframe.index + 1))
        weights = capture_chord_weights(delay, start.dt if with_before else None, previous.dt, keyframe.dt)
        pending.removals.append(index)
        pending.terms.append(Term(keys, (POSE,) * len(keys), partial(capture_chord_error, axle_x=self.rig.axle_x("tractor"), chord_length=chord,
                                                                      weights=weights), np.array([sigma])))

    @property
    def _trailer_crab(self) -> bool:
        """The trailer's crab angle is a variable ``B(k)`` (``smoother.trailer_crab_sigma_deg``)."""
        return self.trailer_nonholonomic and self.config.smoother.trailer_crab_sigma_deg is not None

    @property
    def _crab_sigma(self) -> float:
        """Prior sigma (radians) of the crab angle at the first keyframe and at a restart."""
        return float(np.radians(self.config.smoother.trailer_crab_sigma_deg))

    @staticmethod
    def _add_scalar_prior(key: int, value: float, sigma: float, timestamp: float, pending: _Pending) -> None:
        """A scalar variable ``key = value`` with a prior of ``sigma`` (``W``, ``B`` at the first keyframe and at a restart)."""
        pending.insert(key, value, timestamp)
        pending.graph.add(gtsam.PriorFactorDouble(key, value, gtsam.noiseModel.Isotropic.Sigma(1, sigma)))

    def _add_random_walk(self, symbol: Callable[[int], int], keyframe: _Keyframe, sigma: float, pending: _Pending) -> None:
        """``symbol(k)`` starting at ``symbol(k-1)``'s value, tied to it by a random-walk step of
        ``sigma`` (floored at 1e-5: a standstill keyframe drives no distance)."""
        k = keyframe.index
        value = self._double(symbol(k - 1), pending)
        pending.insert(symbol(k), float(value), keyframe.timestamp)
        pending.graph.add(gtsam.BetweenFactorDouble(symbol(k - 1), symbol(k), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, max(float(sigma), 1e-5))))

    def _add_crab(self, keyframe: _Keyframe, pending: _Pending) -> None:
        """``B(k)``, the trailer's crab angle over the pair (k-1, k) (``factors.nonholonomic``,
        :func:`crabbed_nonholonomic_error`): a random walk from ``B(k-1)`` whose sigma grows with the
        square root of the distance (``smoother.trailer_crab_random_walk_deg_per_sqrt_100m``: it
        follows the road's cross-slope and the load), so a steady drift is measured by the
        trailer's cameras over the window instead of being denied by every pair's arc alike."""
        if not (self.use_trailer and self._trailer_crab):
            return
        step = np.radians(self.config.smoother.trailer_crab_random_walk_deg_per_sqrt_100m) * np.sqrt(keyframe.chord / 100.0)
        self._add_random_walk(B, keyframe, step, pending)

    @property
    def _wheel_scale(self) -> bool:
        """The wheel odometry's scale is a variable ``W(k)`` (config ``scale.wheel_scale_sigma``)."""
        return self.config.scale.wheel_speed and self.config.scale.wheel_scale_sigma is not None

    def _add_wheel_scale(self, keyframe: _Keyframe, pending: _Pending) -> None:
        """``W(k)``, the wheel odometry's scale at keyframe k (factors.wheel_speed,
        ``scaled_chord_error``): a random walk from ``W(k-1)`` whose sigma grows with the square
        root of the distance driven (``scale.wheel_scale_random_walk_per_sqrt_km``; tyres warm up,
        pressure and load change slowly), so the other metric sources (ground plane, cross-camera
        pairs, the 2-point solver in turns) calibrate it over the whole drive, not one window."""
        if not self._wheel_scale:
            return
        self._add_random_walk(W, keyframe, self.config.scale.wheel_scale_random_walk_per_sqrt_km * np.sqrt(keyframe.chord / 1000.0), pending)

    def wheel_scale(self) -> tuple[float, float | None] | None:
        """The newest estimate of the wheel odometry's scale and its sigma (from the last marginals
        when there are any); None when it is not estimated."""
        newest = max(self._window, default=None)
        if not self._wheel_scale or newest is None or not self._estimate.exists(W(newest)):
            return None
        return float(self._estimate.atDouble(W(newest))), self._marginal_sigma(W(newest))

    def _initial_hitch(self, keyframe: _Keyframe, pending: _Pending) -> float:
        """θ_k: the window's θ_{k-1} plus the 1-point RANSAC's change of θ over the pair if any, else held (standstill), the
        change that makes the trailer's initial motion its own measured one (``MotionInit.T_trailer``: a tractor
        without tracks carried by the trailer), or predicted by the trailer non-holonomic closed form
        ``ψ = 2 atan2(w_y, w_x + 2 s_B)`` (DESIGN 2)."""
        init = keyframe.init
        previous = self._double(A(keyframe.index - 1), pending)
        if init.hitch is not None and init.trailer_status is MotionStatus.OK:
            if init.hitch_prev is not None:
                # the pair measures the change of theta well (the difference of two measured yaws),
                # its absolute value weakly: composed onto the window's value, the initial trailer
                # pose stays consistent with the window and the pose gate keeps its correspondences
                return float(wrap_angle(previous + init.hitch - init.hitch_prev))
            return float(init.hitch)
        if init.tractor_status is MotionStatus.STANDSTILL:
            return previous
        if init.T_trailer is not None:  # the trailer's own motion measured (a tractor carried by it): the initial poses follow it
            return float(wrap_angle(previous + yaw_of(init.T_trailer) - yaw_of(init.T_tractor)))
        s_b = -self.rig.axle_x("trailer")
        w = rot_z(-previous) @ init.T_tractor[:3, 3]
        psi = 2.0 * np.arctan2(w[1], w[0] + 2.0 * s_b)
        return float(wrap_angle(previous + psi - yaw_of(init.T_tractor)))

    def _hitch_step_sigma(self, keyframe: _Keyframe) -> float:
        """Random-walk sigma of θ between consecutive keyframes: grows with distance and time; at
        a standstill the hitch cannot turn (the bodies stand still relative to each other), so
        θ is held as tightly as the bodies' zero motion, and what the moving keyframes measure
        later carries back over the standstill."""
        config = self.config.smoother
        if keyframe.init.tractor_status is MotionStatus.STANDSTILL:
            return float(np.radians(config.standstill_rotation_sigma_deg))
        variance = (np.radians(config.hitch_random_walk_deg_per_m)) ** 2 * max(keyframe.chord, 1e-3)
        variance += (np.radians(config.hitch_hold_sigma_growth_deg_per_s)) ** 2 * max(keyframe.dt, 1e-3)
        return float(np.sqrt(variance))

    def _predicted_motion(self, body: str, keyframe: _Keyframe, pending: _Pending) -> np.ndarray:
        """Constant-velocity prediction of a body's motion (used when it could not be estimated)."""
        key = X if body == "tractor" else Y
        k = keyframe.index
        if keyframe.init.tractor_status is MotionStatus.STANDSTILL or k < 2 or (k - 2) not in self._window:
            return np.eye(4)
        last = relative_pose(self._pose(key(k - 2), pending), self._pose(key(k - 1), pending))
        previous_dt = self._window[k - 1].dt
        if previous_dt <= 0:
            return np.eye(4)
        ratio = keyframe.dt / previous_dt
        yaw = yaw_of(last) * ratio
        return make_pose(rot_z(yaw), last[:3, 3] * ratio)

    # ------------------------------------------------------------------ factors
    def _add_joint_loop(self, k: int, pending: _Pending) -> None:
        """Joint loop ``X(k), Y(k), A(k)`` (paper eqs. (3)-(5)) as a term of the keyframe's stacked
        factor, as a fifth wheel couples the bodies: rigid in roll and at the king-pin, free in yaw
        (``theta``) and nearly free in the plate's pitch (``joint_loop_pitch_sigma_deg``, in the
        tractor's axes: :func:`factors.joint_loop.fifth_wheel_error`)."""
        config = self.config.smoother
        sigmas = _pose_sigma_vector(np.radians(config.joint_loop_rotation_sigma_deg), config.joint_loop_translation_sigma_m)
        sigmas[1] = np.radians(config.joint_loop_pitch_sigma_deg)
        pending.terms.append(Term((X(k), Y(k), A(k)), (POSE, POSE, SCALAR), fifth_wheel_error, sigmas))

    def _nonholonomic_sigma(self, body: str, keyframe: _Keyframe, pending: _Pending) -> float:
        """Sigma (m) of a body's non-holonomic residual over keyframe pair (k-1, k):
        :func:`nonholonomic_sigma` of its axle's chord and yaw change in the current values, with the
        body's base slip (``*nonholonomic_slip_deg``)."""
        config = self.config.smoother
        key = X if body == "tractor" else Y
        k = keyframe.index
        T_j_k = relative_pose(self._pose(key(k - 1), pending), self._pose(key(k), pending))
        axle = np.array([self.rig.axle_x(body), 0.0, 0.0])
        chord = float(np.linalg.norm(T_j_k[:3, :3] @ axle + T_j_k[:3, 3] - axle))
        base = config.nonholonomic_slip_deg if body == "tractor" else config.trailer_nonholonomic_slip_deg
        return nonholonomic_sigma(chord, keyframe.dt, yaw_of(T_j_k[:3, :3]), base, config.nonholonomic_slip_deg_per_mps2,
                                  config.nonholonomic_sigma_m, config.nonholonomic_slip_correlation_s)

    def _interval_motion(self, key, k: int, pending: _Pending) -> tuple[float, float] | None:
        """Speed (m/s, of the body origin) and yaw rate (rad/s) over keyframe pair (k-1, k) from the
        window's current poses; None when k-1 is not in the window."""
        if k < 1 or (k - 1) not in self._window or k not in self._window:
            return None
        dt = max(self._window[k].dt, 1e-3)
        T_j_k = relative_pose(self._pose(key(k - 1), pending), self._pose(key(k), pending))
        return float(np.linalg.norm(T_j_k[:2, 3])) / dt, yaw_of(T_j_k[:3, :3]) / dt

    def _planar_sigmas(self, key, keyframe: _Keyframe, pending: _Pending) -> np.ndarray:
        """Sigmas of a body's planar-motion residual over keyframe pair (k-1, k)
        (:func:`factors.planar.planar_sigmas`) at the largest lateral (``v * yaw rate``) and
        longitudinal (speed change) acceleration of this and the previous interval, from the
        window's current poses: the nose of a braking truck rises when it stops within a pair, which
        the pair's mean acceleration does not show. A planar factor tighter than the suspension
        pushes an unmodelled pitch or roll change into the yaw and the chord."""
        config = self.config.smoother
        k = keyframe.index
        motions = [self._interval_motion(key, index, pending) for index in (k, k - 1, k - 2)]
        lateral, longitudinal = 0.0, 0.0
        for age, (motion, before) in enumerate(zip(motions[:2], motions[1:])):
            if motion is None:
                continue
            speed, yaw_rate = motion
            lateral = max(lateral, abs(speed * yaw_rate))
            if before is not None:
                interval = 0.5 * (self._window[k - age].dt + self._window[k - age - 1].dt)
                longitudinal = max(longitudinal, abs(speed - before[0]) / max(interval, 1e-3))
        return planar_sigmas(lateral, longitudinal, np.radians(config.planar_rotation_sigma_deg), np.radians(config.suspension_roll_deg_per_mps2),
                             np.radians(config.suspension_pitch_deg_per_mps2), config.planar_height_sigma_m)

    def _add_hitch_limit(self, k: int, pending: _Pending) -> None:
        """The hitch's mechanical range on ``A(k)`` (:mod:`factors.hitch_limit`): the trailer's own
        measurements cannot tell theta from theta + pi in straight driving."""
        pending.graph.add(HitchLimitFactor(A(k), float(np.radians(self.config.smoother.hitch_limit_deg)), _HITCH_STOP_NOISE))

    def _add_smooth_speed(self, key, keyframe: _Keyframe, pending: _Pending) -> None:
        sigma = self.config.scale.smooth_speed_sigma_mps2
        k = keyframe.index
        if sigma is None or k < 2 or (k - 2) not in self._window:
            return
        previous = self._window[k - 1]
        if previous.init.tractor_status is MotionStatus.STANDSTILL or previous.dt <= 0 or keyframe.dt <= 0:
            return
        noise = gtsam.noiseModel.Isotropic.Sigma(1, sigma * 0.5 * (previous.dt + keyframe.dt))
        pending.graph.add(SmoothSpeedFactor(key(k - 2), key(k - 1), key(k), previous.dt, keyframe.dt, noise))

    def _gec_sigma(self, camera: Camera) -> float:
        """Sampson residual sigma of a camera: pixel sigma / focal length (DESIGN section 3)."""
        return self.config.smoother.pixel_sigma / (0.5 * (camera.fx + camera.fy))

    def _add_stacked_epipolar(self, blocks: list[tuple[EpipolarBlock, float, float]], pending: _Pending) -> object:
        """One :class:`factors.StackedEpipolarFactor` with all GEC blocks of the new keyframe (both
        bodies, every keyframe pair and camera pair), Huber per residual, 6 rows per keyframe pair;
        each block ``(block, Sampson sigma, mount sigma)`` (:meth:`_mount_sigma`; all 0: rigid
        mounts). It is marginalised when its oldest key leaves the window: with pairs up to 3
        keyframes apart, as before when the rows of (k-3, k) had factors of their own."""
        if not blocks:
            return None
        from factors import StackedEpipolarFactor

        mount_sigmas = [mount for _, _, mount in blocks]  # all > 0 (moving pairs) unless both mount keys are 0
        factor = StackedEpipolarFactor([block for block, _, _ in blocks], [sigma for _, sigma, _ in blocks], self.config.smoother.huber_k,
                                       mount_sigmas=mount_sigmas if min(mount_sigmas) > 0.0 else None,
                                       relinearize_threshold=self.config.smoother.relinearize_threshold)
        pending.graph.add(factor)
        pending.residuals += len(factor)
        return factor

    def _verified(self, keyframe: _Keyframe, camera: str, observations: CameraObservations, index: np.ndarray) -> np.ndarray:
        """Mask of the observations ``index`` that the RANSAC of their keyframe pair kept (all True
        when there is no RANSAC verdict: the first keyframe, or no estimate)."""
        if keyframe.init.tractor_status is MotionStatus.FIRST:
            return np.ones(index.shape[0], dtype=bool)
        verified = keyframe.init.inlier_tracks.get(camera)
        if verified is None:
            return np.ones(index.shape[0], dtype=bool)
        return np.isin(observations.track_ids[index], verified)

    def _mount_sigma(self, chord_m: float, dt: float) -> float:
        """Sigma (radians per axis) of a camera's rotation relative to its body between two views
        ``dt`` seconds and ``chord_m`` apart (DESIGN 11, "Camera mounts"): a floor (engine shake,
        bracket flex) and road-excited vibration in proportion to the speed at graph construction."""
        config = self.config.smoother
        speed = chord_m / dt if dt > 0.0 else 0.0
        return float(np.radians(np.hypot(config.camera_mount_sigma_deg, config.camera_mount_sigma_deg_per_mps * speed)))

    def _add_epipolar_factors(self, body: str, keyframe: _Keyframe, pending: _Pending, blocks: list[tuple[EpipolarBlock, float, float]]) -> bool:
        """GEC blocks between keyframe k and the earlier keyframes of the window (module docstring),
        appended to ``blocks``. Returns True when at least one block links k to k-1."""
        config = self.config
        key = X if body == "tractor" else Y
        k = keyframe.index
        lag_start = keyframe.timestamp - config.smoother.lag_s
        linked_previous = False
        T_world_k = self._pose(key(k), pending)
        cameras = self.rig.cameras_on(body)
        # each camera's extrinsic at its capture time, once per keyframe (not per camera pair)
        twist_k = self._body_twist(body, keyframe, pending)
        keyframe.capture_twists[body] = twist_k
        extrinsics_k = {camera.name: self._capture_extrinsic(keyframe, camera, twist_k) for camera in cameras}
        cross_gap = 0
        if config.scale.cross_camera and len(cameras) > 1:
            # long cross-camera gaps only with the trailer coupling (joint modes): on a single body
            # (tractor_only, separate) gaps beyond max_pair_gap made the scale collapse after a
            # straight start on the demo route (not understood yet; issue 5 report)
            cross_gap = config.scale.cross_camera_max_gap if self.joint else min(config.scale.cross_camera_max_gap, config.smoother.max_pair_gap)
        for j in range(k - 1, max(k - 1 - max(config.smoother.max_pair_gap, cross_gap), -1), -1):
            earlier = self._window.get(j)
            if earlier is None or earlier.timestamp < lag_start:
                break
            T_j_k = relative_pose(self._pose(key(j), pending), T_world_k)
            chord = float(np.linalg.norm(T_j_k[:3, 3]))
            if chord < config.keyframes.standstill_distance_m:
                continue
            mount_sigma = self._mount_sigma(chord, keyframe.timestamp - earlier.timestamp)
            twist_j = self._body_twist(body, earlier, pending)
            extrinsics_j = {camera.name: self._capture_extrinsic(earlier, camera, twist_j) for camera in cameras}
            for camera_j in cameras:
                first = earlier.observations.cameras.get(camera_j.name)
                if first is None or len(first) == 0:
                    continue
                for camera_k in cameras:
                    second = keyframe.observations.cameras.get(camera_k.name)
                    if second is None or len(second) == 0:
                        continue
                    if camera_k is camera_j:
                        if k - j > config.smoother.max_pair_gap:
                            continue
                        index_j, index_k = match_tracks(first, second)
                        gate_px = config.smoother.gate_px
                    else:
                        if k - j > cross_gap:
                            continue
                        (usable_j, ids_j), (usable_k, ids_k) = earlier.usable_landmarks(camera_j.name), keyframe.usable_landmarks(camera_k.name)
                        _, index_j, index_k = np.intersect1d(ids_j, ids_k, assume_unique=True, return_indices=True)
                        index_j, index_k = usable_j[index_j], usable_k[index_k]
                        gate_px = config.scale.cross_camera_gate_px
                    if index_j.size < config.keyframes.min_tracks:
                        continue
                    # per-observation outlier rejection: an observation is used only if the RANSAC of
                    # its keyframe's pair (k-1, k) kept it; without a RANSAC verdict the pose gate decides
                    valid = self._verified(keyframe, camera_k.name, second, index_k) & self._verified(earlier, camera_j.name, first, index_j)
                    index_j, index_k = index_j[valid], index_k[valid]
                    if index_j.size < config.keyframes.min_tracks:
                        continue
                    T_body_camera_j, T_body_camera_k = extrinsics_j[camera_j.name], extrinsics_k[camera_k.name]
                    keep = self._gate(camera_j, camera_k, first.bearings[index_j], second.bearings[index_k], T_j_k, gate_px, T_body_camera_j, T_body_camera_k)
                    if keep.sum() < config.keyframes.min_tracks:
                        continue
                    index_j, index_k = index_j[keep], index_k[keep]
                    cap = config.smoother.max_window_tracks_per_camera
                    if index_j.shape[0] > cap:
                        chosen = np.sort(self._rng.choice(index_j.shape[0], cap, replace=False))
                        index_j, index_k = index_j[chosen], index_k[chosen]
                    correspondences = self._correspondences((camera_j, first, index_j, twist_j, T_body_camera_j),
                                                            (camera_k, second, index_k, twist_k, T_body_camera_k))
                    sigma = 0.5 * (self._gec_sigma(camera_j) + self._gec_sigma(camera_k))
                    blocks.append((EpipolarBlock(key(j), key(k), correspondences), sigma, mount_sigma))
                    linked_previous |= j == k - 1
        return linked_previous

    @staticmethod
    def _row_extrinsics(camera: Camera, observations: CameraObservations, index: np.ndarray, twist: np.ndarray | None,
                        T_body_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R_body_camera`` (N, 3, 3) and centre (N, 3) of ``camera`` when each observation
        ``index`` was exposed: ``T_body_camera`` at the image's capture time
        (:meth:`_capture_extrinsic`) moved on along the body's constant-velocity arc by its row's
        readout (``Camera.row_times``; :func:`planar_motions` of the planar ``twist``, which composes:
        ``Exp((delta + r) xi) = Exp(r xi) Exp(delta xi)``). A global shutter, or no twist: that one
        extrinsic for every row."""
        count = index.shape[0]
        if camera.readout_time <= 0.0 or twist is None:
            return np.broadcast_to(T_body_camera[:3, :3], (count, 3, 3)), np.broadcast_to(T_body_camera[:3, 3], (count, 3))
        rotations, translations = planar_motions(twist, camera.row_times(observations.pixels[index]))
        return rotations @ T_body_camera[:3, :3], rotations @ T_body_camera[:3, 3] + translations

    def _correspondences(self, view_j: tuple, view_k: tuple) -> object:
        """Body-frame correspondences of one camera pair between keyframes j and k, each view
        ``(camera, observations, index, twist, T_body_camera at its capture time)``: with those
        extrinsics, or with ``smoother.rolling_shutter_rows`` at each observation's row time
        (:meth:`_row_extrinsics`: one GEC centre per ray)."""
        (camera_j, first, index_j, twist_j, T_body_camera_j), (camera_k, second, index_k, twist_k, T_body_camera_k) = view_j, view_k
        rolling = camera_j.readout_time > 0.0 or camera_k.readout_time > 0.0
        if not self.config.smoother.rolling_shutter_rows or not rolling:
            return body_correspondences(T_body_camera_j, first.bearings[index_j], second.bearings[index_k], T_body_camera_k)
        rotations_j, centers_j = self._row_extrinsics(camera_j, first, index_j, twist_j, T_body_camera_j)
        rotations_k, centers_k = self._row_extrinsics(camera_k, second, index_k, twist_k, T_body_camera_k)
        return body_correspondences_per_row(rotations_j, centers_j, first.bearings[index_j], rotations_k, centers_k, second.bearings[index_k])

    @staticmethod
    def _capture_extrinsic(keyframe: _Keyframe, camera: Camera, twist: np.ndarray | None) -> np.ndarray:
        """``T_body_camera`` of ``camera`` at its own capture time: an unsynchronised camera
        (``CameraObservations.timestamp``, frames.csv ``<camera>_timestamp``) took its image
        ``delta`` seconds after the keyframe's time, when the body had moved on. The body pose at
        ``t_k + delta`` on the constant-velocity arc through the keyframe's motion from its
        neighbour turns that into an extrinsic of the keyframe's body pose:
        ``Exp(delta xi) T_body_camera`` with ``xi`` the body's planar ``twist`` at the keyframe
        (:meth:`_body_twist`, once per body and keyframe; None: the calibrated extrinsic)."""
        delta = keyframe.observations.camera_timestamp(camera.name) - keyframe.timestamp
        if abs(delta) < 1e-6 or twist is None:
            return camera.T_body_camera
        return gtsam.Pose3.Expmap(twist * delta).matrix() @ camera.T_body_camera

    def _body_twist(self, body: str, keyframe: _Keyframe, pending: _Pending) -> np.ndarray | None:
        """The body's twist at keyframe k (GTSAM order ``[omega, v]``, per second) from the
        window's current poses of k and its neighbour, ``Log(T_{k-1}^-1 T_k) / dt``, kept in the
        body's plane: yaw rate and the horizontal velocity only (DESIGN 11). The out-of-plane
        parts (pitch and roll rates, vertical speed) between keyframes are a few tenths of a
        degree per second on real roads, below what the window resolves when the factor is
        built (the newest trailer pose starts at the tractor's attitude): extrapolated over the
        camera's delay, their noise became a systematic pitch of the unsynchronised cameras and
        the trajectory drifted 0.6 deg of pitch per 100 m on the realistic motorway (bearings);
        the planar twist drifts 0.02 deg / 100 m there. None without a neighbour pose."""
        key = X if body == "tractor" else Y
        k = keyframe.index
        neighbour = self._window.get(k - 1) or self._window.get(k + 1)
        if neighbour is None or not (pending.values.exists(key(neighbour.index)) or self._estimate.exists(key(neighbour.index))):
            return None
        dt = abs(keyframe.timestamp - neighbour.timestamp)
        if dt <= 0.0:
            return None
        T_earlier_later = relative_pose(self._pose(key(min(k, neighbour.index)), pending), self._pose(key(max(k, neighbour.index)), pending))
        return planar_twist(T_earlier_later, dt)

    def _gate(self, camera_i: Camera, camera_j: Camera, bearings_i: np.ndarray, bearings_j: np.ndarray, T_i_j: np.ndarray, gate_px: float,
              T_body_camera_i: np.ndarray | None = None, T_body_camera_j: np.ndarray | None = None) -> np.ndarray:
        """Correspondences whose Sampson residual under the initial motion is below ``gate_px``
        (extrinsics at the cameras' capture times when given)."""
        T_body_camera_i = camera_i.T_body_camera if T_body_camera_i is None else T_body_camera_i
        T_body_camera_j = camera_j.T_body_camera if T_body_camera_j is None else T_body_camera_j
        residual = gec_sampson(bearings_i @ T_body_camera_i[:3, :3].T, bearings_j @ T_body_camera_j[:3, :3].T, T_i_j[:3, :3], T_i_j[:3, 3],
                               T_body_camera_i[:3, 3], T_body_camera_j[:3, 3])
        threshold = gate_px / (0.25 * (camera_i.fx + camera_i.fy + camera_j.fx + camera_j.fy))
        return np.abs(residual) < threshold

    # ------------------------------------------------------------------ results
    def _forget_old(self, newest: float) -> None:
        """Drop window bookkeeping of keyframes the smoother has marginalised."""
        present = {key for key in self._smoother.timestamps().keys()}
        for index in list(self._window):
            if X(index) not in present:
                del self._window[index]

    def _compute_marginals(self, k: int) -> gtsam.Marginals | None:
        """``gtsam.Marginals`` of the current window (DESIGN section 3), None if disabled or singular.

        Where the Cholesky factorisation fails, the window is factorised again with its position and
        heading pinned (:func:`_with_gauge_anchor`): the marginalised prior anchors them only weakly,
        and over a long, fast window that leaves a condition number near 1e11 (motorway at 29 m/s:
        eigenvalues 3e-5 for the window's common translation against 8e6), on which GTSAM's
        elimination met a non-positive pivot. The sigmas read here (the hitch angle, the wheel
        scale) are of relative quantities; the anchor moves them by 0.15 % (tests/backend), where
        the last sigma was kept before (30 keyframes of a 29 m/s route)."""
        if not self.joint or not self.config.smoother.marginals:
            return None
        graph = self._smoother.getFactors()
        try:
            return gtsam.Marginals(graph, self._estimate)
        except RuntimeError as error:
            failure = first_line(error)
        try:
            return gtsam.Marginals(_with_gauge_anchor(graph.linearize(self._estimate), self._estimate), self._estimate)
        except RuntimeError as error:
            logger.warning("keyframe %d: marginal covariance not available (%s; %s with the window's position pinned): the last hitch "
                           "sigma is kept", k, failure, first_line(error))
            return None

    def _marginal_sigma(self, key: int) -> float | None:
        """1-sigma of a scalar variable from the last marginals; None without marginals or where
        they cannot give one (RuntimeError; IndexError: a key the marginals' Bayes tree lacks)."""
        if self._marginals is None:
            return None
        try:
            return float(np.sqrt(self._marginals.marginalCovariance(key)[0, 0]))
        except (RuntimeError, IndexError):
            return None

    def _sigma_of(self, index: int) -> float | None:
        """1-sigma of θ at keyframe ``index`` from the last marginals; where they cannot give one
        (a singular window, a key the Bayes tree lacks) the last sigma they gave, or the hitch
        prior's before any: never no sigma, never a smaller one than was known (issue 16).
        ``None`` only without a joint hitch or with marginals disabled."""
        if not self.joint or not self.config.smoother.marginals:
            return None
        sigma = self._marginal_sigma(A(index))
        if sigma is None or not np.isfinite(sigma):
            return self._last_sigma if self._last_sigma is not None else float(np.radians(self.config.smoother.hitch_prior_sigma_deg))
        self._last_sigma = sigma
        return sigma

    def _separate_hitch_angle(self, keyframe: _Keyframe) -> float:
        """θ from the two separately estimated trajectories (module docstring)."""
        k = keyframe.index
        if k in self._separate_hitch and k == 0:
            return self._separate_hitch[k]
        previous = self._separate_hitch.get(k - 1, 0.0)
        if (k - 1) not in self._window:
            self._separate_hitch.setdefault(k, previous)
            return self._separate_hitch[k]
        T_tractor = relative_pose(self._estimate.atPose3(X(k - 1)).matrix(), self._estimate.atPose3(X(k)).matrix())
        T_trailer = relative_pose(self._estimate.atPose3(Y(k - 1)).matrix(), self._estimate.atPose3(Y(k)).matrix())
        if keyframe.init.tractor_status is MotionStatus.STANDSTILL or np.linalg.norm(T_tractor[:2, 3]) < self.config.keyframes.standstill_distance_m:
            hitch = previous
        else:
            hitch_previous = float(wrap_angle(np.arctan2(T_tractor[1, 3], T_tractor[0, 3]) - np.arctan2(T_trailer[1, 3], T_trailer[0, 3])))
            if abs(hitch_previous) > 0.5 * np.pi:
                # beyond jack-knifing: the trailer's own translation came out reversed (its sign is
                # weakly determined by its cameras alone); the hitch moved the other way
                hitch_previous = float(wrap_angle(hitch_previous + np.pi))
            hitch = float(wrap_angle(hitch_previous + yaw_of(T_trailer) - yaw_of(T_tractor)))
        self._separate_hitch[k] = hitch
        for old in [index for index in self._separate_hitch if index < min(self._window, default=k) - 2]:
            del self._separate_hitch[old]
        return hitch

    def _publish(self, keyframe: _Keyframe, sigma: float | None) -> KeyframeEstimate:
        k = keyframe.index
        T_world_tractor = self._estimate.atPose3(X(k)).matrix()
        T_world_trailer = hitch = None
        if self.use_trailer:
            T_world_trailer = self._estimate.atPose3(Y(k)).matrix()
            hitch = self._estimate.atDouble(A(k)) if self.joint else self._separate_hitch.get(k)
        return KeyframeEstimate(
            index=k, frame=keyframe.frame, timestamp=keyframe.timestamp,
            T_world_tractor=T_world_tractor, T_world_trailer=T_world_trailer,
            hitch_angle=None if hitch is None else float(hitch), hitch_sigma=sigma,
            tractor_status=keyframe.init.tractor_status.value, trailer_status=keyframe.init.trailer_status.value,
        )

    def _log_state(self, body: str, status: MotionStatus, keyframe: _Keyframe) -> None:
        """Log state changes (standstill, too few tracks, unobservable scale) once, not per keyframe."""
        previous = self._last_state.get(body)
        if previous == status.value:
            return
        self._last_state[body] = status.value
        if status is MotionStatus.OK:
            if previous is not None:
                logger.info("frame %d: %s motion estimated again (was %s)", keyframe.frame, body, previous)
            return
        messages = {
            MotionStatus.STANDSTILL: "standstill: motion held at zero, hitch angle held (it cannot turn at rest)",
            MotionStatus.TOO_FEW_TRACKS: "too few tracks: motion predicted (constant velocity), weak prior",
            MotionStatus.SCALE_UNOBSERVABLE: "scale unobservable (straight driving): chord from the smooth-speed prior",
        }
        if body == "trailer" and status is not MotionStatus.STANDSTILL:
            message = "no trailer estimate (" + status.value + "): hitch angle predicted by the trailer model, sigma grows"
        elif status is MotionStatus.SCALE_UNOBSERVABLE and body == "tractor" and keyframe.init.scale_chord is not None:
            # not a degraded state: the 2-point chord is unobservable, a measured chord replaces it
            logger.info("frame %d: tractor straight driving: chord from the measured metric chord (ground plane / stereo)", keyframe.frame)
            return
        else:
            message = messages.get(status, status.value)
        logger.warning("frame %d: %s %s", keyframe.frame, body, message)


_GAUGE_SIGMA = 1.0  # m and rad: the pin of _with_gauge_anchor, far looser than any relative constraint in a window


def _with_gauge_anchor(linear: gtsam.GaussianFactorGraph, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
    """``linear`` (the window linearised at ``values``) with a prior of :data:`_GAUGE_SIGMA` on the
    oldest tractor pose's tangent space: it pins the window's absolute position and attitude, which
    only the marginalised prior anchors, and leaves the marginals of relative quantities (the hitch
    angle) all but unchanged (``ArticulatedSmoother._compute_marginals``)."""
    oldest = min(key for key in values.keys() if gtsam.Symbol(key).chr() == ord("x"))
    linear.push_back(gtsam.JacobianFactor(oldest, np.eye(6), np.zeros(6), gtsam.noiseModel.Isotropic.Sigma(6, _GAUGE_SIGMA)))
    return linear
