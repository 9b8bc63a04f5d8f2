"""Minimal solvers for the tractor motion under the Ackermann (circular-arc) model, DESIGN 2.1.

The tractor moves by ``R = Rz(phi)``, ``t = rho u(phi/2) + (I - Rz(phi)) m`` with ``m`` the axle
midpoint (DESIGN 2 (NH)). For one correspondence of a camera at offset ``p = c - m`` from the axle,
the generalized epipolar constraint (paper eq. (1)) becomes

    (rho - 2 sin(phi/2) p_y) U + 2 sin(phi/2) p_x N = 0,
    U = cos(phi/2) U_c - sin(phi/2) U_s,   N = cos(phi/2) N_c - sin(phi/2) N_s.

Two correspondences give a quadratic in ``x = tan(phi/2)`` (2-point solver, metric scale);
a camera with ``p_x = 0`` gives the scale-free 1-point solver ``tan(phi/2) = U_c / U_s``.
All functions are vectorised over a leading batch axis (used by RANSAC).
"""
from __future__ import annotations

import numpy as np

from ampc_vo.geometry import check_bearings

_MIN_AXLE_OFFSET = 1e-6  # |p_x| below this: the camera is above the axle (scale-free)


def arc_coefficients(bearings_i: np.ndarray, bearings_j: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(U_c, U_s, N_c, N_s)`` of DESIGN 2.1 for body-frame bearings ``(..., 3)``."""
    fx, fy, fz = bearings_i[..., 0], bearings_i[..., 1], bearings_i[..., 2]
    gx, gy, gz = bearings_j[..., 0], bearings_j[..., 1], bearings_j[..., 2]
    u_c = fy * gz - fz * gy
    u_s = fx * gz + fz * gx
    n_c = fz * gx - fx * gz
    n_s = fy * gz + fz * gy
    return u_c, u_s, n_c, n_s


def rotations_z(angles: np.ndarray | float) -> np.ndarray:
    """Rotations about z, ``Rz(angle)``, vectorised: (...) -> (..., 3, 3)."""
    angles = np.asarray(angles, dtype=float)
    cos, sin = np.cos(angles), np.sin(angles)
    rotation = np.zeros(angles.shape + (3, 3))
    rotation[..., 0, 0] = cos
    rotation[..., 0, 1] = -sin
    rotation[..., 1, 0] = sin
    rotation[..., 1, 1] = cos
    rotation[..., 2, 2] = 1.0
    return rotation


def ackermann_motion(yaw_change: np.ndarray | float, chord: np.ndarray | float, axle_x: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``(..., 3, 3)`` and translation ``(..., 3)`` of the Ackermann arc (DESIGN 2 (NH)):
    ``R = Rz(phi)``, ``t = rho u(phi/2) + (I - Rz(phi)) m``, ``m = (axle_x, 0, 0)``."""
    yaw_change = np.asarray(yaw_change, dtype=float)
    chord = np.asarray(chord, dtype=float)
    cos, sin = np.cos(yaw_change), np.sin(yaw_change)
    rotation = rotations_z(yaw_change)
    half = 0.5 * yaw_change
    translation = np.zeros(np.broadcast(yaw_change, chord).shape + (3,))
    translation[..., 0] = chord * np.cos(half) + axle_x * (1.0 - cos)
    translation[..., 1] = chord * np.sin(half) - axle_x * sin
    return rotation, translation


def chord_from_yaw(
    yaw_change: np.ndarray, bearings_i: np.ndarray, bearings_j: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares chord for given yaw changes from K correspondences (DESIGN 2.1).

    ``yaw_change`` (...,), bearings and camera-to-axle ``offsets`` ``p`` (..., K, 3). Minimises
    ``sum_k ((rho - 2 s p_ky) U_k + 2 s p_kx N_k)^2`` with ``s = sin(phi/2)``. Returns
    ``(chord, determined)``: ``determined`` is False when the chord is not observable from these
    correspondences (``U_k ~ 0``: straight motion; or every ``p_x ~ 0``).
    """
    u_c, u_s, n_c, n_s = arc_coefficients(bearings_i, bearings_j)
    half = 0.5 * np.asarray(yaw_change)[..., None]
    cos, sin = np.cos(half), np.sin(half)
    u = cos * u_c - sin * u_s
    n = cos * n_c - sin * n_s
    weight = np.sum(u * u, axis=-1)
    numerator = np.sum(u * (2.0 * sin * offsets[..., 1] * u - 2.0 * sin * offsets[..., 0] * n), axis=-1)
    cosine = np.sum(bearings_i * bearings_j, axis=-1)
    cross_norm = np.sum(1.0 - cosine * cosine, axis=-1)  # sum |f x f'|^2 of unit bearings
    with np.errstate(divide="ignore", invalid="ignore"):
        chord = numerator / weight
    has_offset = np.any(np.abs(offsets[..., 0]) > _MIN_AXLE_OFFSET, axis=-1)
    determined = (weight > 1e-18 * np.maximum(cross_norm, 1e-300)) & has_offset & np.isfinite(chord)
    return np.where(determined, chord, np.nan), determined


def tractor_motion_2pt_batch(
    bearings_i: np.ndarray, bearings_j: np.ndarray, camera_centers: np.ndarray, axle_x: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised 2-point solver over H samples (DESIGN 2.1).

    ``bearings_i``, ``bearings_j``, ``camera_centers``: (H, 2, 3) in the tractor frame. Returns
    ``(yaw_change (H, 2), chord (H, 2), valid (H, 2))``; invalid entries are NaN. A solution whose
    chord is undetermined (straight motion, both ``p_x ~ 0``) has a finite yaw and ``chord = NaN``
    and ``valid`` False.
    """
    offsets = camera_centers - np.array([axle_x, 0.0, 0.0])
    u_c, u_s, n_c, n_s = arc_coefficients(bearings_i, bearings_j)
    (u1c, u2c), (u1s, u2s) = np.moveaxis(u_c, -1, 0), np.moveaxis(u_s, -1, 0)
    (n1c, n2c), (n1s, n2s) = np.moveaxis(n_c, -1, 0), np.moveaxis(n_s, -1, 0)
    p1x, p2x = offsets[..., 0, 0], offsets[..., 1, 0]
    dy = offsets[..., 0, 1] - offsets[..., 1, 1]
    # (p1y - p2y) U1 U2 - p1x N1 U2 + p2x N2 U1 = 0 with U = U_c - x U_s, N = N_c - x N_s (over cos^2)
    a = dy * u1s * u2s - p1x * n1s * u2s + p2x * n2s * u1s
    b = -(dy * (u1c * u2s + u1s * u2c) - p1x * (n1c * u2s + n1s * u2c) + p2x * (n2c * u1s + n2s * u1c))
    c = dy * u1c * u2c - p1x * n1c * u2c + p2x * n2c * u1c
    roots = _quadratic_roots(a, b, c)
    yaw = 2.0 * np.arctan(roots)
    chord, determined = chord_from_yaw(yaw, bearings_i[..., None, :, :], bearings_j[..., None, :, :], offsets[..., None, :, :])
    valid = np.isfinite(yaw) & determined
    return yaw, chord, valid


def _quadratic_roots(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Real roots (H, 2) of ``a x^2 + b x + c`` (NaN where absent), numerically stable; a
    vanishing leading coefficient leaves the linear root ``-c / b``."""
    discriminant = b * b - 4.0 * a * c
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), np.abs(c))
    real = discriminant >= -1e-12 * scale * scale
    root = np.sqrt(np.maximum(discriminant, 0.0))
    q = -0.5 * (b + np.where(b >= 0.0, root, -root))
    with np.errstate(divide="ignore", invalid="ignore"):
        first = np.where(np.abs(a) > 1e-14 * scale, q / a, np.nan)
        second = np.where(np.abs(q) > 1e-300, c / q, np.nan)
    roots = np.stack([first, second], axis=-1)
    roots[~real | (scale == 0.0)] = np.nan
    roots[~np.isfinite(roots)] = np.nan
    return roots


def tractor_motion_2pt(
    bearings_i: np.ndarray, bearings_j: np.ndarray, camera_centers: np.ndarray, axle_x: float
) -> list[tuple[float, float]]:
    """Tractor ``(yaw_change, chord)`` solutions from two correspondences (DESIGN 2.1).

    ``bearings_i``, ``bearings_j``: (2, 3) unit bearings in the tractor frame (already rotated by
    ``R_body_camera``); ``camera_centers``: (2, 3) centres of the cameras that saw them (the two
    points may come from different cameras); ``axle_x``: the tractor axle. Returns 0 to 2
    solutions. Straight motion or both cameras above the axle (``p_x = 0``) leave the chord
    undetermined: such roots are not returned (use :func:`tractor_yaw_1pt`).
    """
    bearings_i = check_bearings(bearings_i, "bearings_i", count=2)
    bearings_j = check_bearings(bearings_j, "bearings_j", count=2)
    centers = np.asarray(camera_centers, dtype=float).reshape(2, 3)
    yaw, chord, valid = tractor_motion_2pt_batch(bearings_i[None], bearings_j[None], centers[None], axle_x)
    solutions = [(float(y), float(r)) for y, r, ok in zip(yaw[0], chord[0], valid[0]) if ok]
    unique: list[tuple[float, float]] = []
    for solution in solutions:
        if not any(abs(solution[0] - other[0]) < 1e-12 and abs(solution[1] - other[1]) < 1e-12 for other in unique):
            unique.append(solution)
    return unique


def tractor_yaw_1pt_batch(bearings_i: np.ndarray, bearings_j: np.ndarray) -> np.ndarray:
    """Scale-free 1-point yaw change ``tan(phi/2) = U_c / U_s`` for cameras above the axle
    (``p_x = 0``, DESIGN 2.1), vectorised over (..., 3). NaN where undefined."""
    u_c, u_s, _, _ = arc_coefficients(bearings_i, bearings_j)
    with np.errstate(divide="ignore", invalid="ignore"):
        yaw = 2.0 * np.arctan(u_c / u_s)
    return np.where(np.abs(u_s) > 1e-15, yaw, np.nan)


def tractor_yaw_1pt(bearing_i: np.ndarray, bearing_j: np.ndarray) -> float | None:
    """Scale-free yaw change from one correspondence of a camera above the axle (``p_x = 0``).
    Returns None when undefined (``U_s = 0``)."""
    bearing_i = check_bearings(np.reshape(bearing_i, (1, 3)), "bearing_i")[0]
    bearing_j = check_bearings(np.reshape(bearing_j, (1, 3)), "bearing_j")[0]
    yaw = float(tractor_yaw_1pt_batch(bearing_i, bearing_j))
    return None if not np.isfinite(yaw) else yaw
