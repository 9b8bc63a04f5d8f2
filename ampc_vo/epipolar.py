"""Generalized epipolar constraint (GEC) residuals, paper eqs. (1), (2); DESIGN section 2.

The one implementation shared by the minimal solvers, RANSAC scoring and the GTSAM factors.

For a body that moves by ``(R, t) = T_i_j`` between views i and j (``p_i = R p_j + t``), a ray
seen in view i from the camera centre ``c_i`` with body-frame bearing ``f`` and the same point
seen in view j from ``c_j`` with body-frame bearing ``f'`` are coplanar:

    r = (f x R f') . (R c_j + t - c_i) = 0                                  (paper eq. (1))

``c_i == c_j`` for intra-camera correspondences; different centres give the Plücker two-camera
form. The Sampson-normalised residual divides by the norm of the gradient of ``r`` projected on
the tangent planes of the two unit bearings; it approximates the angular error in radians.

All functions broadcast over hypotheses: ``rotation`` may be (..., 3, 3) and ``translation``
(..., 3); results are then (..., N).
"""
from __future__ import annotations

import numpy as np


def _baseline(rotation: np.ndarray, translation: np.ndarray, center_i: np.ndarray, center_j: np.ndarray) -> np.ndarray:
    """``d = R c_j + t - c_i`` with shape (..., 3)."""
    return np.einsum("...ab,b->...a", rotation, center_j) + translation - center_i


def gec_algebraic(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    center_i: np.ndarray,
    center_j: np.ndarray | None = None,
) -> np.ndarray:
    """Algebraic GEC residual ``(f x R f') . (R c_j + t - c_i)`` for N body-frame bearings (N, 3)."""
    center_j = center_i if center_j is None else center_j
    rotated_j = np.einsum("...ab,nb->...na", rotation, bearings_j)  # g = R f'
    baseline = _baseline(rotation, translation, center_i, center_j)[..., None, :]
    return np.einsum("...na,...na->...n", np.cross(bearings_i, rotated_j), baseline)


def gec_sampson(
    bearings_i: np.ndarray,
    bearings_j: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    center_i: np.ndarray,
    center_j: np.ndarray | None = None,
) -> np.ndarray:
    """Sampson-normalised GEC residual (approximately radians), DESIGN section 2.

    ``r / sqrt(|P_f (g x d)|^2 + |P_g (d x f)|^2)`` with ``g = R f'``, ``d = R c_j + t - c_i``
    and ``P_v = I - v v^T`` the tangent-plane projector of the unit vector v.
    """
    center_j = center_i if center_j is None else center_j
    rotated_j = np.einsum("...ab,nb->...na", rotation, bearings_j)
    baseline = np.broadcast_to(_baseline(rotation, translation, center_i, center_j)[..., None, :], rotated_j.shape)
    bearings_i = np.broadcast_to(bearings_i, rotated_j.shape)
    grad_f = np.cross(rotated_j, baseline)
    grad_g = np.cross(baseline, bearings_i)
    residual = np.einsum("...na,...na->...n", bearings_i, grad_f)
    tangent_f = grad_f - np.einsum("...na,...na->...n", grad_f, bearings_i)[..., None] * bearings_i
    tangent_g = grad_g - np.einsum("...na,...na->...n", grad_g, rotated_j)[..., None] * rotated_j
    norm = np.sqrt(np.einsum("...na,...na->...n", tangent_f, tangent_f) + np.einsum("...na,...na->...n", tangent_g, tangent_g))
    return residual / np.maximum(norm, 1e-12)
