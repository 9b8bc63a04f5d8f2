"""Estimate a body's Ackermann axle offset ``axle_x`` from its ground-truth poses (DESIGN 2, (NH)).

Between two poses of a body the rigid axle's midpoint ``m = (a, 0, 0)`` moves along a circular arc,
so its displacement ``d = R m + t - m`` in the first body frame points at half the yaw change φ:
``n(φ/2) . d = 0``. Since ``n(φ/2) . (R - I) e_x = 2 sin(φ/2)``, each pose pair gives one linear
equation in ``a``:

    2 sin(φ/2) a = -n(φ/2) . t                                            (NH solved for axle_x)

which only carries information on turning pairs (φ != 0). The least-squares solution over all
turning pairs is returned with its standard error.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ampc_vo.errors import AmpcError
from ampc_vo.geometry import unit_normal, yaws_of


@dataclass(frozen=True)
class AxleOffsetEstimate:
    """``axle_x`` (m, in the body frame of the poses), its standard error, the number of turning
    pose pairs used and the RMS of the chord-direction residuals (m)."""

    axle_x: float
    standard_error: float
    pairs: int
    residual_rms: float


def estimate_axle_x(T_world_body: np.ndarray, step: int = 1, min_yaw_change_rad: float = np.radians(0.5)) -> AxleOffsetEstimate:
    """Least-squares ``axle_x`` from (N, 4, 4) poses using pairs ``(k, k + step)`` whose yaw change
    exceeds ``min_yaw_change_rad``. Raises :class:`AmpcError` if fewer than 2 pairs turn."""
    poses = np.asarray(T_world_body, dtype=float)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) <= step:
        raise AmpcError(f"need more than {step} poses of shape (4, 4), got {poses.shape}")
    first, second = poses[:-step], poses[step:]
    relative_rotation = np.einsum("nji,njk->nik", first[:, :3, :3], second[:, :3, :3])      # R_i^T R_j
    relative_translation = np.einsum("nji,nj->ni", first[:, :3, :3], second[:, :3, 3] - first[:, :3, 3])
    yaw_change = yaws_of(relative_rotation)
    turning = np.abs(yaw_change) > min_yaw_change_rad
    if turning.sum() < 2:
        raise AmpcError(f"only {int(turning.sum())} pose pairs turn by more than {np.degrees(min_yaw_change_rad):.2f} deg: axle_x is not observable on straight driving")
    half = yaw_change[turning] / 2.0
    coefficient = 2.0 * np.sin(half)
    target = -np.einsum("na,na->n", unit_normal(half)[:, :2], relative_translation[turning, :2])
    axle_x = float(coefficient @ target / (coefficient @ coefficient))
    residual = coefficient * axle_x - target
    dof = max(len(residual) - 1, 1)
    standard_error = float(np.sqrt(residual @ residual / dof / (coefficient @ coefficient)))
    return AxleOffsetEstimate(axle_x, standard_error, int(turning.sum()), float(np.sqrt(np.mean(residual**2))))
