"""RANSAC estimators around the minimal solvers (DESIGN 2.1, 2.2, section 4).

* :func:`estimate_tractor_motion`: 2-point Ackermann solver, samples mixed over cameras; scale-free
  1-point fallback when every camera is above the axle.
* :func:`estimate_hitch_angles`: 1-point trailer solver given the tractor motion, consensus and
  continuity with the previous hitch angle.

Hypotheses are scored in batches with the vectorised Sampson residual (:mod:`ampc_vo.epipolar`)
and a cheirality check, with the MSAC truncated quadratic cost; the iteration count adapts to the
inlier ratio. The best hypothesis is refined over its inliers (:mod:`ampc_vo.solvers.refine`).
Degenerate input returns a :class:`SolverStatus`, never an exception or a silently wrong number.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ampc_vo.geometry import make_pose
from ampc_vo.solvers.attitude import attitude_motion, estimate_attitude_motion
from ampc_vo.solvers.noise import MAD_TO_SIGMA, correspondence_noise
from ampc_vo.solvers.refine import refine_tractor, refine_tractor_batch, refine_trailer_yaw, sampson_residuals
from ampc_vo.solvers.status import SolverStatus
from ampc_vo.solvers.tractor import ackermann_motion, tractor_motion_2pt_batch, tractor_yaw_1pt_batch
from ampc_vo.solvers.trailer import hitch_angles_1pt_batch, positive_depth, trailer_motion_from_yaw
from ampc_vo.solvers.estimates import (
    STILL_PARALLAX_SIGMAS,
    Group,
    HitchEstimate,
    RansacConfig,
    TractorMotionEstimate,
    as_groups,
    attitude_compensated_parallax,
    chord_is_observable,
    median_parallax,
    parallax,
)

logger = logging.getLogger(__name__)

_TIGHTEST_TURN_RADIUS_M = 4.0  # below any truck's rear-axle turning radius (about 6-9 m for tractors)
_SAMPLE_YAW_TOLERANCE = float(np.radians(0.3))  # yaw noise of a 2-point sample, beside that radius


# ---------------------------------------------------------------------- scoring
def _score(
    groups: Sequence[Group], rotation: np.ndarray, translation: np.ndarray, threshold: float, check_top: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """MSAC cost (H,) and inlier matrix (H, M) of H hypotheses over all groups' correspondences.

    The truncated quadratic of the Sampson residual ranks all hypotheses; the ``check_top`` best
    are then re-scored with the cheirality check (a point behind either camera is an outlier) and
    the others get an infinite cost (they cannot win this batch).
    """
    residual = sampson_residuals(groups, rotation, translation)
    inliers = np.abs(residual) < threshold
    cost = np.sum(np.where(inliers, residual * residual, threshold * threshold), axis=1)
    top = np.argsort(cost)[:check_top]
    rotation_top, translation_top = rotation[top], translation[top]
    cheiral = np.concatenate(
        [positive_depth(g.bearings_i, g.bearings_j, rotation_top, translation_top, g.center) for g in groups if len(g)], axis=-1
    )
    inliers[top] &= cheiral
    checked = np.full(len(cost), np.inf)
    checked[top] = np.sum(np.where(inliers[top], residual[top] ** 2, threshold * threshold), axis=1)
    return checked, inliers


def _required_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> float:
    """Classic adaptive RANSAC iteration count ``log(1 - p) / log(1 - w^s)``."""
    good = inlier_ratio**sample_size
    if good >= 1.0 - 1e-12:
        return 1.0
    if good <= 1e-12:
        return float("inf")
    return float(np.log(1.0 - confidence) / np.log(1.0 - good))


def _split(flat_mask: np.ndarray, groups: Sequence[Group]) -> list[np.ndarray]:
    """Cut a mask over the stacked valid correspondences into per-group full-length masks."""
    masks, start = [], 0
    for group in groups:
        masks.append(group.full_mask(flat_mask[start : start + len(group)]))
        start += len(group)
    return masks


def _stack(groups: Sequence[Group]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    bearings_i = np.concatenate([g.bearings_i for g in groups] or [np.zeros((0, 3))])
    bearings_j = np.concatenate([g.bearings_j for g in groups] or [np.zeros((0, 3))])
    centers = np.concatenate([np.broadcast_to(g.center, (len(g), 3)) for g in groups] or [np.zeros((0, 3))])
    return bearings_i, bearings_j, centers


# ---------------------------------------------------------------------- tractor
Hypothesis = tuple[float, float, float, np.ndarray]  # (MSAC cost, yaw change, chord, inliers over the stacked points)


def estimate_tractor_motion(
    correspondences: Sequence[Any],
    axle_x: float,
    config: RansacConfig | None = None,
    chord_prior: float | None = None,
    rng: np.random.Generator | None = None,
    moving: bool = False,
    direction: float | None = None,
) -> TractorMotionEstimate:
    """Tractor motion from per-camera correspondences by RANSAC over the 2-point solver (DESIGN 2.1).

    ``correspondences``: one entry per tractor camera, ``(bearings_i (N, 3), bearings_j (N, 3),
    center (3,))`` in the tractor frame (or an object with ``as_group()``); samples mix cameras.
    ``axle_x``: tractor axle. Steps: adaptive RANSAC with MSAC scoring; local optimisation of the
    best hypotheses and of chord-scaled seeds (LO-RANSAC, least squares over inliers); scale
    checks. ``chord_prior`` (metres, e.g. wheel odometry; its sign, where it has one, is the direction
    of travel of a pair whose chord was not measured) is used only when the scale is
    unobservable (straight driving, cameras above the axle, ambiguous chord): the status stays
    ``SCALE_UNOBSERVABLE`` but ``chord`` and ``T_i_j`` are then filled with it. ``moving``: the
    truck is known to move (it could not have stopped within the pair): no standstill test, and
    correspondences without parallax (on the vehicle itself, e.g. the trailer's box in a mirror, or
    far on the line of motion) are left out. ``direction`` (+1 forward, -1 backward; None:
    either): the sign the chord must have when the truck could not have changed its direction
    of travel within the pair (at speed it must brake to rest first); hypotheses against it are
    not drivable (traffic moving with the truck looks like its reverse). Where it could have
    stopped, a reversal against the prior with an unmeasured chord whose tracks only pitched and
    rolled is a standstill (:func:`_unless_only_pitched`).
    """
    config = config or RansacConfig()
    rng = rng if rng is not None else np.random.default_rng(config.seed)
    groups = as_groups(correspondences)
    empty_masks = [np.zeros(g.size, dtype=bool) for g in groups]
    total = sum(len(g) for g in groups)
    if total < max(2, config.min_inliers):
        return TractorMotionEstimate(SolverStatus.TOO_FEW_POINTS, inlier_masks=empty_masks)
    if moving:
        groups = [group.subset(parallax(group) >= config.standstill_parallax) for group in groups]
        if sum(len(g) for g in groups) < max(2, config.min_inliers):
            return TractorMotionEstimate(SolverStatus.TOO_FEW_POINTS, inlier_masks=empty_masks)
    planar = _estimate_planar(groups, empty_masks, axle_x, config, chord_prior, rng, moving, direction)
    if planar.status is SolverStatus.STANDSTILL and not moving and not np.isfinite(planar.noise_still_parallax) \
            and median_parallax(groups) >= config.standstill_parallax and _translated(groups, chord_prior, config):
        # the tracks moved, but the refinement shrank the chord below min_chord (straight driving:
        # no tracks fix it); a truck that was moving and whose tracks translated is known to move:
        # estimated again as such, its still tracks left out (as when a standstill is not reachable)
        logger.debug("chord refined to %.3f m with translated tracks and a moving prediction: estimated as moving", planar.chord)
        return estimate_tractor_motion(correspondences, axle_x, config, chord_prior, rng, moving=True, direction=direction)
    if config.max_attitude_change <= 0.0 or planar.status is SolverStatus.STANDSTILL:
        estimate = planar
    else:
        estimate = _with_attitude(groups, planar, axle_x, config, chord_prior, direction)
    if moving or direction is not None:
        return estimate
    return _unless_only_pitched(groups, estimate, config, chord_prior)


def _unless_only_pitched(groups: Sequence[Group], estimate: TractorMotionEstimate, config: RansacConfig,
                         chord_prior: float | None) -> TractorMotionEstimate:
    """A standstill instead of ``estimate`` where that turns the truck's direction of travel
    against the prediction's (``chord_prior``'s sign) without measuring its chord while the tracks
    moved no more than a body pitching and rolling at rest explains
    (:func:`attitude_compensated_parallax` below ``standstill_parallax``): the rebound of the
    suspension after a stop moves every bearing by pixels, and the cheirality of a short baseline
    then votes for either sign. A truck that could not have stopped (``moving``, a ``direction``)
    is not asked."""
    if estimate.status is not SolverStatus.SCALE_UNOBSERVABLE or chord_prior is None or not np.isfinite(chord_prior):
        return estimate
    if estimate.chord_sign * np.sign(chord_prior) >= 0.0:
        return estimate
    if not _only_pitched(groups, config):
        return estimate
    logger.debug("a reversal with an unmeasured chord whose tracks only pitched and rolled: a standstill")
    return _standstill(groups)


def _standstill(groups: Sequence[Group]) -> TractorMotionEstimate:
    """A standstill (no motion) with every correspondence of ``groups`` an inlier."""
    every = [group.full_mask(np.ones(len(group), dtype=bool)) for group in groups]
    return TractorMotionEstimate(SolverStatus.STANDSTILL, 0.0, 0.0, np.eye(4), every, sum(len(group) for group in groups))


def _with_attitude(groups: Sequence[Group], planar: TractorMotionEstimate, axle_x: float, config: RansacConfig,
                   chord_prior: float | None, direction: float | None) -> TractorMotionEstimate:
    """The planar estimate, or where it explains less than ``attitude_fraction`` of the
    correspondences, a motion with a pitch and roll change (:mod:`ampc_vo.solvers.attitude`) if that
    explains clearly more (``_ATTITUDE_GAIN`` times the inliers). Its chord is not taken from the
    tracks (the attitude change and the chord trade off): ``SCALE_UNOBSERVABLE`` with the prior's
    chord, as in straight driving; without a prior of at least ``min_chord`` nothing is searched.
    Without a ``direction`` both signs of the prior's chord are searched (the truck may have stopped
    and changed its direction within the pair)."""
    total = sum(len(group) for group in groups)
    if total == 0 or planar.num_inliers >= config.attitude_fraction * total:
        return planar
    known = chord_prior is not None and np.isfinite(chord_prior) and abs(chord_prior) >= config.min_chord
    if not known:  # a truck predicted at rest: a fixed chord near zero fits any still tracks (traffic, its own body)
        return planar
    measured = planar.status in (SolverStatus.OK, SolverStatus.SCALE_UNOBSERVABLE)
    likely = direction if direction is not None else planar.chord_sign if measured else float(np.sign(chord_prior))
    # where the truck could have changed its direction of travel, the tracks decide it: a drive-off
    # after reversing, predicted backwards, is searched forwards too (the likely sign keeps ties)
    found, sign = None, likely
    for candidate in ([likely] if direction is not None else [likely, -likely]):
        chord = candidate * abs(float(chord_prior))
        seeds = [(planar.yaw_change if np.isfinite(planar.yaw_change) else 0.0, chord)]
        if np.isfinite(planar.yaw_change) and planar.yaw_change != 0.0:
            seeds.append((0.0, chord))
        attempt = estimate_attitude_motion(groups, seeds, axle_x, config.sampson_threshold, config.max_attitude_change, fix_chord=True,
                                           iterations=config.refine_iterations)
        if attempt is not None and (found is None or np.sum(attempt.inliers) > np.sum(found.inliers)):
            found, sign = attempt, candidate
    if found is None or np.sum(found.inliers) < max(_least_inliers(groups, config), _ATTITUDE_GAIN * planar.num_inliers):
        return planar
    logger.debug("attitude change in a pair: pitch %.2f deg, roll %.2f deg, %d of %d inliers (planar: %d)", np.degrees(found.pitch),
                 np.degrees(found.roll), int(np.sum(found.inliers)), total, planar.num_inliers)
    T_i_j = make_pose(*attitude_motion(found.yaw_change, found.chord, found.pitch, found.roll, axle_x))
    return TractorMotionEstimate(
        SolverStatus.SCALE_UNOBSERVABLE, found.yaw_change, found.chord, T_i_j, _split(found.inliers, groups),
        int(np.sum(found.inliers)), planar.num_hypotheses, found.yaw_sigma, float("inf"), sign, float("nan"), (found.pitch, found.roll),
    )


def _estimate_planar(groups: Sequence[Group], empty_masks: list[np.ndarray], axle_x: float, config: RansacConfig, chord_prior: float | None,
                     rng: np.random.Generator, moving: bool, direction: float | None) -> TractorMotionEstimate:
    """The planar motion (``R = Rz(phi)``) of :func:`estimate_tractor_motion` (``groups`` already
    without the still correspondences when ``moving``)."""
    parallax = median_parallax(groups)
    if not moving and parallax < config.standstill_parallax:
        return _standstill(groups)
    bearings_i, bearings_j, centers = _stack(groups)
    scale_capable = np.abs(centers[:, 0] - axle_x) > config.min_camera_axle_offset
    if not np.any(scale_capable):
        return _tractor_scale_free(groups, bearings_i, bearings_j, axle_x, config, chord_prior, rng)

    pool, drawn = _sample_tractor_hypotheses(groups, bearings_i, bearings_j, centers, np.flatnonzero(scale_capable), axle_x, config, rng,
                                             direction)
    if not pool or np.sum(pool[0][3]) < config.min_inliers:
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    _, yaw_change, chord, inliers = pool[0]
    if not config.refine:
        T_i_j = make_pose(*ackermann_motion(yaw_change, chord, axle_x))
        return TractorMotionEstimate(SolverStatus.OK, yaw_change, chord, T_i_j, _split(inliers, groups), int(np.sum(inliers)), drawn,
                                     chord_sign=float(np.sign(chord) or 1.0))
    refined = _local_optimization(groups, pool, axle_x, config)
    if direction is not None:  # a chord seed or the refinement may cross zero
        refined = [model for model in refined if model[2] * direction > 0.0]
        if not refined:
            return _scale_unobservable(groups, pool[0], axle_x, config, chord_prior, drawn, float("inf"))
    cost, refined_yaw, refined_chord, covariance, rms, refined_inliers, start = refined[0]
    if not moving:
        still = _noise_standstill(groups, parallax, [(model[1], model[2]) for model in refined] + [(pool[0][1], pool[0][2])], axle_x)
        if still is not None:
            logger.debug("median parallax %.2e rad within the tracks' own noise (still below %.2e rad): a standstill", parallax, still)
            return dataclasses.replace(_standstill(groups), num_hypotheses=drawn, noise_still_parallax=still)
    chord_sigma = float(np.sqrt(covariance[1, 1])) if np.isfinite(covariance[1, 1]) else float("inf")
    if config.chord_direction_sigma > 0.0:  # the model's share (RansacConfig): dominant at small yaw changes
        lever = float(np.max(np.abs(centers[scale_capable, 0] - axle_x)))
        chord_sigma = float(np.hypot(chord_sigma, refined_chord**2 * config.chord_direction_sigma / max(abs(refined_yaw) * lever, 1e-12)))
    if not _scale_is_known(refined, chord_sigma, config):
        return _scale_unobservable(groups, pool[0], axle_x, config, chord_prior, drawn, chord_sigma)
    count = int(np.sum(refined_inliers))
    yaw_sigma = float(np.sqrt(covariance[0, 0]))
    if count < _least_inliers(groups, config):
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    masks = _split(refined_inliers, groups)
    if abs(refined_chord) < config.min_chord:
        if moving or abs(refined_yaw) > max(3.0 * yaw_sigma, config.min_chord / _TIGHTEST_TURN_RADIUS_M):
            # A truck cannot turn on the spot (nor be known to move and stand still): the chord was
            # not measured in this pair (rotation-like tracks); the yaw is refined with the prior's.
            prior = (cost, refined_yaw, chord_prior if chord_prior is not None else refined_chord, refined_inliers)
            return _scale_unobservable(groups, prior, axle_x, config, chord_prior, drawn, chord_sigma)
        return TractorMotionEstimate(SolverStatus.STANDSTILL, 0.0, 0.0, np.eye(4), masks, count, drawn, yaw_sigma, chord_sigma, 1.0, rms)
    if not _drivable(refined_yaw, refined_chord, 3.0 * yaw_sigma):
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    T_i_j = make_pose(*ackermann_motion(refined_yaw, refined_chord, axle_x))
    sign = 1.0 if refined_chord >= 0 else -1.0
    return TractorMotionEstimate(SolverStatus.OK, refined_yaw, refined_chord, T_i_j, masks, count, drawn, yaw_sigma, chord_sigma, sign, rms)


# still correspondences' median parallax straddles STILL_PARALLAX_SIGMAS (1.665) times the noise
# measured from them, which the sample's medians spread (about 10 % with 100 correspondences; measured
# 1.44-1.68 at rest in realistic bearings with 1.0 and 1.5 px of noise, 1.6-1.9 with 200 points of one
# camera at 2 px): motion needs that exceeded by this factor (2.16 times the noise; at 1.5 px a
# chord of 0.2 m showed 2.4 times it, 0.12 m 1.9)
_NOISE_STILL_MARGIN = 1.3
_NOISE_SEED = 0  # the noise measure's own samples (correspondence_noise): reproducible, the RANSAC's stream untouched


def _noise_standstill(groups: Sequence[Group], parallax: float, motions: Sequence[tuple[float, float]], axle_x: float) -> float | None:
    """Whether a pair whose median parallax (``parallax``, radians) is above ``standstill_parallax`` is a standstill all the
    same, under the noise its own correspondences measure: the median parallax (radians) below which
    it is one when it is, else None.

    ``ransac.standstill_parallax`` (from ``smoother.pixel_sigma``) assumes the tracks' noise; tracks
    noisier than that show a median parallax above it at rest, and the motion fitted to that noise
    measured a chord of it (a standing start read as 0.46 m/s with 1.5 px of noise). At rest no
    motion explains the parallax, moving one explains most of it: the ratio of the median parallax
    to the noise decides, whatever the noise. A standstill needs ``_NOISE_STILL_MARGIN`` times the
    still points' median parallax (``STILL_PARALLAX_SIGMAS`` sigma) not reached at the noise of
    both measures: the Sampson residuals under the best of the pair's planar ``motions`` ((yaw
    change, chord): the refined models and RANSAC's best; cheap, and from above: the planar model's
    error (braking pitches the body) and the outliers add to their median) and, where that says standstill, under each camera's
    own essential matrix (:func:`~ampc_vo.solvers.noise.correspondence_noise`: pitch and roll
    explained; without it braking to rest was cut short by up to a second)."""
    yaw_changes, chords = (np.array(values, dtype=float) for values in zip(*motions))
    residuals = sampson_residuals(groups, *ackermann_motion(yaw_changes, chords, axle_x))
    if residuals.size == 0:
        return None
    planar_noise = MAD_TO_SIGMA * float(np.min(np.median(np.abs(residuals), axis=1)))
    if parallax >= _NOISE_STILL_MARGIN * STILL_PARALLAX_SIGMAS * planar_noise:
        return None
    still = _NOISE_STILL_MARGIN * STILL_PARALLAX_SIGMAS * correspondence_noise(groups, np.random.default_rng(_NOISE_SEED))
    return still if parallax < still else None


def _translated(groups: Sequence[Group], chord_prior: float | None, config: RansacConfig) -> bool:
    """Whether the tracks of a pair whose motion refined to a chord below ``min_chord`` (though their
    median parallax is above ``standstill_parallax``) show that the truck moved all the same: a
    prediction of at least ``min_chord`` (it was moving) and a median parallax, after the pitch and
    roll a body at rest may turn by (:func:`attitude_compensated_parallax`), of at least
    ``standstill_parallax``: no rotation at rest leaves that, a translation does. Straight driving
    fixes no chord (DESIGN 2.3), and the refinement of an unobservable chord may shrink it to
    nothing: a truck driving at 1.5 m/s was published at rest for a keyframe."""
    if chord_prior is None or not np.isfinite(chord_prior) or abs(chord_prior) < config.min_chord:
        return False
    return not _only_pitched(groups, config)


def _only_pitched(groups: Sequence[Group], config: RansacConfig) -> bool:
    """Whether the tracks moved no more than a body pitching and rolling at rest explains: the median
    of :func:`attitude_compensated_parallax` below ``standstill_parallax``."""
    return bool(np.median(attitude_compensated_parallax(groups)) < config.standstill_parallax)


_ATTITUDE_GAIN = 1.25  # an attitude motion replaces the planar one when it explains this many times its inliers


def _least_inliers(groups: Sequence[Group], config: RansacConfig) -> float:
    """Inliers a tractor motion needs: ``min_inliers`` and ``min_inlier_fraction`` of the correspondences."""
    return max(config.min_inliers, config.min_inlier_fraction * sum(len(group) for group in groups))


def _drivable(yaw_change: np.ndarray | float, chord: np.ndarray | float, yaw_tolerance: np.ndarray | float) -> np.ndarray | bool:
    """Whether a truck can drive a motion: the axle's turn radius ``|chord / yaw_change|`` not
    below ``_TIGHTEST_TURN_RADIUS_M``, within ``yaw_tolerance`` (radians) of the yaw change. Moving
    traffic at a near-standstill makes consensus motions no truck can make (10 degrees in 10 cm)."""
    tolerance = np.where(np.isfinite(yaw_tolerance), yaw_tolerance, 0.0)
    return np.abs(yaw_change) <= np.abs(chord) / _TIGHTEST_TURN_RADIUS_M + tolerance


def _sample_tractor_hypotheses(
    groups: Sequence[Group], bearings_i: np.ndarray, bearings_j: np.ndarray, centers: np.ndarray, capable_index: np.ndarray,
    axle_x: float, config: RansacConfig, rng: np.random.Generator, direction: float | None = None,
) -> tuple[list[Hypothesis], int]:
    """Adaptive RANSAC over 2-point samples (the first point from a camera off the axle); returns
    the cheirality-checked, drivable hypotheses (chord of sign ``direction`` where given) sorted
    by MSAC cost, and the number of samples drawn."""
    total = len(bearings_i)
    pool: list[Hypothesis] = []
    best_cost, drawn, required = np.inf, 0, float(config.min_iterations)
    while drawn < min(max(required, config.min_iterations), config.max_iterations):
        first = capable_index[rng.integers(0, len(capable_index), config.batch_size)]
        second = rng.integers(0, total - 1, config.batch_size)
        second = second + (second >= first)  # distinct from first
        drawn += config.batch_size
        sample = np.stack([first, second], axis=1)
        yaw, chord, valid = tractor_motion_2pt_batch(bearings_i[sample], bearings_j[sample], centers[sample], axle_x)
        valid &= _drivable(yaw, chord, _SAMPLE_YAW_TOLERANCE)
        if direction is not None:
            valid &= chord * direction > 0.0
        if not np.any(valid):
            continue
        yaw, chord = yaw[valid], chord[valid]
        cost, inliers = _score(groups, *ackermann_motion(yaw, chord, axle_x), config.sampson_threshold)
        pool.extend((float(cost[k]), float(yaw[k]), float(chord[k]), inliers[k]) for k in np.flatnonzero(np.isfinite(cost)))
        best = int(np.argmin(cost))
        if cost[best] < best_cost:
            best_cost = cost[best]
            required = _required_iterations(np.sum(inliers[best]) / total, 2, config.confidence)
    pool.sort(key=lambda item: item[0])
    return pool, drawn


def _local_optimization(groups: Sequence[Group], pool: Sequence[Hypothesis], axle_x: float, config: RansacConfig) -> list[tuple]:
    """LO-RANSAC: refine the ``config.local_optimizations`` best hypotheses and the best one with
    its chord scaled by ``config.chord_seeds`` (the chord is the weakly observed direction, so
    basins along it are explored); returns the refined models sorted by MSAC cost, each
    ``(cost, yaw, chord, covariance, rms, inliers, start hypothesis)``."""
    best_yaw, best_chord = pool[0][1], pool[0][2]
    seeds = np.array([best_chord * factor for factor in config.chord_seeds])
    candidates = list(pool[: config.local_optimizations])
    if seeds.size:
        seed_costs, seed_inliers = _score(groups, *ackermann_motion(np.full(seeds.size, best_yaw), seeds, axle_x), config.sampson_threshold,
                                          check_top=seeds.size)
        candidates += [(float(seed_costs[k]), best_yaw, float(seeds[k]), seed_inliers[k]) for k in range(seeds.size)]
    candidates = [h for h in candidates if np.sum(h[3]) >= config.min_inliers]
    return sorted(_refine_tractor_hypotheses(groups, candidates, axle_x, config), key=lambda item: item[0])


def _scale_is_known(refined: Sequence[tuple], chord_sigma: float, config: RansacConfig) -> bool:
    """Scale checks on the best refined model (DESIGN 2.1, 2.3): observable chord (finite, bounded,
    small relative sigma); no sign change and no loss of consensus during refinement (a chord
    wandering along a flat cost); no other basin with a chord more than 3 sigma away within
    ``ambiguity_points`` outliers' worth of MSAC cost (the chord would hinge on single points)."""
    cost, _, chord, _, _, inliers, start = refined[0]
    margin = config.ambiguity_points * config.sampson_threshold**2
    ambiguous = any(
        abs(other[2] - chord) > max(3.0 * chord_sigma, 0.05 * abs(chord)) and other[0] - cost < margin for other in refined[1:]
    )
    return bool(
        not ambiguous and chord_is_observable(chord, chord_sigma, config) and chord * start[2] > 0.0
        and np.sum(inliers) >= 0.8 * np.sum(start[3])
    )


def _scale_unobservable(
    groups: Sequence[Group], hypothesis: Hypothesis, axle_x: float, config: RansacConfig, chord_prior: float | None, drawn: int,
    chord_sigma: float,
) -> TractorMotionEstimate:
    """The yaw change refined with the chord fixed (prior, or the hypothesis' magnitude with at least
    1 m), direction of travel from the hypothesis; ``chord`` is the prior or NaN."""
    _, yaw_change, chord, _ = hypothesis
    sign = 1.0 if chord >= 0 else -1.0
    known = chord_prior is not None and np.isfinite(chord_prior)
    fixed = sign * (abs(float(chord_prior)) if known else max(abs(chord), 1.0))
    # the tracks are scored along the hypothesis' direction of travel: a prior near zero (a truck
    # predicted at rest that moves off) would make every track with parallax an outlier
    scored_chord = fixed if abs(fixed) >= config.min_chord else sign * max(abs(chord), 1.0)
    yaw_change, _, covariance, rms = refine_tractor(
        groups, yaw_change, scored_chord, axle_x, config.refine_iterations, fix_chord=True,
        robust_threshold=config.sampson_threshold, robust_rounds=config.refine_rounds,
    )
    _, scored = _score(groups, *ackermann_motion(np.array([yaw_change]), np.array([scored_chord]), axle_x), config.sampson_threshold, check_top=1)
    if np.sum(scored[0]) < _least_inliers(groups, config):
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=[np.zeros(g.size, bool) for g in groups], num_hypotheses=drawn)
    yaw_sigma = float(np.sqrt(covariance[0, 0])) if np.isfinite(covariance[0, 0]) else float("nan")
    reported = fixed if known else float("nan")
    T_i_j = make_pose(*ackermann_motion(yaw_change, reported, axle_x)) if known else None
    return TractorMotionEstimate(
        SolverStatus.SCALE_UNOBSERVABLE, yaw_change, reported, T_i_j, _split(scored[0], groups), int(np.sum(scored[0])), drawn,
        yaw_sigma, chord_sigma, sign, rms,
    )


def _refine_tractor_hypotheses(
    groups: Sequence[Group], candidates: Sequence[Hypothesis], axle_x: float, config: RansacConfig
) -> list[tuple]:
    """Refine hypotheses ``(cost, yaw, chord, inliers)`` together (one batched Levenberg-Marquardt)
    by least squares over their inliers, re-selecting the inliers up to ``config.refine_rounds``
    times. Near-identical starts are merged; after each round, starts clearly worse than the best
    (by more than 4 ``ambiguity_points`` outliers' worth) or converged onto a better start's basin
    are dropped. Returns, per surviving hypothesis, ``(MSAC cost, yaw, chord, covariance, rms,
    inliers, hypothesis)`` of the refined model.""" 
    distinct: list[Hypothesis] = []
    for candidate in candidates:  # near-identical starts converge to the same basin
        if not any(abs(candidate[1] - d[1]) < 1e-4 and abs(candidate[2] - d[2]) < 1e-3 * abs(d[2]) + 1e-6 for d in distinct):
            distinct.append(candidate)
    yaw = np.array([c[1] for c in distinct])
    chord = np.array([c[2] for c in distinct])
    masks = np.array([c[3] for c in distinct])
    keep = np.arange(len(distinct))
    margin = 4.0 * config.ambiguity_points * config.sampson_threshold**2
    for _ in range(max(config.refine_rounds, 1)):
        params, covariance, cost, used = refine_tractor_batch(groups, yaw, chord, masks, axle_x, config.refine_iterations)
        yaw, chord = params[:, 0], params[:, 1]
        msac, scored = _score(groups, *ackermann_motion(yaw, chord, axle_x), config.sampson_threshold, check_top=len(keep))
        unchanged = np.array_equal(scored, masks)
        # drop starts that are clearly worse than the best or converged onto a better one's basin
        order = np.argsort(msac)
        survivors: list[int] = []
        for k in order:
            duplicate = any(abs(yaw[k] - yaw[j]) < 1e-6 and abs(chord[k] - chord[j]) < 1e-5 * abs(chord[j]) + 1e-9 for j in survivors)
            if not duplicate and msac[k] <= msac[order[0]] + margin:
                survivors.append(int(k))
        survivors = np.array(survivors)
        yaw, chord, masks, keep = yaw[survivors], chord[survivors], scored[survivors], keep[survivors]
        covariance, cost, used, msac = covariance[survivors], cost[survivors], used[survivors], msac[survivors]
        if unchanged:
            break
    rms = np.sqrt(cost / np.maximum(used, 1))
    return [(float(msac[k]), float(yaw[k]), float(chord[k]), covariance[k], float(rms[k]), masks[k], distinct[keep[k]]) for k in range(len(keep))]


def _tractor_scale_free(
    groups: Sequence[Group], bearings_i: np.ndarray, bearings_j: np.ndarray, axle_x: float, config: RansacConfig,
    chord_prior: float | None, rng: np.random.Generator,
) -> TractorMotionEstimate:
    """1-point scale-free fallback for cameras above the axle (``p_x = 0``, DESIGN 2.1): yaw change
    and direction of travel (hypotheses with both chord signs, cheirality decides); the chord is
    the prior (or NaN)."""
    total = len(bearings_i)
    unit = abs(float(chord_prior)) if chord_prior is not None and np.isfinite(chord_prior) else 1.0
    best: Hypothesis | None = None
    drawn, required = 0, float(config.min_iterations)
    while drawn < min(max(required, config.min_iterations), config.max_iterations):
        index = rng.integers(0, total, config.batch_size)
        drawn += config.batch_size
        yaw = tractor_yaw_1pt_batch(bearings_i[index], bearings_j[index])
        yaw = yaw[np.isfinite(yaw)]
        if yaw.size == 0:
            continue
        yaw = np.concatenate([yaw, yaw])
        chord = np.concatenate([np.full(yaw.size // 2, unit), np.full(yaw.size // 2, -unit)])
        cost, inliers = _score(groups, *ackermann_motion(yaw, chord, axle_x), config.sampson_threshold)
        winner = int(np.argmin(cost))
        if best is None or cost[winner] < best[0]:
            best = (float(cost[winner]), float(yaw[winner]), float(chord[winner]), inliers[winner])
            required = _required_iterations(np.sum(best[3]) / total, 1, config.confidence)
    if best is None or np.sum(best[3]) < config.min_inliers:
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=[np.zeros(g.size, bool) for g in groups], num_hypotheses=drawn)
    return _scale_unobservable(groups, best, axle_x, config, chord_prior, drawn, float("nan"))


# ---------------------------------------------------------------------- trailer
def estimate_hitch_angles(
    trailer_correspondences: Sequence[Any],
    tractor_motion: tuple[float, np.ndarray],
    trailer_axle_x: float,
    config: RansacConfig | None = None,
    prior_hitch_angle: float | None = None,
    rng: np.random.Generator | None = None,
) -> HitchEstimate:
    """Hitch angles before/after a motion by RANSAC over the trailer 1-point solver (DESIGN 2.2).

    ``trailer_correspondences``: one entry per trailer camera, ``(bearings_i, bearings_j,
    center)`` in the trailer frame; ``tractor_motion``: ``(yaw_change, translation (3,))`` of the
    tractor (paper ``R_AA'``, ``t_AA'``); ``prior_hitch_angle``: the previous estimate of
    ``theta'`` (continuity ``theta_k = theta'_{k-1}``): hypotheses outside ``config.prior_gate``
    are dropped when some hypothesis lies inside it. At standstill the prior is held.
    """
    config = config or RansacConfig()
    rng = rng if rng is not None else np.random.default_rng(config.seed)
    groups = as_groups(trailer_correspondences)
    empty_masks = [np.zeros(g.size, dtype=bool) for g in groups]
    yaw_change, translation = tractor_motion
    translation = np.asarray(translation, dtype=float) if translation is not None else np.full(3, np.nan)
    if yaw_change is None or not np.isfinite(yaw_change) or translation.shape != (3,) or not np.all(np.isfinite(translation)):
        return HitchEstimate(SolverStatus.NO_MOTION_PRIOR, inlier_masks=empty_masks)
    held = float(prior_hitch_angle) if prior_hitch_angle is not None else float("nan")
    if np.hypot(translation[0], translation[1]) < config.min_chord:
        return HitchEstimate(SolverStatus.STANDSTILL, held, held, 0.0, inlier_masks=empty_masks)
    total = sum(len(g) for g in groups)
    if total < max(1, config.min_inliers):
        return HitchEstimate(SolverStatus.TOO_FEW_POINTS, inlier_masks=empty_masks)
    bearings_i, bearings_j, centers = _stack(groups)

    order = rng.permutation(total)
    use_prior = prior_hitch_angle is not None and np.isfinite(prior_hitch_angle)
    best: dict[bool, tuple[float, float, float, np.ndarray]] = {}  # inside the prior gate? -> (cost, psi, sign, inliers)
    drawn, required = 0, float(config.min_iterations)
    while drawn < min(max(required, config.min_iterations), config.max_iterations, total):
        index = order[drawn : drawn + config.batch_size]
        drawn += len(index)
        solved = hitch_angles_1pt_batch(
            bearings_i[index], bearings_j[index], centers[index], yaw_change, translation, trailer_axle_x, config.max_hitch_angle
        )
        valid = solved["valid"]
        if not np.any(valid):
            continue
        psi, sign, hitch_i = solved["trailer_yaw_change"][valid], solved["chord_sign"][valid], solved["hitch_angle_i"][valid]
        inside = np.abs(hitch_i - prior_hitch_angle) <= config.prior_gate if use_prior else np.ones(len(psi), dtype=bool)
        for gated in (True, False):
            chosen = inside == gated
            if not np.any(chosen):
                continue
            _, _, rotation, trailer_translation = trailer_motion_from_yaw(psi[chosen], sign[chosen], yaw_change, translation, trailer_axle_x)
            cost, inliers = _score(groups, rotation, trailer_translation, config.sampson_threshold)
            winner = int(np.argmin(cost))
            if gated not in best or cost[winner] < best[gated][0]:
                best[gated] = (float(cost[winner]), float(psi[chosen][winner]), float(sign[chosen][winner]), inliers[winner])
        leader = best.get(True) or best.get(False)
        required = _required_iterations(np.sum(leader[3]) / total, 1, config.confidence)
    if not best:
        return HitchEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    _, psi_best, sign_best, inliers = best.get(True) or best[False]
    variance, rms = float("nan"), float("nan")
    if config.refine and np.sum(inliers) >= 2:
        psi_best, variance, rms = refine_trailer_yaw(
            groups, psi_best, sign_best, yaw_change, translation, trailer_axle_x, config.refine_iterations,
            robust_threshold=config.sampson_threshold, robust_rounds=config.refine_rounds,
        )
        _, _, rotation, trailer_translation = trailer_motion_from_yaw(np.array([psi_best]), sign_best, yaw_change, translation, trailer_axle_x)
        _, scored = _score(groups, rotation, trailer_translation, config.sampson_threshold)
        inliers = scored[0]
    count = int(np.sum(inliers))
    if count < config.min_inliers:
        return HitchEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    hitch_i, hitch_j, rotation, trailer_translation = trailer_motion_from_yaw(psi_best, sign_best, yaw_change, translation, trailer_axle_x)
    # d theta / d psi by central differences for the standard deviation of theta
    step = 1e-6
    slope = (trailer_motion_from_yaw(psi_best + step, sign_best, yaw_change, translation, trailer_axle_x)[0]
             - trailer_motion_from_yaw(psi_best - step, sign_best, yaw_change, translation, trailer_axle_x)[0]) / (2 * step)
    sigma = float(abs(slope) * np.sqrt(variance)) if np.isfinite(variance) else float("nan")
    return HitchEstimate(
        SolverStatus.OK, float(hitch_i), float(hitch_j), psi_best, sign_best, make_pose(rotation, trailer_translation),
        _split(inliers, groups), count, drawn, sigma, rms,
    )
