"""Non-linear refinement of the tractor/trailer two-view estimates over their inliers.

Residuals are Sampson-normalised GEC residuals from :mod:`ampc_vo.epipolar` (paper eqs. (1),
(2), (6)); the parameters are minimal: tractor ``(phi, rho)`` with the Ackermann model, trailer
``psi`` with both hitch angles in closed form from the trailer non-holonomic constraint
(DESIGN 2.2), or jointly ``(phi, rho, psi)``. A small Levenberg-Marquardt with a forward-difference
Jacobian evaluates all perturbed parameter vectors (and several starts) in one broadcast call.
"""
from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ampc_vo.epipolar import gec_sampson
from ampc_vo.geometry import make_pose, rot_z
from ampc_vo.solvers.status import SolverStatus
from ampc_vo.solvers.tractor import ackermann_motion, rotations_z
from ampc_vo.solvers.trailer import trailer_motion_from_yaw
from ampc_vo.solvers.estimates import (
    Group,
    HitchEstimate,
    JointEstimate,
    RansacConfig,
    TractorMotionEstimate,
    as_groups,
    chord_is_observable,
)

logger = logging.getLogger(__name__)

_DIFFERENCE_STEP = 1e-7


def sampson_residuals(groups: Sequence[Group], rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Stacked Sampson residuals (H, M) of all groups for H body motions (H, 3, 3), (H, 3)."""
    parts = [gec_sampson(group.bearings_i, group.bearings_j, rotation, translation, group.center) for group in groups if len(group)]
    if not parts:
        return np.zeros(rotation.shape[:-2] + (0,))
    return np.concatenate(parts, axis=-1)


def levenberg_marquardt_batch(
    residual_batch: Callable[[np.ndarray], np.ndarray],
    initial: np.ndarray,
    weights: np.ndarray | None = None,
    iterations: int = 20,
    tolerance: float = 1e-5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Minimise ``sum_m w_km r_m(x_k)^2`` for K independent starts at once.

    ``initial`` (K, P); ``residual_batch`` maps (H, P) parameter rows to (H, M) residuals;
    ``weights`` (K, M) (e.g. 0/1 inlier masks) or None. Every iteration evaluates all K trial
    points and their P forward-difference neighbours in ONE call (the Python overhead, not the
    arithmetic, dominates at these sizes), so an accepted step already carries its Jacobian. A
    start stops when its step is below ``tolerance * (1 + |x|)``, its cost decreases by less than
    a relative 1e-7, or its damping explodes.

    Returns ``(x (K, P), covariance (K, P, P), cost (K,), count (K,))``: covariance
    ``s^2 (J^T W J)^-1`` with ``s^2 = cost / (count - P)``, ``count`` the number of non-zero weights.
    """
    x = np.array(initial, dtype=float, ndmin=2)
    starts, count = x.shape
    steps = _DIFFERENCE_STEP * np.maximum(1.0, np.abs(x))  # (K, P)
    offsets = np.concatenate([np.zeros((starts, 1, count)), steps[:, :, None] * np.eye(count)[None]], axis=1)  # (K, P+1, P)

    def evaluate(points: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residuals, Jacobians and costs of the starts ``rows`` at ``points`` (len(rows), P)."""
        values = residual_batch((points[:, None, :] + offsets[rows]).reshape(-1, count)).reshape(len(rows), count + 1, -1)
        if weights is not None:
            values = values * root_weights[rows][:, None, :]
        residual = values[:, 0]
        jacobian = np.swapaxes(values[:, 1:] - residual[:, None], 1, 2) / steps[rows][:, None, :]  # (K, M, P)
        return residual, jacobian, np.einsum("km,km->k", residual, residual)

    root_weights = None if weights is None else np.sqrt(np.asarray(weights, dtype=float))
    residual, jacobian, cost = evaluate(x, np.arange(starts))
    damping = np.full(starts, 1e-4)
    active = np.isfinite(cost)
    identity = np.eye(count)
    for _ in range(iterations):
        if not np.any(active):
            break
        normal = np.einsum("kmp,kmq->kpq", jacobian, jacobian)
        gradient = np.einsum("kmp,km->kp", jacobian, residual)
        diagonal = np.einsum("kpp->kp", normal)[:, :, None] * identity + 1e-12 * identity
        try:
            step = -np.linalg.solve(normal + damping[:, None, None] * diagonal, gradient[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        step[~active] = 0.0
        rows = np.flatnonzero(active)
        trial_residual, trial_jacobian, trial_cost = evaluate(x[rows] + step[rows], rows)
        better = np.isfinite(trial_cost) & (trial_cost <= cost[rows])
        accepted = np.zeros(starts, dtype=bool)
        accepted[rows[better]] = True
        decrease = np.zeros(starts)
        decrease[rows[better]] = cost[rows[better]] - trial_cost[better]
        x[accepted] += step[accepted]
        residual[accepted], jacobian[accepted], cost[accepted] = trial_residual[better], trial_jacobian[better], trial_cost[better]
        damping = np.where(accepted, np.maximum(damping / 10.0, 1e-9), damping * 10.0)
        small_step = np.all(np.abs(step) <= tolerance * (1.0 + np.abs(x)), axis=1)
        converged = accepted & ((decrease <= 1e-7 * cost) | small_step)
        active &= ~converged & (damping < 1e8)
    used = np.full(starts, residual.shape[1]) if weights is None else np.count_nonzero(root_weights, axis=1)
    covariance = np.full((starts, count, count), np.nan)
    for k in range(starts):
        if used[k] > count and np.isfinite(cost[k]):
            try:
                covariance[k] = np.linalg.inv(jacobian[k].T @ jacobian[k]) * cost[k] / (used[k] - count)
            except np.linalg.LinAlgError:
                pass
    return x, covariance, cost, used


def levenberg_marquardt(
    residual_batch: Callable[[np.ndarray], np.ndarray], initial: np.ndarray, iterations: int = 20, tolerance: float = 1e-5
) -> tuple[np.ndarray, np.ndarray, float]:
    """Minimise ``sum r(x)^2`` from one start ``initial`` (P,) (:func:`levenberg_marquardt_batch`).

    Returns ``(x, covariance (P, P), rms)``."""
    x, covariance, cost, used = levenberg_marquardt_batch(residual_batch, np.asarray(initial, dtype=float)[None], None, iterations, tolerance)
    return x[0], covariance[0], float(np.sqrt(cost[0] / max(int(used[0]), 1)))


def robust_least_squares(
    residual_batch: Callable[[np.ndarray], np.ndarray], initial: np.ndarray, threshold: float, rounds: int = 3, iterations: int = 15
) -> tuple[np.ndarray, np.ndarray, float]:
    """Iteratively reweighted :func:`levenberg_marquardt` with the Cauchy loss over all residuals.

    Each round fixes weights ``w = 1 / (1 + (r / c)^2)`` at the current estimate, with the scale
    ``c = 2.385 sigma`` (95% efficiency), ``sigma = 1.4826 median |r|`` over residuals below
    ``threshold``, clipped to ``[threshold / 8, threshold / 2]``: outliers fade out smoothly,
    so the estimate does not depend on a hard inlier set chosen at the initial hypothesis.
    Returns ``(x, covariance, rms)``; the covariance uses the effective count ``sum w``.
    """
    x = np.asarray(initial, dtype=float)
    covariance, rms = np.full((x.size, x.size), np.nan), float("nan")
    for _ in range(rounds):
        residual = residual_batch(x[None])[0]
        small = np.abs(residual[np.abs(residual) < threshold])
        sigma = 1.4826 * float(np.median(small)) if small.size else threshold / 3.0
        scale = float(np.clip(2.385 * sigma, threshold / 8.0, threshold / 2.0))
        root_weight = 1.0 / np.sqrt(1.0 + (residual / scale) ** 2)
        x, covariance, rms = levenberg_marquardt(lambda params: residual_batch(params) * root_weight, x, iterations)
        effective = float(np.sum(root_weight**2)) - x.size
        if effective > 0 and residual.size > x.size:
            covariance = covariance * (residual.size - x.size) / effective
    return x, covariance, rms


def refine_tractor(
    groups: Sequence[Group], yaw_change: float, chord: float, axle_x: float, iterations: int = 15, fix_chord: bool = False,
    robust_threshold: float | None = None, robust_rounds: int = 3,
) -> tuple[float, float, np.ndarray, float]:
    """Refine the Ackermann ``(phi, rho)`` over the groups' correspondences (DESIGN 2.1);
    returns ``(phi, rho, covariance, rms)``. Least squares over inliers, or with
    ``robust_threshold`` the Cauchy IRLS of :func:`robust_least_squares` over all points.
    With ``fix_chord`` only ``phi`` is optimised (scale-free case) and the covariance is 1x1."""
    def residual_batch(params: np.ndarray) -> np.ndarray:
        chords = np.full(len(params), chord) if fix_chord else params[:, 1]
        rotation, translation = ackermann_motion(params[:, 0], chords, axle_x)
        return sampson_residuals(groups, rotation, translation)

    initial = np.array([yaw_change] if fix_chord else [yaw_change, chord])
    if robust_threshold is None:
        params, covariance, rms = levenberg_marquardt(residual_batch, initial, iterations)
    else:
        params, covariance, rms = robust_least_squares(residual_batch, initial, robust_threshold, robust_rounds, iterations)
    return float(params[0]), (chord if fix_chord else float(params[1])), covariance, rms


def refine_tractor_batch(
    groups: Sequence[Group], yaw_change: np.ndarray, chord: np.ndarray, inlier_masks: np.ndarray, axle_x: float, iterations: int = 20
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares refinement of K Ackermann hypotheses ``(phi_k, rho_k)`` at once, each over its
    own inliers (``inlier_masks`` (K, M) over the groups' stacked correspondences), DESIGN 2.1.
    Returns ``(params (K, 2), covariance (K, 2, 2), cost (K,), inlier count (K,))``."""
    def residual_batch(params: np.ndarray) -> np.ndarray:
        return sampson_residuals(groups, *ackermann_motion(params[:, 0], params[:, 1], axle_x))

    initial = np.stack([np.asarray(yaw_change, dtype=float), np.asarray(chord, dtype=float)], axis=1)
    return levenberg_marquardt_batch(residual_batch, initial, inlier_masks, iterations)


def refine_trailer_yaw(
    groups: Sequence[Group], trailer_yaw_change: float, chord_sign: float, yaw_change: float, hitch_translation: np.ndarray,
    trailer_axle_x: float, iterations: int = 15, robust_threshold: float | None = None, robust_rounds: int = 3,
) -> tuple[float, float, float]:
    """Refine ``psi`` with both hitch angles in closed form (DESIGN 2.2) over trailer groups
    (least squares over inliers, or Cauchy IRLS over all points with ``robust_threshold``).

    Returns ``(psi, variance of psi, rms)``."""
    def residual_batch(params: np.ndarray) -> np.ndarray:
        _, _, rotation, translation = trailer_motion_from_yaw(params[:, 0], chord_sign, yaw_change, hitch_translation, trailer_axle_x)
        return sampson_residuals(groups, rotation, translation)

    if robust_threshold is None:
        params, covariance, rms = levenberg_marquardt(residual_batch, np.array([trailer_yaw_change]), iterations)
    else:
        params, covariance, rms = robust_least_squares(residual_batch, np.array([trailer_yaw_change]), robust_threshold, robust_rounds, iterations)
    return float(params[0]), float(covariance[0, 0]), rms


def _inlier_groups(correspondences: Sequence[Any], masks: Sequence[np.ndarray]) -> list[Group]:
    groups = as_groups(correspondences)
    if len(masks) != len(groups):
        raise ValueError(f"expected {len(groups)} inlier masks, got {len(masks)}")
    return [group.subset(np.asarray(mask, dtype=bool)[group.rows]) for group, mask in zip(groups, masks)]


def refine_joint(
    tractor_correspondences: Sequence[Any],
    trailer_correspondences: Sequence[Any],
    tractor: TractorMotionEstimate,
    hitch: HitchEstimate,
    tractor_axle_x: float,
    trailer_axle_x: float,
    config: RansacConfig | None = None,
    trailer_nonholonomic: bool = True,
) -> JointEstimate:
    """Joint refinement of tractor and trailer over both bodies' inliers (paper eqs. (1), (6)).

    With ``trailer_nonholonomic`` the parameters are ``(phi, rho, psi)``: tractor Ackermann motion
    and the trailer yaw change, the hitch angles in closed form from the trailer non-holonomic
    constraint (DESIGN 2.2). Without it they are ``(phi, rho, theta, theta')`` with the trailer
    motion from paper eqs. (3), (4) only (for comparison). Starts from the RANSAC estimates and
    uses their inlier masks (the tractor estimate needs a chord: a ``SCALE_UNOBSERVABLE`` estimate
    made with ``chord_prior`` is accepted). Returns a :class:`JointEstimate`; its status is the
    failing input's status when an input is not usable (values NaN), ``SCALE_UNOBSERVABLE`` when
    the refined chord's relative sigma exceeds ``config.max_relative_chord_sigma``, else ``OK``.
    """
    config = config or RansacConfig()
    if not tractor.status.usable or not np.isfinite(tractor.chord) or not hitch.ok:
        status = hitch.status if tractor.status.usable and np.isfinite(tractor.chord) else tractor.status
        nan = float("nan")
        return JointEstimate(status, tractor.yaw_change, tractor.chord, hitch.hitch_angle_i, hitch.hitch_angle_j, hitch.trailer_yaw_change,
                             np.full((4, 4), nan), np.full((4, 4), nan), np.full((3, 3), nan), nan, trailer_nonholonomic)
    front = _inlier_groups(tractor_correspondences, tractor.inlier_masks)
    back = _inlier_groups(trailer_correspondences, hitch.inlier_masks)
    sign = hitch.chord_sign

    def stacked(rotation, translation, trailer_rotation, trailer_translation) -> np.ndarray:
        return np.concatenate(
            [sampson_residuals(front, rotation, translation), sampson_residuals(back, trailer_rotation, trailer_translation)], axis=1
        )

    if trailer_nonholonomic:
        def residual_batch(params: np.ndarray) -> np.ndarray:
            rotation, translation = ackermann_motion(params[:, 0], params[:, 1], tractor_axle_x)
            _, _, trailer_rotation, trailer_translation = trailer_motion_from_yaw(
                params[:, 2], sign, params[:, 0], translation, trailer_axle_x
            )
            return stacked(rotation, translation, trailer_rotation, trailer_translation)

        initial = np.array([tractor.yaw_change, tractor.chord, hitch.trailer_yaw_change])
    else:
        def residual_batch(params: np.ndarray) -> np.ndarray:
            rotation, translation = ackermann_motion(params[:, 0], params[:, 1], tractor_axle_x)
            hitch_i, hitch_j = params[:, 2], params[:, 3]
            trailer_rotation = rotations_z(params[:, 0] + hitch_j - hitch_i)  # paper eq. (3)
            trailer_translation = np.einsum("hba,hb->ha", rotations_z(hitch_i), translation)  # paper eq. (4): Q^T t
            return stacked(rotation, translation, trailer_rotation, trailer_translation)

        initial = np.array([tractor.yaw_change, tractor.chord, hitch.hitch_angle_i, hitch.hitch_angle_j])

    params, covariance, rms = levenberg_marquardt(residual_batch, initial, max(config.refine_iterations, 20))
    yaw_change, chord = float(params[0]), float(params[1])
    rotation, translation = ackermann_motion(yaw_change, chord, tractor_axle_x)
    if trailer_nonholonomic:
        psi = float(params[2])
        hitch_i, hitch_j, trailer_rotation, trailer_translation = trailer_motion_from_yaw(psi, sign, yaw_change, translation, trailer_axle_x)
        hitch_i, hitch_j = float(hitch_i), float(hitch_j)
    else:
        hitch_i, hitch_j = float(params[2]), float(params[3])
        psi = yaw_change + hitch_j - hitch_i
        trailer_rotation = rot_z(psi)
        trailer_translation = rot_z(-hitch_i) @ translation
    status = SolverStatus.OK
    if not chord_is_observable(chord, float(np.sqrt(covariance[1, 1])), config):
        status = SolverStatus.SCALE_UNOBSERVABLE
    return JointEstimate(
        status=status, yaw_change=yaw_change, chord=chord, hitch_angle_i=hitch_i, hitch_angle_j=hitch_j, trailer_yaw_change=psi,
        T_i_j=make_pose(rotation, translation), T_trailer_i_j=make_pose(trailer_rotation, trailer_translation),
        covariance=covariance, rms_residual=rms, trailer_nonholonomic=trailer_nonholonomic,
    )
