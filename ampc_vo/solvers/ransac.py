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

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ampc_vo.geometry import make_pose
from ampc_vo.solvers.refine import refine_tractor, refine_tractor_batch, refine_trailer_yaw, sampson_residuals
from ampc_vo.solvers.status import SolverStatus
from ampc_vo.solvers.tractor import ackermann_motion, tractor_motion_2pt_batch, tractor_yaw_1pt_batch
from ampc_vo.solvers.trailer import hitch_angles_1pt_batch, positive_depth, trailer_motion_from_yaw
from ampc_vo.solvers.estimates import Group, HitchEstimate, RansacConfig, TractorMotionEstimate, as_groups, chord_is_observable, median_parallax

logger = logging.getLogger(__name__)


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
def estimate_tractor_motion(
    correspondences: Sequence[Any],
    axle_x: float,
    config: RansacConfig | None = None,
    chord_prior: float | None = None,
    rng: np.random.Generator | None = None,
) -> TractorMotionEstimate:
    """Tractor motion from per-camera correspondences by RANSAC over the 2-point solver (DESIGN 2.1).

    ``correspondences``: one entry per tractor camera, ``(bearings_i (N, 3), bearings_j (N, 3),
    center (3,))`` in the tractor frame (or an object with ``as_group()``); samples mix cameras.
    ``axle_x``: tractor axle. ``chord_prior`` (metres, e.g. wheel odometry) is used only when
    the scale is unobservable (straight driving, all cameras above the axle): the status stays
    ``SCALE_UNOBSERVABLE`` but ``chord`` and ``T_i_j`` are then filled with it.
    """
    config = config or RansacConfig()
    rng = rng if rng is not None else np.random.default_rng(config.seed)
    groups = as_groups(correspondences)
    empty_masks = [np.zeros(g.size, dtype=bool) for g in groups]
    total = sum(len(g) for g in groups)
    if total < max(2, config.min_inliers):
        return TractorMotionEstimate(SolverStatus.TOO_FEW_POINTS, inlier_masks=empty_masks)
    if median_parallax(groups) < config.standstill_parallax:
        return TractorMotionEstimate(SolverStatus.STANDSTILL, 0.0, 0.0, np.eye(4), [g.full_mask(np.ones(len(g), bool)) for g in groups], total)
    bearings_i, bearings_j, centers = _stack(groups)
    scale_capable = np.abs(centers[:, 0] - axle_x) > config.min_camera_axle_offset
    if not np.any(scale_capable):
        return _tractor_scale_free(groups, bearings_i, bearings_j, axle_x, config, chord_prior, rng)

    capable_index = np.flatnonzero(scale_capable)
    pool: list[tuple[float, float, float, np.ndarray]] = []  # (cost, yaw, chord, inliers) of checked hypotheses
    best_cost, drawn, required = np.inf, 0, float(config.min_iterations)
    while drawn < min(max(required, config.min_iterations), config.max_iterations):
        first = capable_index[rng.integers(0, len(capable_index), config.batch_size)]
        second = rng.integers(0, total - 1, config.batch_size)
        second = second + (second >= first)  # distinct from first
        drawn += config.batch_size
        sample = np.stack([first, second], axis=1)
        yaw, chord, valid = tractor_motion_2pt_batch(bearings_i[sample], bearings_j[sample], centers[sample], axle_x)
        if not np.any(valid):
            continue
        yaw, chord = yaw[valid], chord[valid]
        cost, inliers = _score(groups, *ackermann_motion(yaw, chord, axle_x), config.sampson_threshold)
        checked = np.flatnonzero(np.isfinite(cost))
        pool.extend((float(cost[k]), float(yaw[k]), float(chord[k]), inliers[k]) for k in checked)
        best = int(np.argmin(cost))
        if cost[best] < best_cost:
            best_cost = cost[best]
            required = _required_iterations(np.sum(inliers[best]) / total, 2, config.confidence)
    pool.sort(key=lambda item: item[0])
    if not pool or np.sum(pool[0][3]) < config.min_inliers:
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)

    _, yaw_change, chord, inliers = pool[0]
    sign = 1.0 if chord >= 0 else -1.0
    chord_sigma = yaw_sigma = rms = float("nan")
    scale_known = True
    if config.refine:
        # local optimisation: refine the best few hypotheses, keep the lowest MSAC cost (LO-RANSAC)
        candidates = list(pool[: config.local_optimizations])
        # the chord is the weakly observed direction: also start from scaled chords of the best
        for factor in config.chord_seeds:
            seed_chord = pool[0][2] * factor
            seed_cost, seed_inliers = _score(groups, *ackermann_motion(np.array([pool[0][1]]), np.array([seed_chord]), axle_x), config.sampson_threshold, 1)
            candidates.append((float(seed_cost[0]), pool[0][1], seed_chord, seed_inliers[0]))
        candidates = [h for h in candidates if np.sum(h[3]) >= config.min_inliers]
        refined = sorted(_refine_tractor_hypotheses(groups, candidates, axle_x, config), key=lambda item: item[0])
        best_cost, refined_yaw, refined_chord, covariance, refined_rms, refined_inliers, start = refined[0]
        chord_sigma = float(np.sqrt(covariance[1, 1])) if np.isfinite(covariance[1, 1]) else float("inf")
        # another basin with a clearly different chord and nearly the same cost: the scale is ambiguous
        margin = config.ambiguity_points * config.sampson_threshold**2
        ambiguous = any(
            abs(other[2] - refined_chord) > max(3.0 * chord_sigma, 0.05 * abs(refined_chord)) and other[0] - best_cost < margin
            for other in refined[1:]
        )
        # a chord that changed sign or lost the consensus (cheirality) wandered along a flat cost
        scale_known = (
            not ambiguous and chord_is_observable(refined_chord, chord_sigma, config) and refined_chord * start[2] > 0.0
            and np.sum(refined_inliers) >= 0.8 * np.sum(start[3])
        )
        if scale_known:
            yaw_change, chord, rms, inliers = refined_yaw, refined_chord, refined_rms, refined_inliers
            sign, yaw_sigma = (1.0 if chord >= 0 else -1.0), float(np.sqrt(covariance[0, 0]))
    count = int(np.sum(inliers))
    if count < config.min_inliers:
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=empty_masks, num_hypotheses=drawn)
    if not scale_known:
        # scale unobservable (straight driving): refine the yaw with the chord fixed (DESIGN 2.3)
        known = chord_prior is not None and np.isfinite(chord_prior)
        fixed = sign * (abs(float(chord_prior)) if known else max(abs(chord), 1.0))
        yaw_change, _, covariance, rms = refine_tractor(
            groups, yaw_change, fixed, axle_x, config.refine_iterations, fix_chord=True, robust_threshold=config.sampson_threshold, robust_rounds=config.refine_rounds
        )
        _, scored = _score(groups, *ackermann_motion(np.array([yaw_change]), np.array([fixed]), axle_x), config.sampson_threshold)
        inliers = scored[0]
        yaw_sigma = float(np.sqrt(covariance[0, 0])) if np.isfinite(covariance[0, 0]) else float("nan")
        reported = fixed if known else float("nan")
        T_i_j = make_pose(*ackermann_motion(yaw_change, reported, axle_x)) if known else None
        return TractorMotionEstimate(
            SolverStatus.SCALE_UNOBSERVABLE, yaw_change, reported, T_i_j, _split(inliers, groups), int(np.sum(inliers)), drawn, yaw_sigma,
            chord_sigma, sign, rms,
        )
    masks = _split(inliers, groups)
    if abs(chord) < config.min_chord:
        return TractorMotionEstimate(SolverStatus.STANDSTILL, 0.0, 0.0, np.eye(4), masks, count, drawn, yaw_sigma, chord_sigma, 1.0, rms)
    T_i_j = make_pose(*ackermann_motion(yaw_change, chord, axle_x))
    return TractorMotionEstimate(SolverStatus.OK, yaw_change, chord, T_i_j, masks, count, drawn, yaw_sigma, chord_sigma, sign, rms)


def _refine_tractor_hypotheses(
    groups: Sequence[Group], candidates: Sequence[tuple[float, float, float, np.ndarray]], axle_x: float, config: RansacConfig
) -> list[tuple[float, float, float, np.ndarray, float, np.ndarray, tuple]]:
    """LO step: refine all hypotheses ``(cost, yaw, chord, inliers)`` together by least squares over
    their inliers, re-selecting the inliers up to ``config.refine_rounds`` times. Returns, per
    hypothesis, ``(MSAC cost, yaw, chord, covariance, rms, inliers, hypothesis)`` of the refined model."""
    distinct: list[tuple[float, float, float, np.ndarray]] = []
    for candidate in candidates:  # near-identical starts converge to the same basin
        if not any(abs(candidate[1] - d[1]) < 1e-4 and abs(candidate[2] - d[2]) < 1e-3 * abs(d[2]) + 1e-6 for d in distinct):
            distinct.append(candidate)
    candidates = distinct
    yaw = np.array([c[1] for c in candidates])
    chord = np.array([c[2] for c in candidates])
    masks = np.array([c[3] for c in candidates])
    for _ in range(max(config.refine_rounds, 1)):
        params, covariance, cost, used = refine_tractor_batch(groups, yaw, chord, masks, axle_x, config.refine_iterations)
        yaw, chord = params[:, 0], params[:, 1]
        msac, scored = _score(groups, *ackermann_motion(yaw, chord, axle_x), config.sampson_threshold, check_top=len(candidates))
        if np.array_equal(scored, masks):
            break
        masks = scored
    rms = np.sqrt(cost / np.maximum(used, 1))
    return [
        (float(msac[k]), float(yaw[k]), float(chord[k]), covariance[k], float(rms[k]), scored[k], candidates[k])
        for k in range(len(candidates))
    ]


def _split_flat(flat_mask: np.ndarray, groups: Sequence[Group]) -> list[np.ndarray]:
    """Cut a mask over the stacked valid correspondences into per-group masks over valid rows."""
    bounds = np.cumsum([0] + [len(g) for g in groups])
    return [flat_mask[bounds[k] : bounds[k + 1]] for k in range(len(groups))]


def _tractor_scale_free(
    groups: Sequence[Group], bearings_i: np.ndarray, bearings_j: np.ndarray, axle_x: float, config: RansacConfig,
    chord_prior: float | None, rng: np.random.Generator,
) -> TractorMotionEstimate:
    """1-point scale-free fallback for cameras above the axle (``p_x = 0``, DESIGN 2.1): yaw change
    and direction of travel; the chord is the prior (or NaN)."""
    total = len(bearings_i)
    unit = abs(float(chord_prior)) if chord_prior is not None and np.isfinite(chord_prior) else 1.0
    best_cost, best_hypothesis, best_inliers = np.inf, None, None
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
        rotation, translation = ackermann_motion(yaw, chord, axle_x)
        cost, inliers = _score(groups, rotation, translation, config.sampson_threshold)
        best = int(np.argmin(cost))
        if cost[best] < best_cost:
            best_cost, best_hypothesis, best_inliers = cost[best], (float(yaw[best]), float(chord[best])), inliers[best]
            required = _required_iterations(np.sum(best_inliers) / total, 1, config.confidence)
    if best_hypothesis is None or np.sum(best_inliers) < config.min_inliers:
        return TractorMotionEstimate(SolverStatus.NO_CONSENSUS, inlier_masks=[np.zeros(g.size, bool) for g in groups], num_hypotheses=drawn)
    yaw_change, chord = best_hypothesis
    inliers = best_inliers
    yaw_sigma, rms = float("nan"), float("nan")
    if config.refine:
        yaw_change, chord, covariance, rms = refine_tractor(
            groups, yaw_change, chord, axle_x, config.refine_iterations, fix_chord=True, robust_threshold=config.sampson_threshold, robust_rounds=config.refine_rounds
        )
        yaw_sigma = float(np.sqrt(covariance[0, 0])) if np.isfinite(covariance[0, 0]) else float("nan")
        _, scored = _score(groups, *ackermann_motion(np.array([yaw_change]), np.array([chord]), axle_x), config.sampson_threshold)
        inliers = scored[0]
    sign = 1.0 if chord >= 0 else -1.0
    known = chord_prior is not None and np.isfinite(chord_prior)
    reported = sign * unit if known else float("nan")
    T_i_j = make_pose(*ackermann_motion(yaw_change, reported, axle_x)) if known else None
    return TractorMotionEstimate(
        SolverStatus.SCALE_UNOBSERVABLE, yaw_change, reported, T_i_j, _split(inliers, groups), int(np.sum(inliers)), drawn, yaw_sigma,
        float("nan"), sign, rms,
    )


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
        solved = hitch_angles_1pt_batch(bearings_i[index], bearings_j[index], centers[index], yaw_change, translation, trailer_axle_x, config.max_hitch_angle)
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
            groups, psi_best, sign_best, yaw_change, translation, trailer_axle_x, config.refine_iterations, robust_threshold=config.sampson_threshold, robust_rounds=config.refine_rounds
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
