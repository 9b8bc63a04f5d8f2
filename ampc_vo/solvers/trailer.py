"""Trailer 1-point solver: both hitch angles from one trailer correspondence, DESIGN 2.2.

Given the tractor motion ``(phi, t)``, the trailer moves on an arc of yaw ``psi = 2 alpha`` and
chord ``rho_B`` of its axle ``b = (axle_x, 0, 0)``, ``s_B = -axle_x``. The hitch displacement seen
from the trailer is ``w = Rz(-theta) t = Rz(alpha) (rho_B, 2 s_B sin alpha)``, so
``rho_B^2 + 4 s_B^2 sin^2 alpha = tau^2`` (``tau = |t|``), and one trailer correspondence of a
camera at ``p = c - b`` gives ``rho_B = 2 sin alpha (p_y - p_x N / U)`` (DESIGN 2.1 coefficients).
Eliminating ``rho_B``:

    4 x^2 [ (p_y U - p_x N)^2 + s_B^2 U^2 ] - tau^2 U^2 (1 + x^2) = 0,   x = tan(alpha)   (quartic)

then ``theta = atan2(t_y, t_x) - alpha - atan2(2 s_B sin alpha, rho_B)``, ``theta' = theta + psi - phi``.
Roots are polished on the unsquared equation for both signs of ``rho_B`` and kept when
``|theta|, |theta'| < max_hitch_angle`` and the point has positive depth in both views.
"""
from __future__ import annotations

import numpy as np

from ampc_vo.geometry import check_bearings, wrap_angle
from ampc_vo.solvers.tractor import arc_coefficients, rotations_z

_ONES3 = np.ones(3)
_NEAR_REAL = 1e-3  # |Im x| <= _NEAR_REAL (1 + |x|): accept (DESIGN 2.2)
_POLISH_ITERATIONS = 6
_MAX_POLISH_STEP = 0.01  # rad per Newton step
_MAX_POLISH_DRIFT = 0.02  # rad from the quartic root
_RESIDUAL_TOLERANCE = 1e-4  # unsquared residual relative to tau * |(U_c, U_s)|


def trailer_motion_from_yaw(
    trailer_yaw_change: np.ndarray | float,
    chord_sign: np.ndarray | float,
    yaw_change: np.ndarray | float,
    hitch_translation: np.ndarray,
    trailer_axle_x: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hitch angles and trailer motion from the trailer yaw change ``psi`` (DESIGN 2.2).

    The trailer non-holonomic constraint fixes the direction of ``w = Rz(-theta) t`` given ``psi``:
    ``w = Rz(psi/2) (rho_B, 2 s_B sin(psi/2))`` with ``rho_B = sign sqrt(tau^2 - 4 s_B^2 sin^2(psi/2))``.
    Vectorised: ``psi``, ``chord_sign``, ``yaw_change`` (...) and ``hitch_translation`` (..., 3)
    broadcast (tractor translation ``t``; its z is carried over). Returns ``(theta_i, theta_j, R_trailer (..., 3, 3),
    t_trailer (..., 3))`` with ``R_trailer = Rz(psi)``, ``t_trailer = Rz(-theta) t`` (paper eqs. (3), (4)).
    """
    psi = np.asarray(trailer_yaw_change, dtype=float)
    s_b = -trailer_axle_x
    t = np.asarray(hitch_translation, dtype=float)
    t_x, t_y, t_z = t[..., 0], t[..., 1], t[..., 2]
    tau2 = t_x**2 + t_y**2
    half_sin = np.sin(0.5 * psi)
    chord = np.asarray(chord_sign, dtype=float) * np.sqrt(np.maximum(tau2 - 4.0 * s_b * s_b * half_sin**2, 0.0))
    hitch_i = wrap_angle(np.arctan2(t_y, t_x) - 0.5 * psi - np.arctan2(2.0 * s_b * half_sin, chord))
    hitch_j = wrap_angle(hitch_i + psi - np.asarray(yaw_change, dtype=float))
    rotation = rotations_z(psi)
    cos_h, sin_h = np.cos(hitch_i), np.sin(hitch_i)
    translation = np.empty(cos_h.shape + (3,))
    translation[..., 0] = cos_h * t_x + sin_h * t_y
    translation[..., 1] = -sin_h * t_x + cos_h * t_y
    translation[..., 2] = t_z
    return hitch_i, hitch_j, rotation, translation


def positive_depth(
    bearings_i: np.ndarray, bearings_j: np.ndarray, rotation: np.ndarray, translation: np.ndarray, center: np.ndarray
) -> np.ndarray:
    """Cheirality of N intra-camera correspondences under H body motions, broadcasting like
    :func:`ampc_vo.epipolar.gec_sampson`: bearings (N, 3), ``rotation`` (..., 3, 3), ``translation``
    (..., 3), ``center`` (3,) -> (..., N) bool. True when the mid-point triangulation has positive
    depth along both rays; rays too close to parallel to tell (|sin| < 1e-6) count as positive."""
    rotation = np.asarray(rotation, dtype=float)
    rotated_j = bearings_j @ np.swapaxes(rotation, -1, -2)
    baseline = (rotation @ center + translation - center)[..., None, :]
    return _positive_depth_rows(bearings_i, rotated_j, baseline)


def _positive_depth_rows(bearings_i: np.ndarray, rotated_j: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Mid-point cheirality of rays ``c + l f`` and ``c' + m g`` with ``baseline = c' - c``
    (broadcastable (..., 3) arrays): ``l > 0`` and ``m > 0``."""
    cosine = (bearings_i * rotated_j) @ _ONES3
    along_i = (bearings_i * baseline) @ _ONES3
    along_j = (rotated_j * baseline) @ _ONES3
    depth_i = along_i - cosine * along_j  # times 1 - cosine^2
    depth_j = cosine * along_i - along_j
    parallel = 1.0 - cosine * cosine < 1e-12
    return parallel | ((depth_i > 0.0) & (depth_j > 0.0))


def _quartic_roots(coefficients: np.ndarray) -> np.ndarray:
    """Complex roots (H, 4) of quartics with descending coefficients (H, 5); missing roots NaN."""
    count = coefficients.shape[0]
    roots = np.full((count, 4), np.nan + 0j)
    scale = np.max(np.abs(coefficients), axis=1)
    regular = np.abs(coefficients[:, 0]) > 1e-10 * scale
    if np.any(regular):
        normalised = coefficients[regular, 1:] / coefficients[regular, :1]
        companion = np.zeros((normalised.shape[0], 4, 4))
        companion[:, 0, :] = -normalised
        companion[:, 1, 0] = companion[:, 2, 1] = companion[:, 3, 2] = 1.0
        roots[regular] = np.linalg.eigvals(companion)
    for row in np.flatnonzero(~regular & (scale > 0.0) & np.all(np.isfinite(coefficients), axis=1)):
        found = np.roots(coefficients[row])
        roots[row, : len(found)] = found
    return roots


def hitch_angles_1pt_batch(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    camera_centers: np.ndarray,
    yaw_change: float,
    hitch_translation: np.ndarray,
    trailer_axle_x: float,
    max_hitch_angle: float = 0.5 * np.pi,
) -> dict[str, np.ndarray]:
    """Vectorised 1-point solver over H trailer correspondences (DESIGN 2.2).

    Bearings and centres (H, 3) in the trailer frame. Returns arrays of shape (H, 8) (4 roots x 2
    signs of ``rho_B``): ``hitch_angle_i``, ``hitch_angle_j``, ``trailer_yaw_change``,
    ``chord_sign``, ``valid`` (admissible solutions only; others NaN / False).
    """
    s_b = -trailer_axle_x
    t = np.asarray(hitch_translation, dtype=float)
    tau2 = float(t[0] ** 2 + t[1] ** 2)
    offsets = np.asarray(camera_centers, dtype=float) - np.array([trailer_axle_x, 0.0, 0.0])
    offsets = np.broadcast_to(offsets, bearings_i.shape)
    p_x, p_y = offsets[:, 0], offsets[:, 1]
    u_c, u_s, n_c, n_s = arc_coefficients(bearings_i, bearings_j)
    # U' = u0 + u1 x, E = p_y U' - p_x N' = e0 + e1 x (over cos alpha)
    u0, u1 = u_c, -u_s
    e0, e1 = p_y * u_c - p_x * n_c, -p_y * u_s + p_x * n_s
    q0 = e0 * e0 + s_b * s_b * u0 * u0
    q1 = 2.0 * (e0 * e1 + s_b * s_b * u0 * u1)
    q2 = e1 * e1 + s_b * s_b * u1 * u1
    coefficients = np.stack(
        [4.0 * q2 - tau2 * u1 * u1, 4.0 * q1 - 2.0 * tau2 * u0 * u1, 4.0 * q0 - tau2 * (u0 * u0 + u1 * u1), -2.0 * tau2 * u0 * u1, -tau2 * u0 * u0],
        axis=1,
    )
    roots = _quartic_roots(coefficients)
    near_real = np.abs(roots.imag) <= _NEAR_REAL * (1.0 + np.abs(roots.real))
    start = np.where(near_real, np.arctan(roots.real), np.nan)  # alpha, (H, 4)
    start = np.repeat(start[:, :, None], 2, axis=2).reshape(len(start), 8)
    sign = np.tile(np.array([1.0, -1.0]), (len(start), 4))
    col = lambda values: values[:, None]  # noqa: E731 - broadcast (H,) over the 8 candidates
    alpha = start.copy()
    arguments = (tau2, s_b, col(p_x), col(p_y), col(u_c), col(u_s), col(n_c), col(n_s))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(_POLISH_ITERATIONS):
            residual, slope = _unsquared(alpha, sign, *arguments)
            step = np.clip(residual / np.where(np.abs(slope) > 1e-300, slope, np.inf), -_MAX_POLISH_STEP, _MAX_POLISH_STEP)
            step[~np.isfinite(step)] = 0.0
            alpha = alpha - step
            if not np.any(np.abs(step) > 1e-14):
                break
        residual, _ = _unsquared(alpha, sign, *arguments)
    scale = np.sqrt(tau2) * np.hypot(col(u_c), col(u_s)) + 1e-300
    converged = (np.abs(residual) <= _RESIDUAL_TOLERANCE * scale) & (np.abs(alpha - start) <= _MAX_POLISH_DRIFT)
    psi = 2.0 * alpha
    hitch_i, hitch_j, rotation, translation = trailer_motion_from_yaw(psi, sign, yaw_change, t, trailer_axle_x)
    centers = offsets[:, None, :] + np.array([trailer_axle_x, 0.0, 0.0])  # (H, 1, 3)
    rotated_j = np.einsum("hkab,hb->hka", rotation, bearings_j)
    baseline = np.einsum("hkab,hlb->hka", rotation, centers) + translation - centers
    cheiral = _positive_depth_rows(bearings_i[:, None, :], rotated_j, baseline)
    valid = (
        (tau2 > 1e-18) & converged & np.isfinite(hitch_i) & (np.abs(hitch_i) < max_hitch_angle) & (np.abs(hitch_j) < max_hitch_angle)
        & (4.0 * s_b * s_b * np.sin(alpha) ** 2 <= tau2 * (1.0 + 1e-9)) & cheiral
    )
    nan = np.full_like(psi, np.nan)
    return {
        "hitch_angle_i": np.where(valid, hitch_i, nan),
        "hitch_angle_j": np.where(valid, hitch_j, nan),
        "trailer_yaw_change": np.where(valid, psi, nan),
        "chord_sign": sign,
        "valid": valid,
    }


def _unsquared(alpha, sign, tau2, s_b, p_x, p_y, u_c, u_s, n_c, n_s):
    """``g(alpha) = (rho_B - 2 sin(alpha) p_y) U + 2 sin(alpha) p_x N`` with
    ``rho_B = sign sqrt(tau^2 - 4 s_B^2 sin^2 alpha)`` and its derivative (DESIGN 2.2)."""
    sin, cos = np.sin(alpha), np.cos(alpha)
    chord = sign * np.sqrt(np.maximum(tau2 - 4.0 * s_b * s_b * sin * sin, 0.0))
    u = cos * u_c - sin * u_s
    n = cos * n_c - sin * n_s
    d_chord = np.where(np.abs(chord) > 1e-12, -4.0 * s_b * s_b * sin * cos / np.where(np.abs(chord) > 1e-12, chord, 1.0), 0.0)
    d_u = -sin * u_c - cos * u_s
    d_n = -sin * n_c - cos * n_s
    residual = (chord - 2.0 * sin * p_y) * u + 2.0 * sin * p_x * n
    slope = (d_chord - 2.0 * cos * p_y) * u + (chord - 2.0 * sin * p_y) * d_u + 2.0 * cos * p_x * n + 2.0 * sin * p_x * d_n
    return residual, slope


def hitch_angles_1pt(
    bearing_i: np.ndarray,
    bearing_j: np.ndarray,
    camera_center: np.ndarray,
    yaw_change: float,
    hitch_translation: np.ndarray,
    trailer_axle_x: float,
    max_hitch_angle: float = 0.5 * np.pi,
) -> list[tuple[float, float]]:
    """Admissible ``(hitch_angle_i, hitch_angle_j)`` from one trailer correspondence (DESIGN 2.2).

    ``bearing_i``, ``bearing_j`` (3,): unit bearings in the trailer frame; ``camera_center`` (3,)
    in the trailer frame; ``yaw_change`` and ``hitch_translation`` (3,): the tractor motion
    (paper ``R_AA'``, ``t_AA'``); ``trailer_axle_x`` < 0. Returns 0 to ~3 solutions
    (duplicates removed); RANSAC consensus and continuity pick one.
    """
    bearing_i = check_bearings(np.reshape(bearing_i, (1, 3)), "bearing_i")
    bearing_j = check_bearings(np.reshape(bearing_j, (1, 3)), "bearing_j")
    center = np.asarray(camera_center, dtype=float).reshape(1, 3)
    result = hitch_angles_1pt_batch(bearing_i, bearing_j, center, yaw_change, hitch_translation, trailer_axle_x, max_hitch_angle)
    solutions: list[tuple[float, float]] = []
    for hitch_i, hitch_j, ok in zip(result["hitch_angle_i"][0], result["hitch_angle_j"][0], result["valid"][0]):
        if ok and not any(abs(hitch_i - a) < 1e-9 and abs(hitch_j - b) < 1e-9 for a, b in solutions):
            solutions.append((float(hitch_i), float(hitch_j)))
    return solutions
