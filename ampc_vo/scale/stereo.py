"""Metric scale from an overlapping camera pair: the tractor axle chord between two views, measured
from points triangulated by two cameras of one body at the same frame (KITTI left/right, issue 7).

Why: with intra-camera correspondences, metric scale is unobservable in straight driving (DESIGN
2.3). Two cameras of one body that see the same point *in the same frame* (equal
``CameraObservations.landmark_ids``) triangulate it at metric scale with their known baseline; the
point seen again from the other view fixes the length of the motion.

**Derivation** (body frame i, DESIGN 1 conventions). Body motion ``T_i_j = (R, t)`` with the rotation
known and the axle chord ``rho`` unknown; the chord direction ``d`` (unit) is known from the given
motion (DESIGN 2 (NH), ``d ∝ R m + t - m``, axle midpoint ``m = (axle_x, 0, 0)``), so

    t(rho) = rho d + t0,     t0 = m - R m.

A point ``X`` (body frame i, triangulated at frame i) seen at frame j by a camera with centre ``c``
along the body-frame bearing ``g`` satisfies ``g x (R^T (X - t) - c) = 0`` (the ray through the
point), which is linear in ``rho``:

    a - rho b = 0,     a = g x (R^T (X - t0) - c),     b = g x (R^T d)                      (S)

so each observation gives ``rho_k = (a.b) / (b.b)``. The same holds with the views swapped (points
triangulated at j, seen at i, motion ``T_j_i`` whose axle chord has the same length), which
balances the depth errors of the two views.

**Noise.** Per observation, ``sigma_k^2 = sigma_bearing^2 + sigma_point^2`` with the bearing term
``(pixel_sigma / f) |R^T (X - t) - c| / |b|`` (first order of (S) in ``g``) and the point term
``|d rho_k / d Z| sigma_Z``: the triangulation error lies mostly along the first camera's ray
``X = c_a + Z u``; ``d a / d Z = g x R^T u`` and ``sigma_Z = Z^2 sqrt(2) (pixel_sigma / f) /
|B x u|`` (``B`` the pair's baseline). For a point straight ahead ``rho_k`` is off by the relative
depth error ``sigma_Z / Z``: near points (large disparity) are worth most.

**Consensus.** A 1-D MSAC over the ``rho_k`` (each one a hypothesis, up to ``max_hypotheses``; residuals normalised by the
per-observation sigmas; moving objects and mismatched stereo pairs fall out), then the
inverse-variance mean of the consensus set, re-selected a few times. Its sigma is the formal one
inflated by the Birge ratio, with a relative floor (``relative_sigma_floor``: the stereo
calibration's own scale error).

**Yaw and chord together** (:func:`stereo_motion`). Given only a rough guess of the motion (the
2-point solver can fall into the trivial zero-motion basin of the GEC in straight driving, or a
constant-velocity prediction), the consensus chord under the guess selects the inliers, then
Gauss-Newton over the Ackermann parameters (yaw change, chord; DESIGN 2 (NH)) minimises the
angular residuals ``g x (X' - c) / |X' - c|`` of all inlier observations (``X'`` the point moved
into the observing view), each divided by its sigma (bearing noise plus the point's depth error
projected into the view). A planar stereo PnP with the Ackermann constraint: metric yaw and chord.
Without a predicted motion (the first pair of a sequence that starts at speed) the yaw is first
searched on a grid for the consensus chord with the most inliers: from a straight guess, a car
already turning converges to another basin (DESIGN 11, "Metric scale beyond the paper").

**Attitude** (``free_attitude``). The planar motion is then refined to 6 DoF, ``R = Exp(w) R0``,
``t = t0 + v`` around it, on the same residuals, and the chord is the length of the axle's
displacement ``R m + t - m``, its sigma propagated from the fit's covariance. A car or truck pitches
and rolls on its suspension and on the road's grade and crown, and a camera calibrated as level
looks a little down (KITTI's, about 1.2 deg): the vertical part of the motion that the planar model
cannot hold was absorbed by the chord. It lands there amplified: a road point at depth ``Z`` under a
camera ``h`` high moves in the image by ``h rho / Z^2`` per chord ``rho`` and by ``dz / Z`` per
vertical motion ``dz``, so 2 cm of unmodelled vertical motion reads as ``0.02 Z / h`` of chord, 12 %
of a 1 m chord at 10 m. On KITTI's turn clip the planar chords were 7 +- 4 % long (one 27 % long
with a 1.3 % sigma), the 6-DoF ones 4.6 +- 1.3 %, as the stereo-PnP baseline's 4.3 +- 1.5 % (the
clip's calibration against its ground truth). The Ackermann constraint stays with the smoother's
non-holonomic factor.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ampc_vo.geometry import invert_pose, make_pose, rotation_from_vector, triangulate_midpoint, yaw_of
from ampc_vo.scale.ground import axle_chord_direction, axle_displacement
from ampc_vo.observations import FrameObservations
from ampc_vo.rig import Rig
from ampc_vo.observations import match_landmarks
from ampc_vo.solvers.tractor import ackermann_motion

logger = logging.getLogger(__name__)


class StereoScaleStatus(str, Enum):
    """Outcome of a stereo chord measurement (``OK`` or why there is none)."""

    OK = "ok"
    NO_MOTION_DIRECTION = "no_motion_direction"   # the given motion does not move the axle
    NO_STEREO_POINTS = "no_stereo_points"         # no camera pair shares landmarks within a frame
    TOO_FEW_POINTS = "too_few_points"             # too few usable observations or consensus


@dataclass(frozen=True)
class StereoScaleOptions:
    """Options of :func:`stereo_chord` (pixels, metres).

    ``pixel_sigma``: bearing noise, divided by each camera's focal length. ``min_depth_m`` /
    ``max_depth_m``: triangulated points used (far points carry little scale and are biased by any
    disparity error). ``consensus_sigmas``: inlier threshold in per-observation sigmas.
    ``max_relative_point_sigma``: observations whose chord is more uncertain than this share of the
    consensus are ignored. ``min_points``: fewer inliers give no measurement.
    ``relative_sigma_floor``: the returned sigma is at least this share of the chord.
    ``max_hypotheses``: MSAC hypotheses (an evenly spaced subset of the per-observation chords).
    ``free_attitude``: :func:`stereo_motion` refines the planar Ackermann motion to 6 DoF (module
    docstring, "Attitude"); False: the planar motion (the code before, for comparisons).
    """

    pixel_sigma: float = 1.0
    min_depth_m: float = 1.0
    max_depth_m: float = 40.0
    consensus_sigmas: float = 3.0
    max_relative_point_sigma: float = 0.5
    min_points: int = 8
    refine_rounds: int = 3
    relative_sigma_floor: float = 0.01
    max_hypotheses: int = 200
    free_attitude: bool = True


@dataclass(frozen=True)
class StereoPoints:
    """Points of one frame triangulated by camera pairs of one body: ``landmark_ids`` (N,),
    ``points`` (N, 3) body frame, ``rays`` (N, 3) unit body-frame rays of the first camera,
    ``depths`` (N,) along them, ``depth_sigmas`` (N,)."""

    landmark_ids: np.ndarray
    points: np.ndarray
    rays: np.ndarray
    depths: np.ndarray
    depth_sigmas: np.ndarray

    def __len__(self) -> int:
        return int(self.landmark_ids.shape[0])


@dataclass(frozen=True)
class StereoChord:
    """Result of :func:`stereo_chord`: the metric chord of the axle midpoint and its 1-sigma
    (metres), or ``None`` with ``status`` saying why; ``inliers``/``candidates``: counts."""

    status: StereoScaleStatus
    chord: float | None = None
    sigma: float | None = None
    inliers: int = 0
    candidates: int = 0

    @property
    def ok(self) -> bool:
        return self.status is StereoScaleStatus.OK

    def as_scale_chord(self) -> tuple[float, float] | None:
        """``(|chord|, sigma)`` for :class:`ampc_vo.backend.smoother.MotionInit.scale_chord`, or ``None``
        (a negative chord means the motion's direction was reversed; the length still holds)."""
        return (abs(float(self.chord)), float(self.sigma)) if self.ok else None


def stereo_points(rig: Rig, body: str, frame: FrameObservations, options: StereoScaleOptions = StereoScaleOptions()) -> StereoPoints:
    """Triangulate the landmarks that two cameras of ``body`` see in ``frame`` (midpoint method),
    keeping ``min_depth_m <= depth <= max_depth_m``; a landmark seen by several pairs is kept once
    (the first pair in rig order)."""
    ids, points, rays, depths, sigmas = [], [], [], [], []
    cameras = [camera for camera in rig.cameras_on(body) if len(frame.cameras.get(camera.name, ())) > 0]
    for index, first_camera in enumerate(cameras):
        first = frame.cameras[first_camera.name]
        for second_camera in cameras[index + 1:]:
            second = frame.cameras[second_camera.name]
            index_first, index_second = match_landmarks(first, second)
            if index_first.size == 0:
                continue
            T_first_second = invert_pose(first_camera.T_body_camera) @ second_camera.T_body_camera
            points_first, depth = triangulate_midpoint(first.bearings[index_first], second.bearings[index_second], T_first_second)
            keep = np.isfinite(depth) & (depth >= options.min_depth_m) & (depth <= options.max_depth_m)
            ray = first.bearings[index_first[keep]] @ first_camera.R_body_camera.T
            baseline = second_camera.center - first_camera.center
            perpendicular = np.linalg.norm(np.cross(ray, baseline), axis=1)
            angle_sigma = options.pixel_sigma / (0.5 * (first_camera.fx + first_camera.fy))
            ids.append(first.landmark_ids[index_first[keep]])
            points.append(points_first[keep] @ first_camera.R_body_camera.T + first_camera.center)
            rays.append(ray)
            depths.append(depth[keep])
            sigmas.append(depth[keep] ** 2 * np.sqrt(2.0) * angle_sigma / np.maximum(perpendicular, 1e-9))
    if not ids:
        return StereoPoints(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    all_ids = np.concatenate(ids)
    _, first_occurrence = np.unique(all_ids, return_index=True)
    first_occurrence = np.sort(first_occurrence)
    return StereoPoints(all_ids[first_occurrence], np.concatenate(points)[first_occurrence], np.concatenate(rays)[first_occurrence],
                        np.concatenate(depths)[first_occurrence], np.concatenate(sigmas)[first_occurrence])


def point_chords(rig: Rig, body: str, points: StereoPoints, other: FrameObservations, T_i_j: np.ndarray, axle_x: float,
                 options: StereoScaleOptions = StereoScaleOptions()) -> tuple[np.ndarray, np.ndarray]:
    """Per-observation chords (S) and sigmas (module docstring) of ``points`` (body frame i) seen
    in ``other`` (view j) by the cameras of ``body``, for the motion ``T_i_j``; empty arrays when
    the motion does not move the axle."""
    direction = axle_chord_direction(T_i_j, axle_x)
    if direction is None or len(points) == 0:
        return np.zeros(0), np.zeros(0)
    rotation = T_i_j[:3, :3]
    axle = np.array([axle_x, 0.0, 0.0])
    t0 = axle - rotation @ axle
    chords, sigmas = [], []
    for camera in rig.cameras_on(body):
        observations = other.cameras.get(camera.name)
        if observations is None or observations.landmark_ids is None or len(observations) == 0:
            continue
        _, index_points, index_observations = np.intersect1d(points.landmark_ids, observations.landmark_ids, return_indices=True)
        if index_points.size == 0:
            continue
        g = observations.bearings[index_observations] @ camera.R_body_camera.T      # body frame j
        in_j = (points.points[index_points] - t0) @ rotation                        # R^T (X - t0)
        a = np.cross(g, in_j - camera.center)
        b = np.cross(g, direction @ rotation)                                        # g x R^T d
        bb = np.einsum("na,na->n", b, b)
        with np.errstate(divide="ignore", invalid="ignore"):
            chord = np.einsum("na,na->n", a, b) / bb
            distance = np.linalg.norm(in_j - chord[:, None] * (direction @ rotation) - camera.center, axis=1)
            bearing_sigma = options.pixel_sigma / (0.5 * (camera.fx + camera.fy)) * distance / np.sqrt(bb)
            a_by_depth = np.cross(g, points.rays[index_points] @ rotation)
            point_sigma = np.abs(np.einsum("na,na->n", a_by_depth, b) / bb) * points.depth_sigmas[index_points]
        chords.append(chord)
        sigmas.append(np.hypot(bearing_sigma, point_sigma))
    if not chords:
        return np.zeros(0), np.zeros(0)
    chords_all, sigmas_all = np.concatenate(chords), np.concatenate(sigmas)
    usable = np.isfinite(chords_all) & np.isfinite(sigmas_all) & (sigmas_all > 0)
    return chords_all[usable], sigmas_all[usable]


def consensus_chord(chords: np.ndarray, sigmas: np.ndarray, options: StereoScaleOptions = StereoScaleOptions()) -> tuple[float, float, int] | None:
    """1-D MSAC over per-observation chords with sigmas (module docstring): ``(chord, sigma,
    inlier count)`` or ``None`` with fewer than ``min_points`` inliers."""
    count = chords.shape[0]
    if count < options.min_points:
        return None
    threshold = options.consensus_sigmas
    hypotheses = chords if count <= options.max_hypotheses else chords[np.linspace(0, count - 1, options.max_hypotheses).astype(int)]
    normalized = (chords[None, :] - hypotheses[:, None]) / sigmas[None, :]
    cost = np.minimum(normalized**2, threshold**2).sum(axis=1)
    estimate = float(hypotheses[int(np.argmin(cost))])
    inliers = np.zeros(count, bool)
    for _ in range(options.refine_rounds + 1):
        inliers = (np.abs(chords - estimate) < threshold * sigmas) & (sigmas < options.max_relative_point_sigma * abs(estimate))
        if np.count_nonzero(inliers) < options.min_points:
            return None
        weights = 1.0 / sigmas[inliers] ** 2
        estimate = float(np.sum(weights * chords[inliers]) / np.sum(weights))
    used = int(np.count_nonzero(inliers))
    formal = 1.0 / np.sqrt(np.sum(weights))
    birge = np.sqrt(np.sum(weights * (chords[inliers] - estimate) ** 2) / max(used - 1, 1))
    sigma = max(formal * max(1.0, birge), options.relative_sigma_floor * abs(estimate))
    return estimate, float(sigma), used


def stereo_chord(rig: Rig, body: str, first: FrameObservations, second: FrameObservations, T_i_j: np.ndarray, axle_x: float,
                 options: StereoScaleOptions = StereoScaleOptions()) -> StereoChord:
    """The axle chord of ``T_i_j`` (first -> second view of ``body``) at metric scale from the
    landmarks triangulated within each view (module docstring)."""
    if axle_chord_direction(T_i_j, axle_x) is None:
        return StereoChord(StereoScaleStatus.NO_MOTION_DIRECTION)
    return _chord_of_points(rig, body, stereo_points(rig, body, first, options), stereo_points(rig, body, second, options), first, second,
                            T_i_j, axle_x, options)


def _chord_of_points(rig: Rig, body: str, points_first: StereoPoints, points_second: StereoPoints, first: FrameObservations,
                     second: FrameObservations, T_i_j: np.ndarray, axle_x: float, options: StereoScaleOptions) -> StereoChord:
    """:func:`stereo_chord` with the views' stereo points already triangulated (``points_first``,
    ``points_second``: :func:`stereo_points` of ``first`` and ``second``)."""
    if axle_chord_direction(T_i_j, axle_x) is None:
        return StereoChord(StereoScaleStatus.NO_MOTION_DIRECTION)
    if len(points_first) == 0 and len(points_second) == 0:
        return StereoChord(StereoScaleStatus.NO_STEREO_POINTS)
    forward = point_chords(rig, body, points_first, second, T_i_j, axle_x, options)
    backward = point_chords(rig, body, points_second, first, invert_pose(T_i_j), axle_x, options)
    chords, sigmas = np.concatenate([forward[0], backward[0]]), np.concatenate([forward[1], backward[1]])
    result = consensus_chord(chords, sigmas, options)
    if result is None:
        return StereoChord(StereoScaleStatus.TOO_FEW_POINTS, candidates=int(chords.shape[0]))
    chord, sigma, used = result
    return StereoChord(StereoScaleStatus.OK, chord, sigma, used, int(chords.shape[0]))


@dataclass(frozen=True)
class StereoMotion:
    """Result of :func:`stereo_motion`: Ackermann ``yaw_change`` (rad), axle ``chord`` and its
    ``chord_sigma`` (m), ``T_i_j``; ``None`` values with ``status`` saying why there is none."""

    status: StereoScaleStatus
    yaw_change: float | None = None
    chord: float | None = None
    chord_sigma: float | None = None
    T_i_j: np.ndarray | None = None
    inliers: int = 0

    @property
    def ok(self) -> bool:
        return self.status is StereoScaleStatus.OK

    def as_scale_chord(self) -> tuple[float, float] | None:
        return (abs(float(self.chord)), float(self.chord_sigma)) if self.ok else None


@dataclass(frozen=True)
class _Sightings:
    """Stereo points of one view seen from the other view: ``points`` (N, 3) and ``rays`` (N, 3) in
    the source view's body frame, ``depth_sigmas`` (N,), body-frame ``bearings`` (N, 3) and camera
    ``centers`` (N, 3) of the observing view, ``angle_sigmas`` (N,), ``backward`` (N,): the points
    were triangulated in the second view and are seen from the first."""

    points: np.ndarray
    rays: np.ndarray
    depth_sigmas: np.ndarray
    bearings: np.ndarray
    centers: np.ndarray
    angle_sigmas: np.ndarray
    backward: np.ndarray


def _sightings(rig: Rig, body: str, points: StereoPoints, other: FrameObservations, backward: bool, options: StereoScaleOptions) -> list[tuple]:
    parts = []
    for camera in rig.cameras_on(body):
        observations = other.cameras.get(camera.name)
        if observations is None or observations.landmark_ids is None or len(observations) == 0 or len(points) == 0:
            continue
        _, index_points, index_observations = np.intersect1d(points.landmark_ids, observations.landmark_ids, return_indices=True)
        if index_points.size == 0:
            continue
        count = index_points.size
        parts.append((points.points[index_points], points.rays[index_points], points.depth_sigmas[index_points],
                      observations.bearings[index_observations] @ camera.R_body_camera.T, np.tile(camera.center, (count, 1)),
                      np.full(count, options.pixel_sigma / (0.5 * (camera.fx + camera.fy))), np.full(count, backward)))
    return parts


def _all_sightings(rig: Rig, body: str, points_first: StereoPoints, points_second: StereoPoints, first: FrameObservations,
                   second: FrameObservations, options: StereoScaleOptions) -> _Sightings | None:
    parts = _sightings(rig, body, points_first, second, False, options)
    parts += _sightings(rig, body, points_second, first, True, options)
    if not parts:
        return None
    return _Sightings(*(np.concatenate([part[index] for part in parts]) for index in range(7)))


def _motion_residuals(sightings: _Sightings, T_i_j: np.ndarray) -> np.ndarray:
    """Whitened angular residuals (N, 3) of the sightings under the motion ``T_i_j = (R, t)``
    (module docstring, "Yaw and chord together"): a forward sighting's point moves into view j as
    ``R^T (X - t)``, a backward one's into view i as ``R X + t``."""
    rotation, translation = T_i_j[:3, :3], T_i_j[:3, 3]
    forward = ~sightings.backward
    moved = np.empty_like(sightings.points)
    moved[forward] = (sightings.points[forward] - translation) @ rotation            # R^T (X - t)
    moved[~forward] = sightings.points[~forward] @ rotation.T + translation           # R X + t
    moved_rays = np.empty_like(sightings.rays)
    moved_rays[forward] = sightings.rays[forward] @ rotation
    moved_rays[~forward] = sightings.rays[~forward] @ rotation.T
    offset = moved - sightings.centers
    distance = np.linalg.norm(offset, axis=1)
    residual = np.cross(sightings.bearings, offset) / distance[:, None]
    point_angle = np.linalg.norm(np.cross(sightings.bearings, moved_rays), axis=1) * sightings.depth_sigmas / distance
    sigma = np.hypot(sightings.angle_sigmas, point_angle)
    return residual / sigma[:, None]


def _angular_residuals(sightings: _Sightings, yaw_change: float, chord: float, axle_x: float) -> np.ndarray:
    """:func:`_motion_residuals` of the Ackermann motion (DESIGN 2 (NH)) of ``yaw_change`` and ``chord``."""
    return _motion_residuals(sightings, make_pose(*ackermann_motion(yaw_change, chord, axle_x)))


def _subset(sightings: _Sightings, keep: np.ndarray) -> _Sightings:
    return _Sightings(*(getattr(sightings, name)[keep] for name in _Sightings.__dataclass_fields__))


@dataclass(frozen=True)
class _Fit:
    """A Gauss-Newton fit of motion parameters to the inlier sightings (:func:`_gauss_newton`)."""

    parameters: np.ndarray
    covariance: np.ndarray
    inliers: int


_STEP = 1e-6   # forward-difference step of the Jacobians (radians, metres)


def _gauss_newton(residuals: Callable[[np.ndarray, _Sightings], np.ndarray], parameters: np.ndarray, sightings: _Sightings,
                  options: StereoScaleOptions, iterations: int) -> _Fit | StereoScaleStatus:
    """Gauss-Newton over ``parameters`` of the whitened angular ``residuals(parameters, sightings)``
    of the inlier sightings (below ``consensus_sigmas``, re-selected after every step), from the
    given start; the covariance is the inverse normal matrix times the variance factor (at least 1;
    each angular residual has 2 degrees of freedom). ``TOO_FEW_POINTS`` with fewer than
    ``min_points`` inliers or a singular normal matrix."""
    threshold = options.consensus_sigmas

    def inliers_of(values: np.ndarray) -> np.ndarray:
        return np.linalg.norm(residuals(values, sightings), axis=1) < threshold

    def linearised(values: np.ndarray, subset: _Sightings) -> tuple[np.ndarray, np.ndarray]:
        residual = residuals(values, subset).ravel()
        jacobian = np.stack([(residuals(values + _STEP * unit, subset).ravel() - residual) / _STEP for unit in np.eye(values.size)], axis=1)
        return residual, jacobian

    parameters = np.asarray(parameters, dtype=float)
    inliers = inliers_of(parameters)
    for _ in range(iterations):
        if np.count_nonzero(inliers) < options.min_points:
            return StereoScaleStatus.TOO_FEW_POINTS
        residual, jacobian = linearised(parameters, _subset(sightings, inliers))
        try:
            update = -np.linalg.solve(jacobian.T @ jacobian, jacobian.T @ residual)
        except np.linalg.LinAlgError:
            return StereoScaleStatus.TOO_FEW_POINTS
        parameters = parameters + update
        inliers = inliers_of(parameters)
        if np.all(np.abs(update) < 1e-7):
            break
    used = int(np.count_nonzero(inliers))
    if used < options.min_points:
        return StereoScaleStatus.TOO_FEW_POINTS
    residual, jacobian = linearised(parameters, _subset(sightings, inliers))
    variance_factor = max(1.0, float(residual @ residual) / max(residual.size - used - parameters.size, 1))
    return _Fit(parameters, np.linalg.pinv(jacobian.T @ jacobian) * variance_factor, used)


def _along_heading(vector: np.ndarray, yaw_change: float) -> bool:
    """Whether ``vector`` points along the mean heading ``u(yaw_change / 2)`` of an arc (forwards)."""
    return float(vector @ np.array([np.cos(0.5 * yaw_change), np.sin(0.5 * yaw_change), 0.0])) >= 0.0


def stereo_motion(rig: Rig, body: str, first: FrameObservations, second: FrameObservations, T_guess: np.ndarray, axle_x: float,
                  options: StereoScaleOptions = StereoScaleOptions(), iterations: int = 5, yaw_search: float = 0.0) -> StereoMotion:
    """The motion of ``body`` between two views and its axle chord from stereo points (module
    docstring, "Yaw and chord together" and "Attitude"); ``T_guess`` gives the initial yaw and
    direction. ``yaw_search`` (radians): where the guess's yaw is not a prediction (the first pair of
    a sequence that starts at speed, perhaps in a turn), the yaw within +- ``yaw_search`` of it whose
    consensus chord has the most inliers starts the refinement (:func:`_searched_guess`)."""
    if axle_chord_direction(T_guess, axle_x) is None:
        return StereoMotion(StereoScaleStatus.NO_MOTION_DIRECTION)
    points = stereo_points(rig, body, first, options), stereo_points(rig, body, second, options)   # each view triangulated once
    if yaw_search > 0.0:
        T_guess = _searched_guess(rig, body, points, first, second, T_guess, axle_x, options, yaw_search)
    guess = _chord_of_points(rig, body, *points, first, second, T_guess, axle_x, options)
    if not guess.ok:
        return StereoMotion(guess.status)
    sightings = _all_sightings(rig, body, *points, first, second, options)
    yaw_change = float(np.arctan2(T_guess[1, 0], T_guess[0, 0]))
    direction = axle_chord_direction(T_guess, axle_x)
    chord = float(guess.chord) * (1.0 if direction is None or _along_heading(direction, yaw_change) else -1.0)
    planar = _gauss_newton(lambda values, subset: _angular_residuals(subset, values[0], values[1], axle_x), np.array([yaw_change, chord]),
                           sightings, options, iterations)
    if not isinstance(planar, _Fit):
        return StereoMotion(planar, inliers=0)
    yaw_change, chord = (float(value) for value in planar.parameters)
    rotation, translation = ackermann_motion(yaw_change, chord, axle_x)
    sigma, used = float(np.sqrt(planar.covariance[1, 1])), planar.inliers
    if options.free_attitude:
        free = _free_motion(sightings, rotation, translation, axle_x, options, iterations)
        if free is not None:
            T_free, sigma, used = free
            displacement = axle_displacement(T_free, axle_x)
            yaw_change = yaw_of(T_free[:3, :3])
            chord = (1.0 if _along_heading(displacement, yaw_change) else -1.0) * float(np.linalg.norm(displacement))
            return StereoMotion(StereoScaleStatus.OK, yaw_change, chord, max(sigma, options.relative_sigma_floor * abs(chord)), T_free, used)
    return StereoMotion(StereoScaleStatus.OK, yaw_change, chord, max(sigma, options.relative_sigma_floor * abs(chord)),
                        make_pose(rotation, translation), used)


def _free_motion(sightings: _Sightings, rotation: np.ndarray, translation: np.ndarray, axle_x: float, options: StereoScaleOptions,
                 iterations: int) -> tuple[np.ndarray, float, int] | None:
    """The 6-DoF motion refined from the planar Ackermann one (module docstring, "Attitude"):
    ``R = Exp(w) R0``, ``t = t0 + v``; returns ``(T_i_j, sigma of the axle chord, inliers)``, or
    ``None`` where the refinement fails (the planar motion then stands)."""

    def motion(values: np.ndarray) -> np.ndarray:
        return make_pose(rotation_from_vector(values[:3]) @ rotation, translation + values[3:])

    fit = _gauss_newton(lambda values, subset: _motion_residuals(subset, motion(values)), np.zeros(6), sightings, options, iterations)
    if not isinstance(fit, _Fit):
        return None
    length = float(np.linalg.norm(axle_displacement(motion(fit.parameters), axle_x)))
    gradient = np.array([(np.linalg.norm(axle_displacement(motion(fit.parameters + _STEP * unit), axle_x)) - length) / _STEP
                         for unit in np.eye(6)])
    return motion(fit.parameters), float(np.sqrt(max(gradient @ fit.covariance @ gradient, 0.0))), fit.inliers


_YAW_SEARCH_STEP = np.radians(0.5)  # finer than the yaw basin of the consensus chord (side points' chords move ~2 %/0.1 deg)


def _searched_guess(rig: Rig, body: str, points: tuple[StereoPoints, StereoPoints], first: FrameObservations, second: FrameObservations,
                    T_guess: np.ndarray, axle_x: float, options: StereoScaleOptions, yaw_search: float) -> np.ndarray:
    """The Ackermann motion (unit chord, the guess's direction of travel) whose yaw change, within
    ``yaw_search`` of the guess's in steps of :data:`_YAW_SEARCH_STEP`, gives the consensus chord
    (:func:`stereo_chord`; ``points``: both views' stereo points) the most inliers: a wrong yaw
    spreads the per-point chords of points off the motion's direction (module docstring (S)), so
    the consensus then holds few of them. ``T_guess`` where no yaw gives a chord."""
    yaw_guess = float(np.arctan2(T_guess[1, 0], T_guess[0, 0]))
    direction = axle_chord_direction(T_guess, axle_x)
    sign = 1.0 if direction is None or float(direction[0]) >= 0.0 else -1.0
    best_count, best = 0, T_guess
    for yaw_change in yaw_guess + np.arange(-yaw_search, yaw_search + 1e-12, _YAW_SEARCH_STEP):
        candidate = np.eye(4)
        candidate[:3, :3], candidate[:3, 3] = ackermann_motion(yaw_change, sign, axle_x)
        measured = _chord_of_points(rig, body, *points, first, second, candidate, axle_x, options)
        if measured.ok and measured.inliers > best_count:
            best_count, best = measured.inliers, candidate
    return best
